"""Fault injection for the writers beside the single-file cache (#38): a --clips frame layer, the mesh a worker
adds to a frame layer, the `surface` verb's output and OUT.particles.h5. Each write is cut in the middle by a
file-size limit (RLIMIT_FSIZE: SIGXFSZ kills the writing process, or the write fails with EFBIG) in a child
process; every file left must open, with the frames written before, and nothing half-written under a real name.
Before, each of these was written in place: a cut write left a file USD or h5py could not open."""

import json
import os
import resource
import signal
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

from warpsph.cli import main
from conftest import tank_scene


def child(script, *argv, limit=None, killed=True, cwd=None):
    """Runs ``script`` in a child python; ``limit`` (bytes) caps every file it writes from the moment the script
    calls ``cap()``; returns (exit code, stderr)."""
    prelude = textwrap.dedent(f"""
        import resource, signal, sys
        if {killed!r}:
            signal.signal(signal.SIGXFSZ, signal.SIG_DFL)  # Python ignores it; a C program dies of it
        def cap():
            resource.setrlimit(resource.RLIMIT_FSIZE, ({limit!r}, {limit!r}))
    """)
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(script), *map(str, argv)], capture_output=True,
                          text=True, env=env, cwd=cwd, preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_CORE, (0, 0)),
                          timeout=300)
    return proc.returncode, proc.stderr


def expect(code, err, killed):
    if killed:
        assert code == -signal.SIGXFSZ, err
    else:
        assert code == 1 and ("File too large" in err or "EFBIG" in err or "Errno 27" in err), err


def layer_frames(path):
    """The time samples of /World/Fluid's points in the layer ``path`` (fails the test if USD cannot open it)."""
    stage = Usd.Stage.Open(str(path))
    return [int(t) for t in UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr().GetTimeSamples()]


CLIP_FRAMES = """
    import numpy as np
    from warpsph.io.usd import UsdClipCache
    cache = UsdClipCache(sys.argv[1], 25, boundary_points=np.zeros((4, 3)), boundary_radius=0.01)
    rng = np.random.default_rng(0)
    for frame in range(3):
        x = rng.random((50, 3))
        cache.write_frame(frame, x, x, np.arange(50), 0.01)
    cap()
    x = rng.random((40000, 3))  # 1.4 MB of arrays: the layer's write crosses the limit
    cache.write_frame(3, x, x, np.arange(40000), 0.01)
"""


@pytest.mark.slow
@pytest.mark.parametrize("killed", [True, False])
def test_a_clip_frame_layer_cut_mid_write_leaves_only_whole_layers(tmp_path, killed):
    """A --clips run killed (or out of space) while it writes frame 3's layer: frames 0..2 open, and no
    frame.000003.usdc is left that USD cannot open; the cache stitches."""
    from warpsph.io.usd import UsdClipCache

    out = tmp_path / "c.usdc"
    expect(*child(CLIP_FRAMES, out, limit=200_000, killed=killed), killed)
    layers = sorted((tmp_path / "c.clips").glob("frame.*.usdc"))
    assert [p.name for p in layers if ".tmp." not in p.name] == [f"frame.00000{k}.usdc" for k in range(3)]
    for k, layer in enumerate(p for p in layers if ".tmp." not in p.name):
        assert layer_frames(layer) == [k]
    UsdClipCache(out, 25, append=2).finish()  # what resume and a stopped run do; a killed write's files go
    assert layer_frames(out) == [0, 1, 2]
    assert sorted(p.name for p in (tmp_path / "c.clips").iterdir()) == [
        "boundary.npz", "frame.000000.usdc", "frame.000001.usdc", "frame.000002.usdc"]


