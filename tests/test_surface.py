"""Surface meshes (#17): splashsurf's reconstruction of a sphere of particles, /World/FluidSurface in
the caches of ``warpsph run --surface`` (single file and --clips, and after SIGINT), ``warpsph
surface`` re-meshing a finished cache, and bad options refused before anything is written. The
tests that mesh need pysplashsurf (``warpsph[surface]``); the refusals run without it."""

import json
import os
import sys
import importlib.util
import time

import numpy as np
import pytest
import trimesh
from pxr import Usd

from conftest import interrupt_a_long_run, tank_scene
from warpsph.cli import main
from warpsph.surface import SurfaceOptions, boundary_edges, mesh_volume


def need_pysplashsurf():
    """Skips the test where pysplashsurf is missing (warpsph[surface]; the test extra installs it)."""
    pytest.importorskip("pysplashsurf", reason="surface meshes need pysplashsurf (warpsph[surface]; the test "
                                               "extra installs it)")


def lattice_sphere(radius, sphere):
    """Particles of radius ``radius`` on a cubic lattice 2 r apart inside a ball of radius ``sphere``."""
    g = np.arange(-sphere, sphere + 1e-9, 2 * radius)
    p = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return p[np.linalg.norm(p, axis=1) <= sphere]


def run_cli(*args):
    return main([*map(str, args), "--device", "cpu", "--quiet"])


def write_scene(tmp_path, data):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(data))
    return path


def small_scene(tmp_path, frames=3, **kw):
    data = tank_scene(radius=0.03, block=(0.2, 0.3, 0.2), models=[{"type": "micropolar"}],
                      output={"fps": 25, "frames": frames}, **kw)
    return write_scene(tmp_path, data)


def surface_frames(path):
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/World/FluidSurface")
    assert prim and prim.GetTypeName() == "Mesh"
    return stage, prim


@pytest.mark.parametrize("cube", [0.5, 0.75])
def test_a_sphere_of_particles_meshes_to_a_closed_surface_of_the_particles_volume(cube):
    need_pysplashsurf()
    from warpsph.surface import reconstruct

    r, sphere = 0.01, 0.2
    points = lattice_sphere(r, sphere)
    velocity = np.tile([1.0, -2.0, 0.5], (len(points), 1))
    mesh = reconstruct(points, r, velocity, np.full(len(points), 3.0), SurfaceOptions(cube=cube))
    assert_sphere_mesh(mesh, points, r, velocity, volume_tolerance=0.05)


def assert_sphere_mesh(mesh, points, r, velocity, volume_tolerance):
    """A sphere's mesh: closed (every edge has two triangles), the particles' volume N (2r)^3 within the
    tolerance, outward normals of unit length, velocity and vorticity magnitude (3) at the vertices."""
    assert boundary_edges(mesh.faces) == 0
    volume = len(points) * (2 * r) ** 3
    assert mesh_volume(mesh.points, mesh.faces) == pytest.approx(volume, rel=volume_tolerance)
    assert np.all(np.einsum("ij,ij->i", mesh.normals, mesh.points) > 0)
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-3)
    assert np.allclose(mesh.velocities, velocity[0], atol=1e-4)
    assert np.allclose(mesh.primvars["vorticity_magnitude"], 3.0, atol=1e-4)


def test_smoothing_length_and_cube_are_multiples_of_the_particle_radius():
    """pysplashsurf 0.14.1.0 reads them as multiples of the radius (its docstring of
    reconstruct_surface says absolute units): the mesh of a sphere scales with the sphere and the
    edges are about cube * r long."""
    need_pysplashsurf()
    from warpsph.surface import reconstruct

    r, sphere = 0.01, 0.2
    points = lattice_sphere(r, sphere)
    small = reconstruct(points, r)
    large = reconstruct(points * 10.0, r * 10.0)
    assert np.linalg.norm(small.points, axis=1).mean() == pytest.approx(sphere, abs=r)
    assert mesh_volume(large.points, large.faces) == pytest.approx(1000 * mesh_volume(small.points, small.faces), rel=1e-3)
    for cube in (0.5, 1.0):
        mesh = reconstruct(points, r, options=SurfaceOptions(cube=cube))
        edges = np.linalg.norm(mesh.points[mesh.faces[:, 0]] - mesh.points[mesh.faces[:, 1]], axis=1)
        assert 0.4 * cube * r < np.median(edges) < 1.5 * cube * r


def test_no_particles_give_an_empty_mesh():
    need_pysplashsurf()
    from warpsph.surface import reconstruct

    mesh = reconstruct(np.zeros((0, 3)), 0.01, np.zeros((0, 3)))
    assert mesh.points.shape == (0, 3) and mesh.faces.shape == (0, 3)


