"""The background frame writer of ``warpsph run`` (#24): the same cache as writing on the
simulation's thread, errors that stop the run cleanly, signals that leave a readable cache, and
lean caches (--fields, ids only when they change)."""

import json
import textwrap

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from conftest import interrupt_a_long_run, tank_scene
from warpsph.cli import main


def write_scene(tmp_path, data, name="scene.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def run_cli(*args):
    return main([*map(str, args), "--device", "cpu", "--quiet"])


def samples(path):
    """{(prim, attribute): [(time, value as numpy)]} of every time-sampled attribute."""
    stage = Usd.Stage.Open(str(path))
    out = {}
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            times = attr.GetTimeSamples()
            if times:
                out[(str(prim.GetPath()), attr.GetName())] = [(t, np.array(attr.Get(t))) for t in times]
    return out


def assert_same_samples(a, b):
    assert a.keys() == b.keys()
    for key in a:
        assert [t for t, _ in a[key]] == [t for t, _ in b[key]], key
        for (t, x), (_, y) in zip(a[key], b[key]):
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), (key, t)


def time_samples(path, attr="points"):
    stage = Usd.Stage.Open(str(path))
    return stage.GetPrimAtPath("/World/Fluid").GetAttribute(attr).GetTimeSamples()


@pytest.mark.parametrize("clips", [False, True])
def test_background_writer_writes_the_same_cache_as_writing_synchronously(tmp_path, clips):
    data = tank_scene(radius=0.04, block=(0.2, 0.4, 0.4), models=[{"type": "micropolar"}], solver={"sort_interval": 2},
                      output={"fps": 25, "frames": 4})
    scene = write_scene(tmp_path, data)
    extra = ["--clips"] if clips else []
    suffix = ".usda" if clips else ".usdc"
    a, b = tmp_path / f"background{suffix}", tmp_path / f"sync{suffix}"
    assert run_cli("run", scene, "--out", a, "--particles-h5", *extra) == 0
    assert run_cli("run", scene, "--out", b, "--particles-h5", "--sync-output", *extra) == 0
    sa, sb = samples(a), samples(b)
    assert_same_samples(sa, sb)
    assert ("/World/Fluid", "primvars:angular_velocity") in sa and len(sa[("/World/Fluid", "points")]) == 5
    assert a.with_suffix(".stats.csv").read_text() == b.with_suffix(".stats.csv").read_text()
    import h5py

    with h5py.File(a.with_suffix(".particles.h5"), "r") as fa, h5py.File(b.with_suffix(".particles.h5"), "r") as fb:
        for frame in fa["frames"]:
            for name in fa["frames"][frame]:
                assert np.array_equal(fa["frames"][frame][name][...], fb["frames"][frame][name][...])
    if clips:
        for layer in sorted((tmp_path / "background.clips").glob("frame.*.usdc")):
            assert_same_samples(samples(layer), samples(tmp_path / "sync.clips" / layer.name))


def test_particles_are_written_in_id_order_and_ids_only_when_they_change(tmp_path):
    from test_inflow import channel

    scene = write_scene(tmp_path, tank_scene(radius=0.04, solver={"sort_interval": 1}, output={"fps": 25, "frames": 3}))
    out = tmp_path / "tank.usdc"
    assert run_cli("run", scene, "--out", out) == 0
    stage = Usd.Stage.Open(str(out))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    assert points.GetIdsAttr().GetTimeSamples() == [0.0] and points.GetWidthsAttr().GetTimeSamples() == [0.0]
    n = len(points.GetPointsAttr().Get(3))
    assert list(points.GetIdsAttr().Get(3)) == list(range(n))
    # emitters and sinks change the set: ids (and widths when the count changes) follow
    scene = write_scene(tmp_path, channel(frames=8), "channel.json")
    out = tmp_path / "channel.usdc"
    assert run_cli("run", scene, "--out", out) == 0
    stage = Usd.Stage.Open(str(out))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    assert len(points.GetIdsAttr().GetTimeSamples()) > 1
    for f in range(9):
        ids = np.array(points.GetIdsAttr().Get(f))
        assert len(ids) == len(points.GetPointsAttr().Get(f)) == len(points.GetWidthsAttr().Get(f))
        assert np.all(np.diff(ids) > 0)  # id order, unique


def test_fields_writes_only_the_arrays_asked_and_reports_bytes(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.04, models=[{"type": "vorticity_refinement"}],
                                             output={"fps": 25, "frames": 2}))
    out = tmp_path / "lean.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--fields", "points,density,vorticity_magnitude"]) == 0
    err = capsys.readouterr().err
    assert "20.0 B per particle per frame" in err  # 12 (points) + 4 (density) + 4 (vorticity magnitude)
    stage = Usd.Stage.Open(str(out))
    fluid = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    api = UsdGeom.PrimvarsAPI(fluid.GetPrim())
    assert fluid.GetPointsAttr().GetTimeSamples() == [0.0, 1.0, 2.0]
    assert not fluid.GetVelocitiesAttr().GetTimeSamples() and not fluid.GetIdsAttr().GetTimeSamples()
    assert api.GetPrimvar("density").GetTimeSamples() == [0.0, 1.0, 2.0]
    assert api.GetPrimvar("vorticity_magnitude") and not api.GetPrimvar("vorticity")
    assert main(["run", str(scene), "--device", "cpu", "--out", str(tmp_path / "x.usdc"), "--fields", "points,pressure"]) == 2
    assert "--fields: unknown field 'pressure'" in capsys.readouterr().err
    assert not (tmp_path / "x.usdc").exists()
    assert main(["run", str(scene), "--device", "cpu", "--out", str(tmp_path / "x.usdc"), "--fields", "velocities"]) == 2
    assert "points is required" in capsys.readouterr().err