STITCH_AGAIN = """
    import numpy as np
    from warpsph.io.usd import UsdClipCache
    boundary = np.random.default_rng(3).random((40000, 3))  # 0.6 MB in the top-level file
    cache = UsdClipCache(sys.argv[1], 25, boundary_points=boundary, boundary_radius=0.01)
    x = np.random.default_rng(0).random((50, 3))
    for frame in range(3):
        cache.write_frame(frame, x, x, np.arange(50), 0.01)
    cache.finish()
    cache = UsdClipCache(sys.argv[1], 25, append=2)  # resume: frames 3, 4 more
    for frame in (3, 4):
        cache.write_frame(frame, x, x, np.arange(50), 0.01)
    cap()
    cache.finish()  # the top-level file's save crosses the limit
"""


@pytest.mark.slow
@pytest.mark.parametrize("killed", [True, False])
def test_the_stitched_clips_files_cut_mid_write_keep_the_previous_stitch(tmp_path, killed):
    """A --clips run (or its resume) stitches OUT, OUT.topology and OUT.manifest when it ends or stops. Before, they
    were deleted and written again in place: a cut write left no OUT, or one USD could not open. Now the previous
    stitch opens with its frames 0..2, no scratch file is left under a real name, and the next finish stitches 0..4."""
    from warpsph.io.usd import UsdClipCache

    out = tmp_path / "c.usdc"
    expect(*child(STITCH_AGAIN, out, limit=200_000, killed=killed), killed)
    assert layer_frames(out) == [0, 1, 2]
    assert len(Usd.Stage.Open(str(out)).GetPrimAtPath("/World/Boundary").GetAttribute("points").Get()) == 40000
    UsdClipCache(out, 25, append=4).finish()
    assert layer_frames(out) == [0, 1, 2, 3, 4]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.clips", "c.manifest.usdc", "c.topology.usdc", "c.usdc"]
    assert not [p.name for p in (tmp_path / "c.clips").iterdir() if "tmp" in p.name or "stitch" in p.name]


MESH_INTO_LAYER = """
    import numpy as np
    from warpsph.io.usd import UsdClipCache, write_surface_layer
    from warpsph.surface import SurfaceMesh
    cache = UsdClipCache(sys.argv[1], 25)
    x = np.random.default_rng(1).random((50, 3))
    for frame in range(2):
        cache.write_frame(frame, x, x, np.arange(50), 0.01)
    cap()
    n = 30000  # a 1 MB mesh: the layer's save crosses the limit
    mesh = SurfaceMesh(np.random.default_rng(2).random((n, 3)).astype(np.float32),
                       np.arange(3 * n, dtype=np.int32).reshape(-1, 3) % n, np.ones((n, 3), np.float32))
    write_surface_layer(cache.frame_path(1), 1, mesh)  # what a mesher worker does for frame 1
"""


@pytest.mark.slow
@pytest.mark.parametrize("killed", [True, False])
def test_a_mesh_cut_mid_write_into_a_frame_layer_keeps_the_frame(tmp_path, killed):
    """The mesher's worker adds frame 1's mesh to the frame's layer, written (and maybe checkpointed) before: the
    in-place save cut in the middle left a layer USD could not open, its particles lost with it."""
    out = tmp_path / "c.usdc"
    expect(*child(MESH_INTO_LAYER, out, limit=300_000, killed=killed), killed)
    layer = tmp_path / "c.clips" / "frame.000001.usdc"
    assert layer_frames(layer) == [1]
    assert len(Usd.Stage.Open(str(layer)).GetPrimAtPath("/World/Fluid").GetAttribute("points").Get(1)) == 50


def run_tank(tmp_path, frames=6):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2),
                                           output={"fps": 50, "frames": frames})))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "-q"]) == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize("killed", [True, False])