@pytest.mark.parametrize("clips", [False, True])
def test_a_run_with_surface_has_a_mesh_at_every_frame(tmp_path, clips):
    need_pysplashsurf()
    scene = small_scene(tmp_path)
    out = tmp_path / ("run.usda" if clips else "run.usdc")
    assert run_cli("run", scene, "--out", out, "--surface", *(["--clips"] if clips else [])) == 0
    stage, prim = surface_frames(out)
    points = stage.GetPrimAtPath("/World/Fluid").GetAttribute("points")
    assert len(points.GetTimeSamples()) == 4  # the particles stay
    assert prim.GetAttribute("subdivisionScheme").Get() == "none"
    for name in ("points", "faceVertexCounts", "faceVertexIndices", "normals", "extent", "velocities",
                 "primvars:vorticity_magnitude"):
        assert prim.GetAttribute(name).GetTimeSamples() == [0.0, 1.0, 2.0, 3.0], name
    for t in range(4):
        vertices = np.array(prim.GetAttribute("points").Get(t))
        indices = np.array(prim.GetAttribute("faceVertexIndices").Get(t)).reshape(-1, 3)
        counts = np.array(prim.GetAttribute("faceVertexCounts").Get(t))
        assert len(vertices) > 100 and len(counts) == len(indices) and np.all(counts == 3)
        assert indices.max() < len(vertices) and boundary_edges(indices) == 0
        assert len(prim.GetAttribute("normals").Get(t)) == len(vertices)
        assert len(prim.GetAttribute("velocities").Get(t)) == len(vertices)
        assert len(prim.GetAttribute("primvars:vorticity_magnitude").Get(t)) == len(vertices)
    if clips:
        for layer in sorted((tmp_path / "run.clips").glob("frame.*.usdc")):
            stage = Usd.Stage.Open(str(layer))
            assert len(stage.GetPrimAtPath("/World/FluidSurface").GetAttribute("points").GetTimeSamples()) == 1


def test_resume_keeps_meshing(tmp_path):
    need_pysplashsurf()
    scene = small_scene(tmp_path)
    out = tmp_path / "run.usdc"
    assert run_cli("run", scene, "--out", out, "--surface", "--checkpoint-every", "2", "--frames", "2") == 0
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "--frames", "3", "--quiet"]) == 0
    _, prim = surface_frames(out)
    assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]