@pytest.mark.parametrize("clips", [False, True])
def test_a_writer_that_raises_stops_the_run_and_keeps_the_frames_before(tmp_path, monkeypatch, capsys, clips):
    from conftest import fail_frame_writes

    cls, original = fail_frame_writes(monkeypatch, clips, 3, RuntimeError("the renderer's schema went away"))
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 8}))
    out = tmp_path / "o.usdc"
    assert run_cli("run", scene, "--out", out, "--checkpoint-every", 2, *(["--clips"] if clips else [])) == 2
    err = capsys.readouterr().err
    assert "warpsph: error: cannot write frame 3: RuntimeError: the renderer's schema went away" in err
    assert "keeps the frames before it" in err and "Traceback" not in err
    assert time_samples(out) == [0.0, 1.0, 2.0]
    import csv
    import h5py

    with open(out.with_suffix(".stats.csv")) as f:
        assert [int(r["frame"]) for r in csv.DictReader(f)] == [0, 1, 2]
    with h5py.File(out.with_suffix(".checkpoint.h5"), "r") as f:
        assert f.attrs["frame"] == 2  # never a frame the cache lacks
    monkeypatch.setattr(cls, "write_frame", original)
    assert run_cli("resume", out.with_suffix(".checkpoint.h5")) == 0
    assert time_samples(out) == [float(f) for f in range(9)]


@pytest.mark.parametrize("clips", [False, True])
def test_the_output_directory_removed_mid_run_is_a_clear_error(tmp_path, monkeypatch, capsys, clips):
    """USD would create the directory again and write on into it (a clip cache then silently
    lacks its first frames): the run stops instead."""
    import shutil

    from warpsph.io import usd

    cls = usd.UsdClipCache if clips else usd.UsdPointCache
    original = cls.write_frame
    folder = tmp_path / "renders"

    def remove_then_write(self, frame, *args, **kwargs):
        if frame == 2:
            shutil.rmtree(folder)
        return original(self, frame, *args, **kwargs)

    monkeypatch.setattr(cls, "write_frame", remove_then_write)
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 6}))
    out = folder / "o.usda"
    assert run_cli("run", scene, "--out", out, *(["--clips"] if clips else [])) == 2
    err = capsys.readouterr().err
    assert f"warpsph: error: cannot write frame 2: the output directory {folder}" in err and "was removed" in err
    assert "is gone" in err and "Traceback" not in err and not folder.exists()


SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from warpsph.io import usd
    original = usd.UsdPointCache.write_frame
    def slow(self, *args, **kwargs):
        time.sleep(0.3)  # a slow disk: the signal arrives while a frame is being written
        return original(self, *args, **kwargs)
    usd.UsdPointCache.write_frame = slow
    from warpsph.cli import main
    sys.exit(main(sys.argv[1:]))
""")


@pytest.mark.slow
def test_sigint_during_a_write_leaves_a_readable_cache_and_a_matching_checkpoint(tmp_path):
    import h5py

    out, code, err = interrupt_a_long_run(tmp_path, SLOW_WRITER, pause=0.15)  # mid-write
    assert code == 130, err
    done = time_samples(out)
    assert done == [float(f) for f in range(len(done))] and len(done) >= 2
    assert f"holds frames 0..{len(done) - 1}" in err
    with h5py.File(out.with_suffix(".checkpoint.h5"), "r") as f:
        assert f.attrs["frame"] == len(done) - 1
    rows = out.with_suffix(".stats.csv").read_text().splitlines()
    assert len(rows) == len(done) + 1
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "--frames", str(len(done) + 1),
                 "--quiet"]) == 0
    assert time_samples(out) == [float(f) for f in range(len(done) + 2)]


def test_frame_writer_queue_is_bounded_and_a_slow_writer_throttles(tmp_path):
    """With every buffer set taken the simulation waits: memory holds at most DEPTH frames."""
    import threading

    from conftest import make_sim
    from warpsph.io.frames import DEPTH, FrameWriter

    sim = make_sim(tank_scene(radius=0.05))
    gate = threading.Event()
    seen = []

    def write(item):
        gate.wait(10)
        seen.append(item.frame)

    writer = FrameWriter(sim, write, copy=["v"], depth=DEPTH)
    for frame in range(DEPTH):
        writer.submit(sim, frame)  # fills the pool
    blocked = threading.Thread(target=writer.submit, args=(sim, DEPTH))
    blocked.start()
    blocked.join(0.3)
    assert blocked.is_alive()  # waits for a free buffer set
    gate.set()
    blocked.join(10)
    writer.flush()
    writer.close()
    assert seen == list(range(DEPTH + 1)) and writer.written == DEPTH and writer.error is None