def test_the_surface_verb_cut_mid_save_keeps_the_earlier_output_and_its_frames(tmp_path, killed):
    """`warpsph surface --overwrite` cut in the middle of a save: the earlier OUT.surface.usdc is as it was, and
    OUT.surface.partial.usdc (saved in place before: cut, unreadable) opens with the frames of its last save."""
    pytest.importorskip("pysplashsurf", reason="warpsph surface meshes with pysplashsurf")
    cache = run_tank(tmp_path)
    surface = tmp_path / "o.surface.usdc"
    argv = ["surface", str(cache), "--cube", "0.3", "-q"]
    assert main(argv) == 0
    before = surface.read_bytes()
    script = "from warpsph.cli import main\ncap()\nsys.exit(main(sys.argv[1:]))"
    code, err = child(script, *argv, "--overwrite", limit=int(0.6 * len(before)), killed=killed)
    if killed:
        assert code == -signal.SIGXFSZ, err
    else:
        assert code == 2 and "File too large" in err and "Traceback" not in err, err
    assert surface.read_bytes() == before
    partial = tmp_path / "o.surface.partial.usdc"
    stage = Usd.Stage.Open(str(partial))
    meshed = stage.GetPrimAtPath("/World/FluidSurface").GetAttribute("points").GetTimeSamples()
    del stage
    assert meshed == [float(k) for k in range(len(meshed))] and meshed  # frames 0..j, whole
    assert main(argv + ["--overwrite"]) == 0 and not partial.exists()  # and the next run finishes
    assert not [p.name for p in tmp_path.iterdir() if ".tmp." in p.name]


PARTICLE_FRAMES = """
    import numpy as np
    from warpsph.io.particles_h5 import ParticleFrames
    frames = ParticleFrames(sys.argv[1])
    for frame in range(8):
        x = np.full((20000, 3), frame, np.float32)  # 0.5 MB a frame
        if frame == 5:
            cap()  # the limit falls inside frame 5's or 6's write
        frames.write(frame, 0.1 * frame, 10 * frame, {"x": x, "v": x, "ids": np.arange(20000)})
        getattr(frames, "flush", frames.file.flush)()  # a checkpoint after every frame
"""


@pytest.mark.parametrize("killed", [True, False])
def test_particles_h5_cut_mid_write_keeps_the_frames_before(tmp_path, killed):
    """OUT.particles.h5 was appended to in place: a write cut in the middle left a file h5py could not open (or a
    frame half there). Now it holds frames 0..j, each whole, j at least the last save's frame."""
    path = tmp_path / "o.particles.h5"
    expect(*child(PARTICLE_FRAMES, path, limit=4_000_000, killed=killed), killed)
    with h5py.File(path, "r") as f:
        names = sorted(f["frames"])
        assert names == [f"{k:06d}" for k in range(len(names))] and len(names) >= 5, names
        for name in names:
            assert set(f["frames"][name]) == {"x", "v", "ids"}
            assert f["frames"][name]["x"].shape == (20000, 3)
            assert (f["frames"][name]["x"][...] == int(name)).all()


@pytest.mark.slow
def test_particles_h5_of_a_killed_run_resumes_to_the_uninterrupted_frames(tmp_path):
    """run --particles-h5 SIGKILLed after a checkpoint, then resumed: every frame once, the last one equal to an
    uninterrupted run's."""
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2),
                                           output={"fps": 50, "frames": 30})))
    ref = tmp_path / "ref.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(ref), "--particles-h5", "-q"]) == 0
    out = tmp_path / "o.usdc"
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--device", "cpu", "--out", str(out),
                             "--particles-h5", "--checkpoint-every", "4", "-q"], stderr=subprocess.PIPE, text=True)
    stats = out.with_suffix(".stats.csv")
    import time

    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and (not stats.exists() or len(stats.read_text().splitlines()) < 14):
        time.sleep(0.01)
    proc.kill()
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    with h5py.File(out.with_suffix(".particles.h5"), "r") as f:  # opens, frames 0..j
        names = sorted(f["frames"])
        assert names == [f"{k:06d}" for k in range(len(names))]
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "-q"]) == 0
    with h5py.File(out.with_suffix(".particles.h5"), "r") as f, h5py.File(ref.with_suffix(".particles.h5"), "r") as g:
        assert sorted(f["frames"]) == sorted(g["frames"]) == [f"{k:06d}" for k in range(31)]
        np.testing.assert_array_equal(f["frames/000030/x"][...], g["frames/000030/x"][...])
    assert not out.with_name("o.particles.h5.tmp").exists()