SLOW_MESHER = """
import sys, time
from warpsph import surface
def slow_mesher(options, radius, device="cpu", workers=None, clip=None):  # in the run's process, so that the sleep holds
    def mesh(arrays):
        time.sleep(0.2)  # a slow mesher: the signal arrives while a frame is being meshed
        return surface.mesh_frame(arrays["x"], radius, arrays.get("v"), arrays.get("vorticity"), options, device, clip)
    return mesh
surface.mesher_for = slow_mesher
from warpsph.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_sigint_leaves_a_readable_cache_with_the_meshes_of_the_frames_done(tmp_path):
    need_pysplashsurf()
    out, code, err = interrupt_a_long_run(tmp_path, SLOW_MESHER, "--surface", pause=0.1)  # mid-mesh
    assert code == 130, err
    stage, prim = surface_frames(out)
    done = stage.GetPrimAtPath("/World/Fluid").GetAttribute("points").GetTimeSamples()
    assert len(done) >= 2 and done == [float(f) for f in range(len(done))]
    assert prim.GetAttribute("points").GetTimeSamples() == done
    assert prim.GetAttribute("faceVertexIndices").GetTimeSamples() == done
    assert f"holds frames 0..{len(done) - 1}" in err


@pytest.mark.parametrize("source", ["usdc", "clips", "h5"])
def test_surface_command_meshes_a_finished_cache_into_a_new_layer(tmp_path, source, capsys):
    need_pysplashsurf()
    scene = small_scene(tmp_path)
    out = tmp_path / ("run.usda" if source == "clips" else "run.usdc")
    extra = {"usdc": [], "clips": ["--clips"], "h5": ["--particles-h5"]}[source]
    assert run_cli("run", scene, "--out", out, *extra) == 0
    cache = out.with_suffix(".particles.h5") if source == "h5" else out
    before = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*") if p.is_file()}
    assert main(["surface", str(cache), "--frames", "1", "3", "--cube", "1.0", "--quiet"]) == 0
    new = tmp_path / "run.surface.usdc"
    assert {p: p.stat().st_mtime_ns for p in before} == before  # the cache is untouched
    stage, prim = surface_frames(new)
    assert prim.GetAttribute("points").GetTimeSamples() == [1.0, 2.0, 3.0]
    assert stage.GetPrimAtPath("/World/Fluid").GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    assert len(prim.GetAttribute("velocities").Get(2)) == len(prim.GetAttribute("points").Get(2)) > 50
    assert len(prim.GetAttribute("primvars:vorticity_magnitude").Get(2)) == len(prim.GetAttribute("points").Get(2))
    del stage, prim  # USD's layer registry would hand back the layer held open
    # a second time: refused without --overwrite, replaced with it
    assert main(["surface", str(cache), "--quiet"]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["surface", str(cache), "--quiet", "--overwrite"]) == 0
    _, prim = surface_frames(new)
    assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]


def _files(folder):
    return sorted(p.relative_to(folder) for p in folder.rglob("*"))


@pytest.mark.parametrize("option, value", [("--surface-cube", "0"), ("--surface-cube", "-1"),
                                           ("--surface-smoothing", "0"), ("--surface-cube", "nan")])
def test_bad_surface_options_of_run_are_refused_before_anything_is_written(tmp_path, capsys, option, value):
    scene = small_scene(tmp_path)
    before = _files(tmp_path)
    assert run_cli("run", scene, "--out", tmp_path / "x.usdc", "--surface", option, value) == 2
    err = capsys.readouterr().err
    assert f"warpsph: error: {option}:" in err and "Traceback" not in err
    assert _files(tmp_path) == before


def test_missing_pysplashsurf_is_a_clear_error_and_writes_nothing(tmp_path, capsys, monkeypatch):
    scene = small_scene(tmp_path)
    assert run_cli("run", scene, "--out", tmp_path / "a.usdc") == 0
    monkeypatch.setitem(sys.modules, "pysplashsurf", None)  # import pysplashsurf raises ImportError
    before = _files(tmp_path)
    assert run_cli("run", scene, "--out", tmp_path / "x.usdc", "--surface") == 2
    err = capsys.readouterr().err
    assert "warpsph: error: --surface: " in err and "pip install 'warpsph[surface]'" in err
    assert main(["surface", str(tmp_path / "a.usdc")]) == 2
    err = capsys.readouterr().err
    assert "warpsph: error: surface: " in err and "pysplashsurf" in err and "Traceback" not in err
    assert _files(tmp_path) == before


@pytest.mark.parametrize("args, option", [(["--cube", "0"], "--cube"), (["--cube", "-0.5"], "--cube"),
                                          (["--smoothing", "0"], "--smoothing"),
                                          (["--frames", "2", "9"], "--frames"), (["--frames", "3", "1"], "--frames"),
                                          (["--frames", "-1", "2"], "--frames"), (["--radius", "0"], "--radius"),
                                          (["--out", "{tmp}/a.usdc"], "--out"), (["--out", "{tmp}/m.txt"], "--out")])
def test_bad_options_of_surface_are_refused_before_anything_is_written(tmp_path, capsys, monkeypatch, args, option):
    monkeypatch.setitem(sys.modules, "pysplashsurf", sys.modules.get("pysplashsurf") or object())  # present or not
    scene = small_scene(tmp_path)
    assert run_cli("run", scene, "--out", tmp_path / "a.usdc") == 0
    capsys.readouterr()
    before = _files(tmp_path)
    assert main(["surface", str(tmp_path / "a.usdc"), *[a.format(tmp=tmp_path) for a in args]]) == 2
    err = capsys.readouterr().err
    assert f": {option}: " in err and "Traceback" not in err, err
    assert _files(tmp_path) == before


def test_surface_of_a_file_that_is_not_a_cache_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pysplashsurf", sys.modules.get("pysplashsurf") or object())
    (tmp_path / "notes.usdc").write_text("hello")
    assert main(["surface", str(tmp_path / "notes.usdc")]) == 2
    assert "not a warpsph point cache" in capsys.readouterr().err
    assert main(["surface", str(tmp_path / "missing.usdc")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert _files(tmp_path) == [__import__("pathlib").Path("notes.usdc")]


# --- the preview method (Warp's sparse marching cubes), --surface-every and --surface-behind


@pytest.mark.parametrize("cube", [0.75, 1.0])
def test_the_preview_of_a_sphere_of_particles_is_closed_and_holds_the_particles_volume(cube):
    from warpsph.surface import reconstruct_preview

    r, sphere = 0.01, 0.2
    points = lattice_sphere(r, sphere)
    velocity = np.tile([1.0, -2.0, 0.5], (len(points), 1))
    mesh = reconstruct_preview(points, r, velocity, np.full(len(points), 3.0),
                               SurfaceOptions(method="preview", cube=cube), device="cpu")
    assert len(mesh.faces) > 1000
    assert_sphere_mesh(mesh, points, r, velocity, volume_tolerance=0.10)
    assert np.linalg.norm(mesh.points, axis=1).mean() == pytest.approx(sphere, abs=1.5 * r)


def test_the_preview_of_no_particles_is_empty():
    from warpsph.surface import reconstruct_preview

    mesh = reconstruct_preview(np.zeros((0, 3)), 0.01, np.zeros((0, 3)), options=SurfaceOptions(method="preview"))
    assert mesh.points.shape == (0, 3) and mesh.faces.shape == (0, 3)


@pytest.mark.slow
@pytest.mark.parametrize("clips", [False, True])
def test_a_run_with_the_preview_surface_needs_no_pysplashsurf(tmp_path, clips, monkeypatch):
    monkeypatch.setitem(sys.modules, "pysplashsurf", None)
    scene = small_scene(tmp_path)
    out = tmp_path / ("run.usda" if clips else "run.usdc")
    assert run_cli("run", scene, "--out", out, "--surface", "--surface-method", "preview",
                   *(["--clips"] if clips else [])) == 0
    stage, prim = surface_frames(out)
    assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    for t in range(4):
        indices = np.array(prim.GetAttribute("faceVertexIndices").Get(t)).reshape(-1, 3)
        assert len(indices) > 100 and boundary_edges(indices) == 0
        assert len(prim.GetAttribute("velocities").Get(t)) == len(prim.GetAttribute("points").Get(t))
    note = stage.GetRootLayer().customLayerData["warpsph:surface"]
    assert note["method"] == "preview" and note["meshed"] == 4 and note["skipped"] == 0


@pytest.mark.parametrize("clips", [False, True])
def test_surface_every_k_meshes_every_kth_frame_and_the_mesh_holds_between(tmp_path, clips, capsys):
    need_pysplashsurf()
    scene = small_scene(tmp_path, frames=5)
    out = tmp_path / ("run.usda" if clips else "run.usdc")
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--surface", "--surface-every", "2",
                 *(["--clips"] if clips else [])]) == 0  # not --quiet: the surface line is an info line
    assert "in 3 frames (every 2-th frame)" in capsys.readouterr().err
    stage, prim = surface_frames(out)
    assert stage.GetPrimAtPath("/World/Fluid").GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 2.0, 4.0]
    for held, meshed in ((1, 0), (3, 2), (5, 4)):
        for name in ("points", "faceVertexIndices", "normals"):
            assert np.array_equal(np.array(prim.GetAttribute(name).Get(held)), np.array(prim.GetAttribute(name).Get(meshed)))
    note = stage.GetRootLayer().customLayerData["warpsph:surface"]
    assert note["every"] == 2 and note["meshed"] == 3 and note["skipped"] == 0 and "holds the mesh" in note["note"]


def test_surface_workers_sets_how_many_frames_splashsurf_meshes_at_once(tmp_path):
    need_pysplashsurf()
    scene = small_scene(tmp_path, frames=3)
    for workers in (2, 3):
        out = tmp_path / f"run{workers}.usdc"
        assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--surface", "--surface-workers",
                     str(workers), "--quiet"]) == 0
        stage, prim = surface_frames(out)
        note = stage.GetRootLayer().customLayerData["warpsph:surface"]
        assert note["workers"] == workers and note["meshed"] == 4
        assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]


SLOW = 0.6


@pytest.mark.slow
@pytest.mark.parametrize("behind", ["skip", "wait"])
def test_a_mesher_behind_the_simulation_skips_frames_or_waits(tmp_path, monkeypatch, capsys, behind):
    """A mesher slower than the simulation: skip meshes what it can and never holds the run up
    (frames skipped are counted and listed in the metadata); wait meshes every frame."""
    need_pysplashsurf()
    from warpsph import cli, surface

    def slow_mesher(options, radius, device="cpu", workers=None, clip=None):  # in this process, so that the sleep holds
        def mesh(arrays):
            time.sleep(SLOW)
            return surface.mesh_frame(arrays["x"], radius, arrays.get("v"), arrays.get("vorticity"), options, device,
                                      clip)
        return mesh

    monkeypatch.setattr(surface, "mesher_for", slow_mesher)
    scene = small_scene(tmp_path, frames=8)
    out = tmp_path / "run.usdc"
    assert run_cli("run", scene, "--out", out, "--surface", "--surface-behind", behind) == 0
    err = capsys.readouterr().err
    stage, prim = surface_frames(out)
    meshed = [int(t) for t in prim.GetAttribute("points").GetTimeSamples()]
    note = stage.GetRootLayer().customLayerData["warpsph:surface"]
    run = cli.last_run
    if behind == "wait":
        assert meshed == list(range(9)) and note["skipped"] == 0
        assert run["writer_waited"] > 0  # the simulation waited for the mesher
        assert "--surface-every" in err
    else:
        skipped = list(note["skipped_frames"])
        assert 0 in meshed and skipped and sorted(meshed + skipped) == list(range(9))
        assert note["skipped"] == len(skipped) == len(run["surface_skipped"]) and note["meshed"] == len(meshed)
        assert f"{len(skipped)} frames skipped" in err and "skipped because the mesher was behind" in note["note"]
        assert run["writer_waited"] < SLOW  # at most one frame's meshing queued: the run never waits for it
        for t in skipped:  # a skipped frame holds the mesh before it
            before = max(m for m in meshed if m < t)
            assert len(prim.GetAttribute("points").Get(t)) == len(prim.GetAttribute("points").Get(before))


@pytest.mark.parametrize("method", ["splashsurf", "preview"])
def test_a_run_meshes_in_a_worker_process_of_its_own(method):
    """pysplashsurf holds the GIL while it meshes, and Warp's current device is process-wide: a run's
    meshes are made in a spawned worker process, and equal the meshes made here. The arrays go both ways
    through files in the mesher's folder (in /dev/shm where there is one), removed after each frame and
    with the mesher: the preview's mesh (deterministic) comes back bit for bit."""
    if method == "splashsurf":
        need_pysplashsurf()
    from warpsph.io.processes import exchange_root as _exchange_root
    from warpsph.surface import mesh_frame, mesher_for

    r = 0.02
    x = lattice_sphere(r, 0.3).astype(np.float32)
    v = np.random.default_rng(0).normal(size=x.shape).astype(np.float32)
    vorticity = np.random.default_rng(1).normal(size=x.shape).astype(np.float32)
    options = SurfaceOptions(method=method)
    mesher = mesher_for(options, r, workers=2)
    try:
        assert os.path.dirname(mesher.folder) == (_exchange_root() or __import__("tempfile").gettempdir())
        mesh = mesher({"x": x, "v": v, "vorticity": vorticity})
        assert os.listdir(mesher.folder) == []  # the frame's files are gone
    finally:
        mesher.close()
    assert not os.path.exists(mesher.folder)
    assert mesher.worker_pid is not None and mesher.worker_pid != os.getpid()
    here = mesh_frame(x, r, v, vorticity, options)
    assert len(mesh.faces) > 100 and np.array_equal(mesh.faces, here.faces)
    if method == "preview":  # splashsurf's sums depend on its thread count (the worker's share of the cores)
        for name in ("points", "faces", "normals", "velocities"):
            got, want = getattr(mesh, name), getattr(here, name)
            assert got.dtype == want.dtype and got.shape == want.shape and got.tobytes() == want.tobytes(), name
        assert mesh.primvars.keys() == here.primvars.keys() == {"vorticity_magnitude"}
        assert mesh.primvars["vorticity_magnitude"].tobytes() == here.primvars["vorticity_magnitude"].tobytes()
    np.testing.assert_allclose(mesh.points, here.points, atol=1e-6)
    np.testing.assert_allclose(mesh.velocities, here.velocities, atol=1e-5)


