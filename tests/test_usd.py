"""The USD point cache, reopened with pxr; and the CLI end to end."""

import json

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from warpsph.cli import main
from warpsph.io.usd import UsdPointCache, frame_writer
from conftest import make_sim, tank_scene


def test_cli_writes_a_usd_cache_that_reopens(tmp_path, capsys):
    scene = tmp_path / "tank.json"
    scene.write_text(json.dumps(tank_scene(radius=0.04, output={"fps": 20, "frames": 3})))
    out = tmp_path / "tank.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "frame 3/3" in err and "done: frame 3" in err

    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert stage.GetTimeCodesPerSecond() == 20
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 3)
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    n = len(points.GetPointsAttr().Get(0))
    assert n == 5 * 5 * 5
    for attr in (points.GetPointsAttr(), points.GetVelocitiesAttr()):
        assert attr.GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    for attr in (points.GetIdsAttr(), points.GetWidthsAttr()):  # in id order: the same set, written once
        assert attr.GetTimeSamples() == [0.0]
    for attr in (points.GetPointsAttr(), points.GetVelocitiesAttr(), points.GetIdsAttr(), points.GetWidthsAttr()):
        assert len(attr.Get(3)) == n
    assert list(points.GetIdsAttr().Get(2)) == list(range(n))
    assert np.allclose(np.array(points.GetWidthsAttr().Get(1)), 0.08)
    density = UsdGeom.PrimvarsAPI(points.GetPrim()).GetPrimvar("density")
    assert density.GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    assert 900 < np.mean(density.Get(0)) < 1010 and 900 < np.mean(density.Get(3)) < 1010
    # the fluid fell: frame 3 is lower than frame 0 or equal at rest, never higher
    assert np.array(points.GetPointsAttr().Get(3))[:, 1].mean() <= np.array(points.GetPointsAttr().Get(0))[:, 1].mean() + 1e-3
    # no turbulence model: no vorticity primvar
    assert not UsdGeom.PrimvarsAPI(points.GetPrim()).GetPrimvar("vorticity")
    # the diagnostics CSV beside the cache: one row per frame, energy accounted
    from warpsph.diagnostics import read_csv

    rows = read_csv(out.with_suffix(".stats.csv"))
    assert list(rows["frame"]) == [0, 1, 2, 3]
    assert rows["kinetic_energy"][0] == 0.0 and rows["kinetic_energy"][3] > 0.0  # it starts at rest, then falls
    assert rows["potential_energy"][3] < rows["potential_energy"][0]
    boundary = UsdGeom.Points(stage.GetPrimAtPath("/World/Boundary"))
    assert boundary.GetPointsAttr().GetTimeSamples() == []  # static: written once
    assert len(boundary.GetPointsAttr().Get()) > 0


def test_a_run_that_stops_early_leaves_the_frames_done(tmp_path):
    sim = make_sim(tank_scene(radius=0.04))
    out = tmp_path / "partial.usdc"
    cache = UsdPointCache(out, 25, boundary_points=sim.boundary.x.numpy(), boundary_radius=0.04)
    write = frame_writer(cache)

    class Stop(Exception):
        pass

    def on_frame(sim, frame):
        write(sim, frame)
        if frame == 2:
            raise Stop

    try:
        sim.run(frames=10, on_frame=on_frame)
    except Stop:
        pass
    stage = Usd.Stage.Open(str(out))  # opened while the writer still holds its stage
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    assert points.GetPointsAttr().GetTimeSamples() == [0.0, 1.0, 2.0]
    assert stage.GetEndTimeCode() == 2


def test_turbulence_model_adds_vorticity_primvars_and_rotational_energy(tmp_path):
    scene = tmp_path / "vr.json"
    scene.write_text(json.dumps(tank_scene(radius=0.04, output={"fps": 20, "frames": 2},
                                           models=[{"type": "micropolar"}])))
    out = tmp_path / "vr.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    api = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Fluid"))
    vorticity, magnitude = api.GetPrimvar("vorticity"), api.GetPrimvar("vorticity_magnitude")
    assert str(vorticity.GetTypeName()) == "float3[]" and str(magnitude.GetTypeName()) == "float[]"
    np.testing.assert_allclose(np.linalg.norm(np.array(vorticity.Get(2)), axis=1), np.array(magnitude.Get(2)), rtol=1e-5)
    assert api.GetPrimvar("angular_velocity").GetTimeSamples() == [0.0, 1.0, 2.0]
    from warpsph.diagnostics import read_csv

    rows = read_csv(out.with_suffix(".stats.csv"))
    assert rows["enstrophy"][2] > 0.0 and rows["rotational_energy"][2] > 0.0