def test_a_mesh_that_fails_in_the_worker_raises_here_and_leaves_no_files():
    """The worker's exception comes back (BackgroundMesher then stops the run naming the frame) and the
    frame's files in the mesher's folder are removed; closing removes the folder."""
    from warpsph.surface import ProcessMesher

    mesher = ProcessMesher(SurfaceOptions(method="preview"), "not a radius")
    x = lattice_sphere(0.02, 0.1).astype(np.float32)
    try:
        with pytest.raises(ValueError, match="could not convert string to float"):
            mesher({"x": x, "v": np.zeros_like(x)})
        assert os.listdir(mesher.folder) == []
    finally:
        mesher.close()
    assert not os.path.exists(mesher.folder)


@pytest.mark.slow
def test_the_worker_writes_a_clips_frame_s_mesh_into_its_layer_as_the_run_s_process_would(tmp_path):
    """With --clips the worker writes the mesh into the frame's layer itself (the run's process neither reads
    the mesh nor writes it): the layer is the one the run's process would write, and the cache takes the
    mesh that comes back (without arrays) as written."""
    from pxr import Sdf

    from warpsph.io.usd import UsdClipCache, write_surface_layer
    from warpsph.surface import mesh_frame, mesher_for

    r = 0.02
    x = lattice_sphere(r, 0.3).astype(np.float32)
    v = np.random.default_rng(0).normal(size=x.shape).astype(np.float32)
    options = SurfaceOptions(method="preview")  # deterministic: the same mesh in both processes
    caches = {name: UsdClipCache(tmp_path / name / "run.usda", 25) for name in ("worker", "here")}
    for cache in caches.values():
        cache.write_frame(3, x, v, None, r)
    layer = caches["worker"].surface_layer(3)
    mesher = mesher_for(options, r)
    try:
        mesh = mesher({"x": x, "v": v, "layer": (layer, 3)})
    finally:
        mesher.close()
    assert mesh.layer == layer and len(mesh.points) == 0 and mesh.seconds > 0
    written = os.stat(layer).st_mtime_ns
    caches["worker"].write_surface(3, mesh)  # there already: not written again
    assert os.stat(layer).st_mtime_ns == written
    write_surface_layer(caches["here"].surface_layer(3), 3, mesh_frame(x, r, v, None, options))
    text = {name: Sdf.Layer.FindOrOpen(cache.surface_layer(3)).ExportToString() for name, cache in caches.items()}
    assert text["worker"] == text["here"] and "FluidSurface" in text["here"]


def test_mesher_workers_run_below_the_simulation_s_cpu_priority():
    """The simulation's host thread feeds the GPU: on a busy CPU the meshing workers yield to it."""
    from warpsph.io.processes import WORKER_NICENESS
    from warpsph.surface import ProcessMesher

    mesher = ProcessMesher(SurfaceOptions(method="preview"), 0.02)
    try:
        niceness = mesher.pool.submit(os.nice, 0).result()
    finally:
        mesher.close()
    assert niceness >= min(19, os.nice(0) + WORKER_NICENESS)


def test_a_mesh_function_with_two_workers_meshes_two_frames_at_once():
    """Meshing one 1M-particle frame takes longer than simulating one: the background mesher keeps as many
    frames in flight as its mesh function has workers (both calls below must run together to pass the barrier)."""
    import threading

    from warpsph.surface import BackgroundMesher, SurfaceMesh

    class TwoWorkers:
        workers = 2
        barrier = threading.Barrier(2, timeout=20)

        def __call__(self, arrays):
            self.barrier.wait()
            mesh = SurfaceMesh.empty(False)
            mesh.seconds = 0.0
            return mesh

    mesher = BackgroundMesher(TwoWorkers(), depth=2)
    assert mesher.submit(0, {"x": np.zeros((1, 3), np.float32)}) and mesher.submit(1, {"x": np.zeros((1, 3), np.float32)})
    done = sorted(frame for frame, _ in mesher.close())
    assert done == [0, 1] and mesher.error is None