def test_value_clip_mode_stitches_one_layer_per_frame(tmp_path):
    scene = tmp_path / "clips.json"
    scene.write_text(json.dumps(tank_scene(radius=0.05, output={"fps": 10, "frames": 3})))
    out = tmp_path / "clips.usda"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--clips", "--quiet"]) == 0
    layers = sorted((tmp_path / "clips.clips").glob("frame.*.usdc"))
    assert [p.name for p in layers] == [f"frame.{f:06d}.usdc" for f in range(4)]
    assert (tmp_path / "clips.topology.usda").exists()
    single = tmp_path / "single.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(single), "--quiet"]) == 0
    a, b = Usd.Stage.Open(str(out)), Usd.Stage.Open(str(single))
    assert a.GetTimeCodesPerSecond() == 10 and UsdGeom.GetStageMetersPerUnit(a) == 1.0
    assert (a.GetStartTimeCode(), a.GetEndTimeCode()) == (0, 3)
    pa, pb = (UsdGeom.Points(s.GetPrimAtPath("/World/Fluid")) for s in (a, b))
    for f in range(4):  # the same data through clips as in the single file
        np.testing.assert_array_equal(np.array(pa.GetPointsAttr().Get(f)), np.array(pb.GetPointsAttr().Get(f)))
        np.testing.assert_array_equal(np.array(pa.GetIdsAttr().Get(f)), np.array(pb.GetIdsAttr().Get(f)))
    assert len(UsdGeom.Points(a.GetPrimAtPath("/World/Boundary")).GetPointsAttr().Get()) > 0


import pytest  # noqa: E402

from conftest import SCENES_DIR  # noqa: E402


@pytest.mark.parametrize("clips", [False, True])
def test_bodies_are_meshes_with_their_motion(tmp_path, clips):
    """A spinning rod and a static pillar come out as meshes; the rod's transform at each frame
    carries its samples' motion (local mesh point x pose = where the simulation put it)."""
    import os

    meshes = os.path.abspath(os.path.join(SCENES_DIR, "meshes"))
    rod = {"mesh": f"{meshes}/rod.obj", "scale": [1, 0.4, 1], "translation": [0.2, 0.3, 0.2], "name": "rod",
           "motion": {"angular_velocity": 4.0, "center": [0.25, 0.3, 0.2]}}
    pillar = {"mesh": f"{meshes}/pillar.obj", "scale": [0.5, 0.1, 0.5], "translation": [0.05, 0.4, 0.05]}  # above the water
    scene = tmp_path / "stir.json"
    scene.write_text(json.dumps(tank_scene(radius=0.04, domain=(0.4, 0.6, 0.4), block=(0.4, 0.2, 0.4),
                                           obstacles=[rod, pillar], output={"fps": 20, "frames": 3})))
    out = tmp_path / ("stir.usda" if clips else "stir.usdc")
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out)] + (["--clips"] if clips else [])) == 0
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Bodies/rod"))
    assert mesh and len(mesh.GetPointsAttr().Get()) > 0
    static = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Bodies/pillar_1"))
    assert static and not static.GetPrim().GetAttribute("xformOp:translate")
    assert np.array(static.GetPointsAttr().Get())[:, 1].max() == pytest.approx(0.55)  # world space: 0.4 + 1.5 m x 0.1
    local = np.array(mesh.GetPointsAttr().Get(), np.float64)
    tip = local[np.argmax(local[:, 1])]
    frames_seen = []
    for frame in range(4):
        m = np.array(UsdGeom.Xformable(mesh.GetPrim()).ComputeLocalToWorldTransform(Usd.TimeCode(frame)))
        world = np.append(tip, 1.0) @ m  # USD: row vectors
        # the rod turns about the vertical axis through (0.25, *, 0.2), its body-space origin, at 4 rad/s
        assert np.hypot(world[0] - 0.25, world[2] - 0.2) == pytest.approx(np.hypot(tip[0], tip[2]), abs=1e-5)
        frames_seen.append(np.arctan2(world[2] - 0.2, world[0] - 0.25))
    turned = np.unwrap(frames_seen)
    assert np.all(np.diff(turned) < 0)  # right-handed about +y: x towards -z
    assert abs(turned[3] - turned[0]) == pytest.approx(4.0 * 3 / 20, rel=0.1)  # placed at each step's start
    boundary = UsdGeom.Points(stage.GetPrimAtPath("/World/Boundary"))
    assert np.array(boundary.GetPointsAttr().Get())[:, 1].max() < 0.6 + 0.1  # only static samples (walls, pillar)