def test_surface_command_with_the_preview_method(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pysplashsurf", None)
    scene = small_scene(tmp_path)
    out = tmp_path / "run.usdc"
    assert run_cli("run", scene, "--out", out) == 0
    assert main(["surface", str(out), "--method", "preview", "--quiet"]) == 0
    _, prim = surface_frames(tmp_path / "run.surface.usdc")
    assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    assert boundary_edges(np.array(prim.GetAttribute("faceVertexIndices").Get(2)).reshape(-1, 3)) == 0


@pytest.mark.parametrize("option, value", [("--surface-every", "0"), ("--surface-every", "-2"),
                                           ("--surface-workers", "-1")])
def test_bad_surface_every_is_refused_before_anything_is_written(tmp_path, capsys, option, value):
    scene = small_scene(tmp_path)
    before = _files(tmp_path)
    assert run_cli("run", scene, "--out", tmp_path / "x.usdc", "--surface", "--surface-method", "preview",
                   option, value) == 2
    err = capsys.readouterr().err
    assert f"warpsph: error: {option}:" in err and "Traceback" not in err
    assert _files(tmp_path) == before


def test_vt_arrays_filled_outside_the_gil_equal_from_numpy():
    """write_surface fills new Vt arrays through their storage's address (FromNumpy holds the GIL); should a
    usd-core export a copy instead of the storage, the arrays would come out unfilled: they equal FromNumpy's."""
    from pxr import Vt

    from warpsph.io.usd import _vt_array

    rng = np.random.default_rng(0)
    for kind, values in ((Vt.Vec3fArray, rng.random((1001, 3), dtype=np.float32)),
                         (Vt.FloatArray, rng.random(1002, dtype=np.float32)),
                         (Vt.IntArray, rng.integers(-2**31, 2**31 - 1, 3003, dtype=np.int32)),
                         (Vt.Vec3fArray, np.zeros((0, 3), np.float32))):
        array = _vt_array(kind, values)
        assert type(array) is kind and array == kind.FromNumpy(values)
        assert np.asarray(array).tobytes() == values.tobytes()


def test_mesh_quality_of_boxes_is_exact():
    """mesh_quality (#42) on shapes whose numbers are known: a unit box's 12 right triangles (area 6, volume 1,
    smallest angles 45 degrees, closed); its distance to a box 1.2 across is 0.1 from every vertex, 0.1 sqrt(3)
    from the big box's corners back; a walled face at x = 0.3 leaves the box 0.2 outside; a needle is a sliver."""

    from warpsph.surface import SurfaceClip, mesh_quality

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    q = mesh_quality(box, trimesh.creation.box(extents=(1.2, 1.2, 1.2)), radius=0.1,
                     clip=SurfaceClip(hi=(0.3, np.inf, np.inf)))
    assert (q["vertices"], q["faces"], q["watertight"], q["winding_consistent"]) == (8, 12, True, True)
    assert q["boundary_edges"] == 0
    assert q["area"] == pytest.approx(6.0) and q["volume"] == pytest.approx(1.0)
    assert q["sliver_fraction"] == 0.0 and q["min_angle_median"] == pytest.approx(45.0)
    assert q["distance_mean"] == pytest.approx(1.0, rel=1e-5) and q["distance_max"] == pytest.approx(1.0, rel=1e-5)
    assert q["reverse_max"] == pytest.approx(np.sqrt(3.0), rel=1e-5)
    assert q["reverse_over_1r"] == 1.0
    assert q["outside_walls_max"] == pytest.approx(2.0, rel=1e-6)
    needle = (np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.01, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 1, 3]]))
    q = mesh_quality(needle)
    assert (q["watertight"], q["boundary_edges"], q["sliver_fraction"]) == (False, 4, 0.5)


def sphere_quality(mesh, points, r):
    """mesh_quality of a lattice sphere's mesh against the sphere of the particles' volume N (2r)^3."""

    from warpsph.surface import SurfaceClip, mesh_quality

    equal = (3 * len(points) * (2 * r) ** 3 / (4 * np.pi)) ** (1 / 3)
    q = mesh_quality(mesh, trimesh.creation.icosphere(subdivisions=5, radius=equal), radius=r,
                     clip=SurfaceClip(hi=(np.inf, 0.15, np.inf)))
    assert (q["watertight"], q["winding_consistent"], q["boundary_edges"]) == (True, True, 0)
    assert q["outside_walls_max"] == pytest.approx((mesh.points[:, 1].max() - 0.15) / r, rel=1e-5)
    return q, 4 * np.pi * equal ** 2, 4 / 3 * np.pi * equal ** 3


def test_mesh_quality_of_the_preview_of_a_sphere_of_particles():
    """The preview (marching cubes, cube 0.75 r, 25 steps of Taubin smoothing) of 4163 particles in a ball 20 r
    across: closed, the sphere's area and volume (measured +4.2 % / +0.9 %), no slivers (smallest angle < 10
    degrees; 12 % unsmoothed: marching cubes cuts cells near their corners), 0.25 r from the sphere on average
    and 0.77 r at most."""
    from warpsph.surface import reconstruct_preview

    r, sphere = 0.01, 0.2
    points = lattice_sphere(r, sphere)
    mesh = reconstruct_preview(points, r, options=SurfaceOptions(method="preview"), device="cpu")
    q, area, volume = sphere_quality(mesh, points, r)
    assert q["area"] == pytest.approx(area, rel=0.063) and q["volume"] == pytest.approx(volume, rel=0.015)
    assert q["sliver_fraction"] < 0.005
    assert q["distance_mean"] < 0.37 and q["distance_max"] < 1.15 and q["reverse_max"] < 1.15
    assert q["distance_over_1r"] == 0.0 and q["reverse_over_1r"] == 0.0
    raw = reconstruct_preview(points, r, options=SurfaceOptions(method="preview", smoothing_iters=0), device="cpu")
    assert 0.08 < sphere_quality(raw, points, r)[0]["sliver_fraction"] < 0.32  # 0.12 measured


def sparse_particles(r):
    """A slab of fluid 8 layers deep, a sheet of 400 particles 3 r apart above it and 60 droplets of one particle."""
    slab = np.mgrid[0:30, 0:8, 0:30].reshape(3, -1).T * 2 * r
    sheet = np.mgrid[0:20, 0:20].reshape(2, -1).T * 3 * r
    sheet = np.c_[sheet[:, 0], np.full(len(sheet), 30 * r), sheet[:, 1]]
    drops = np.random.default_rng(1).uniform([0, 40 * r, 0], [60 * r, 60 * r, 60 * r], (60, 3))
    return np.concatenate([slab, sheet, drops]).astype(np.float32), len(slab), len(sheet)


def test_the_preview_wraps_sparse_fluid_as_splashsurf_does():
    """Each particle's volume comes from its neighbours (1 / sum_k W_jk, splashsurf's m / rho_j): the sheet and every
    droplet get a closed mesh around them. With the rest volume (2 r)^3 a lone particle's field peaks at 1/pi, under
    any iso value, and the sheet's at about 0.4: both were left out (43 % of splashsurf's vertices more than 1 r from
    the preview's mesh)."""
    from warpsph.surface import reconstruct_preview

    r = 0.01
    points, slab, sheet = sparse_particles(r)
    mesh = reconstruct_preview(points, r, options=SurfaceOptions(method="preview"), device="cpu")
    assert boundary_edges(mesh.faces) == 0
    above = points[slab:]  # the sheet and the droplets: each has mesh vertices around it, about 1.1 r away
    nearest = np.array([np.linalg.norm(mesh.points - p, axis=1).min() for p in above])
    assert nearest.max() < 1.5 * r  # measured 1.08 r; with the rest volume the droplets had none within 10 r
    assert mesh.points[:, 1].max() > points[:, 1].max()  # the highest droplet has its mesh
    if importlib.util.find_spec("pysplashsurf"):
        from warpsph.surface import mesh_quality, reconstruct

        reference = reconstruct(points, r)
        q = mesh_quality(mesh, trimesh.Trimesh(reference.points, reference.faces), radius=r)
        assert q["reverse_over_1r"] < 0.003 and q["distance_mean"] < 0.15  # measured 0.000 and 0.10 r


def test_mesh_quality_of_splashsurf_s_sphere_of_particles():
    """splashsurf's mesh of the same ball: closed, the sphere's area and volume (measured -1.2 % / -2.2 %), no slivers
    (its cleanup and smoothing), 0.15 r from the sphere on average and 0.60 r at most."""
    need_pysplashsurf()
    from warpsph.surface import reconstruct

    r, sphere = 0.01, 0.2
    points = lattice_sphere(r, sphere)
    q, area, volume = sphere_quality(reconstruct(points, r), points, r)
    assert q["area"] == pytest.approx(area, rel=0.02) and q["volume"] == pytest.approx(volume, rel=0.035)
    assert q["sliver_fraction"] < 0.005
    assert q["distance_mean"] < 0.23 and q["distance_max"] < 0.9 and q["reverse_max"] < 0.9