@pytest.mark.parametrize("clips", [False, True])
def test_a_cache_plays_at_the_scenes_fps(tmp_path, device, clips):
    """timeCodesPerSecond and framesPerSecond are both the scene's output.fps (a time code is a frame), and the
    start and end time codes span the frames written: DCCs play the cache at its real speed."""
    import warpsph

    scene = warpsph.Scene.from_dict(tank_scene(radius=0.05, output={"fps": 24, "frames": 3}))
    sim = warpsph.Simulation(scene, device=device)
    out = tmp_path / ("cache.usda" if clips else "cache.usdc")
    with warpsph.io.UsdWriter(out, sim, clips=clips) as usd:
        sim.run(frames=3, on_frame=usd)
    stage = Usd.Stage.Open(str(out))
    layer = stage.GetRootLayer()
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 24
    assert layer.HasTimeCodesPerSecond() and layer.HasFramesPerSecond()
    assert layer.HasStartTimeCode() and layer.HasEndTimeCode()
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 3)


def test_a_single_file_cache_grows_by_appending_each_save(tmp_path, monkeypatch):
    """A save of the single-file cache appends the frames since the last one to a working copy and renames it over
    the file: the layer is written whole (``Export``) once, when the cache is made, and earlier frames are never
    written (and their meshes' indices compressed) again. Before, each save exported the whole layer anew. Every save
    leaves a cache that opens with the frames so far, and no working copy is left at the end."""
    exports = []
    export = Sdf.Layer.Export
    monkeypatch.setattr(Sdf.Layer, "Export", lambda layer, *a, **k: exports.append(a[0]) or export(layer, *a, **k))
    rng = np.random.default_rng(7)
    path = tmp_path / "grow.usdc"
    cache = UsdPointCache(path, fps=25)
    assert len(exports) == 1
    sizes = []
    for frame in range(6):
        x = rng.random((2000, 3), dtype=np.float32)
        cache.write_frame(frame, x, rng.random((2000, 3), dtype=np.float32), np.arange(2000), 0.01,
                          {"density": rng.random(2000, dtype=np.float32)})
        cache.flush()
        stage = Usd.Stage.Open(Sdf.Layer.OpenAsAnonymous(str(path)))  # read anew, not the layer of the loop before
        got = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr()
        assert [int(t) for t in got.GetTimeSamples()] == list(range(frame + 1))
        np.testing.assert_array_equal(np.array(got.Get(frame)), x)
        sizes.append(path.stat().st_size)
    cache.finish(path)
    assert len(exports) == 1 and cache.flushes == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grow.usdc"]  # no working copy left
    assert np.all(np.diff(sizes) > 0)


def _all_samples(path):
    """{(prim, attribute): {frame: values}} of every time-sampled attribute of the cache ``path``."""
    stage = Usd.Stage.Open(Sdf.Layer.OpenAsAnonymous(str(path)))
    return {(str(prim.GetPath()), attr.GetName()): {t: np.array(attr.Get(t)) for t in attr.GetTimeSamples()}
            for prim in stage.Traverse() for attr in prim.GetAttributes() if attr.GetTimeSamples()}


@pytest.mark.slow
def test_the_cache_written_by_a_process_of_its_own_is_the_thread_s_bit_for_bit(tmp_path):
    """``--cache-process`` (the default of a GPU run): the writer process writes the same cache, particles and the
    surface meshes alike, as the writer thread of the run's own process; it leaves no file of its own behind."""
    scene = tmp_path / "tank.json"
    scene.write_text(json.dumps(tank_scene(radius=0.04, output={"fps": 20, "frames": 4})))
    caches = {}
    for flag in ("--cache-process", "--no-cache-process"):
        out = tmp_path / flag.strip("-") / "tank.usdc"
        assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--surface", "--surface-method",
                     "preview", flag, "-q"]) == 0
        assert sorted(p.name for p in out.parent.iterdir()) == ["tank.stats.csv", "tank.usdc"]
        caches[flag] = _all_samples(out)
    got, want = caches["--cache-process"], caches["--no-cache-process"]
    assert sorted(got) == sorted(want)
    assert ("/World/FluidSurface", "faceVertexIndices") in want and ("/World/Fluid", "points") in want
    for key, frames in want.items():
        assert sorted(got[key]) == sorted(frames) == [0.0, 1.0, 2.0, 3.0, 4.0] or key[1] in ("ids", "widths"), key
        for t, values in frames.items():
            np.testing.assert_array_equal(got[key][t], values, err_msg=f"{key} at {t}")