def test_the_device_mesher_meshes_the_simulation_s_own_arrays_between_steps(tmp_path, device):
    """A run on a GPU meshes its frames on its own device (DeviceMesher, the default there): from the particles'
    device arrays, the same surface as the preview of the frame's host arrays, clipped to the walls, with the
    vorticity magnitude; a frame it was not asked for gets no mesh."""
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation
    from warpsph.surface import DeviceMesher, mesh_volume, reconstruct_preview, surface_clip

    scene = load_scene(small_scene(tmp_path))
    sim = Simulation(scene, device=device)
    sim.run(frames=2)
    options = SurfaceOptions(method="preview")
    clip = surface_clip(scene.domain)
    mesher = DeviceMesher(options, scene.particle_radius, clip=clip, every=2)
    mesher.mesh_now(sim, 1)  # not every 2nd: nothing
    mesher.mesh_now(sim, 2)
    assert not mesher.submit(1, {}) and mesher.submit(2, {})
    [(frame, mesh)] = mesher.ready()
    host = reconstruct_preview(sim.positions(), scene.particle_radius, sim.velocities(),
                               sim.field_values("vorticity"), options, device)
    assert frame == 2 and len(mesh.faces) > 100 and boundary_edges(mesh.faces) == 0
    assert len(mesh.points) == len(host.points) and len(mesh.faces) == len(host.faces)
    clamped = np.clip(host.points, np.array(clip.lo)[None], np.array(clip.hi)[None])  # the host's, clipped
    assert mesh_volume(mesh.points, mesh.faces) == pytest.approx(mesh_volume(clamped, host.faces), rel=1e-4)
    lo, hi = np.array(clip.lo), np.array(clip.hi)
    assert (mesh.points >= lo[None] - 1e-6).all() and (mesh.points <= hi[None] + 1e-6).all()
    assert host.points.max(axis=0)[0] > hi[0] or host.points.min(axis=0)[1] < lo[1]  # the host's is unclipped
    assert mesh.primvars["vorticity_magnitude"].shape == (len(mesh.points),)
    assert mesh.primvars["vorticity_magnitude"].max() > 0 and len(mesh.velocities) == len(mesh.points)
    assert mesher.note(options)["meshed"] == 1


def test_the_device_mesher_writes_a_clips_frame_s_mesh_into_its_layer_from_a_process_of_its_own(tmp_path, device):
    """In a --clips cache the device mesher's meshes go into their frame layers from a process of its own (pxr's
    layer save holds the GIL): the layer holds the mesh beside the particles, the main process gets it back
    without its arrays, and nothing is left of the arrays' files."""
    import os

    from warpsph.io.usd import UsdClipCache
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation
    from warpsph.surface import DeviceMesher

    scene = load_scene(small_scene(tmp_path))
    sim = Simulation(scene, device=device)
    sim.run(frames=1)
    cache = UsdClipCache(tmp_path / "run.usda", 25)
    x = sim.positions()
    cache.write_frame(1, x, sim.velocities(), np.arange(len(x)), scene.particle_radius)
    mesher = DeviceMesher(SurfaceOptions(method="preview"), scene.particle_radius)
    mesher.mesh_now(sim, 1)
    assert mesher.submit(1, {"layer": (cache.surface_layer(1), 1)})
    [(frame, mesh)] = mesher.close()
    assert frame == 1 and mesh.layer == cache.surface_layer(1) and len(mesh.points) == 0
    assert mesher.pool is None and not os.path.exists(mesher.folder)
    stage = Usd.Stage.Open(cache.surface_layer(1))
    faces = np.array(stage.GetPrimAtPath("/World/FluidSurface").GetAttribute("faceVertexIndices").Get(1)).reshape(-1, 3)
    assert len(faces) > 100 and boundary_edges(faces) == 0
    assert len(stage.GetPrimAtPath("/World/Fluid").GetAttribute("points").Get(1)) == len(x)


def test_the_device_mesher_meshes_the_frame_s_particles_while_the_simulation_steps_on(tmp_path, device):
    """The device mesher copies the frame's particles and runs its stages between the following steps (on a GPU on
    a stream of its own, each stage launched once the numbers it reads back are there: advance() never waits): the
    mesh is the preview of the particles at the frame, not of where they are when it is done."""
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation
    from warpsph.surface import DeviceMesher, reconstruct_preview

    scene = load_scene(small_scene(tmp_path))
    sim = Simulation(scene, device=device)
    sim.run(frames=2)
    options = SurfaceOptions(method="preview")
    at_frame = (sim.positions(), sim.velocities())
    mesher = DeviceMesher(options, scene.particle_radius)
    mesher.mesh_now(sim, 2)
    for _ in range(5):
        sim.step()
        mesher.advance(sim)
    assert np.abs(sim.positions() - at_frame[0]).max() > 1e-4  # the particles moved on
    assert mesher.submit(2, {})
    [(frame, mesh)] = mesher.ready()
    host = reconstruct_preview(at_frame[0], scene.particle_radius, at_frame[1], None, options, device)
    assert frame == 2 and len(mesh.faces) == len(host.faces) > 100
    np.testing.assert_allclose(mesh.points, host.points, atol=1e-6)


@pytest.mark.skipif(not __import__("warp").is_cuda_available(), reason="needs a CUDA device (the GPU's default mesher)")
def test_a_run_on_the_gpu_meshes_with_the_preview_on_its_device_by_default(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pysplashsurf", None)
    scene = small_scene(tmp_path)
    out = tmp_path / "run.usdc"
    assert main(["run", str(scene), "--out", str(out), "--surface", "--device", "cuda:0", "--quiet"]) == 0
    stage, prim = surface_frames(out)
    assert prim.GetAttribute("points").GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    note = stage.GetRootLayer().customLayerData["warpsph:surface"]
    assert note["method"] == "preview" and note["meshed"] == 4
