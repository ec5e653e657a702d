"""Reliability: output safety, interruption and resume, instability policy, memory, devices, meshes."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh
import warp as wp
from pxr import Usd, UsdGeom

from warpsph import SceneError, load_scene
from warpsph.scene import scene_from_dict
from warpsph.cli import main
from conftest import as_in_a_terminal, signal_group, tank_scene


def write_scene(tmp_path, data, name="scene.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def time_samples(path):
    stage = Usd.Stage.Open(str(path))
    return UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr().GetTimeSamples()


def test_existing_output_is_refused_unless_overwrite(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 1}))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet"]) == 0
    assert out.exists() and not (tmp_path / "o.partial.usdc").exists()  # renamed when complete
    stamp = out.stat().st_mtime_ns
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert out.stat().st_mtime_ns == stamp
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet", "--overwrite"]) == 0


def test_dry_run_prints_the_estimate_and_writes_nothing(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.02))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "1000 fluid" in text and "MiB" in text
    assert not list(tmp_path.glob("o*"))


def test_a_scene_too_large_for_the_device_is_refused_before_allocation(tmp_path, monkeypatch, capsys):
    import warpsph.resources as resources

    scene = write_scene(tmp_path, tank_scene(radius=0.02))
    need = resources.estimate_bytes(scene_from_dict(tank_scene(radius=0.02)), 1000, 0)
    monkeypatch.setattr(resources, "free_bytes", lambda device: need // 2)  # the tank has ~1000 particles
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "particle_radius" in err and "GiB" in err and "free" in err
    assert not out.exists()


def test_cuda_without_a_gpu_says_so(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(wp, "is_cuda_available", lambda: False)
    scene = write_scene(tmp_path, tank_scene(radius=0.05))
    assert main(["run", str(scene), "--device", "cuda", "--out", str(tmp_path / "o.usdc")]) == 2
    assert "--device cpu" in capsys.readouterr().err
    from warpsph.cli import _pick_device

    assert _pick_device("auto") == "cpu"


CRASH = {"name": "crash", "particle_radius": 0.04, "domain": {"min": [0, 0, 0], "max": [1.0, 0.6, 0.4]},
         "gravity": [0, 0, 0], "fluid_blocks": [{"start": [0.3, 0.1, 0.05], "end": [0.6, 0.4, 0.35], "velocity": [8, 0, 0]}],
         "time": {"fixed_dt": 0.04}, "output": {"fps": 25, "frames": 4}}


def test_instability_stops_with_a_diagnostic_and_keeps_the_frames(tmp_path, capsys):
    scene = write_scene(tmp_path, CRASH)
    out = tmp_path / "crash.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet"]) == 3
    err = capsys.readouterr().err
    # the walls hold the particles (test_walls_hold_particles_at_any_speed); they pile up against x = 1
    assert "unstable at step" in err and "density above" in err and "particle id" in err
    assert time_samples(out)[0] == 0.0  # the frames done are kept, under the final name


def test_walls_hold_particles_at_any_speed():
    """A block thrown at a wall at 8 m/s with a fixed step of two particle spacings: no particle crosses a wall
    (before, they tunnelled through the wall layer to x = 2.1 m and y = -1.7 m)."""
    from conftest import make_sim

    sim = make_sim({**CRASH, "time": {"fixed_dt": 0.02}})
    for _ in range(10):
        sim.step()
    x = sim.fluid.x.numpy()
    assert np.isfinite(x).all()
    assert (x >= 0.0).all() and (x <= np.float32([1.0, 0.6, 0.4])).all()
    assert x[:, 0].max() > 0.99  # it did reach the wall


def test_reduce_dt_retries_the_unstable_step(tmp_path):
    scene = write_scene(tmp_path, CRASH)
    out = tmp_path / "crash.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet", "--on-instability", "reduce-dt"]) == 0
    assert time_samples(out) == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_nan_is_caught_on_the_step_it_appears():
    from conftest import make_sim
    from warpsph.simulation import InstabilityError

    sim = make_sim(tank_scene(radius=0.05))
    x = sim.fluid.x.numpy().copy()
    x[3] = np.nan
    sim.fluid.x.assign(x)
    with pytest.raises(InstabilityError, match="NaN"):
        sim.run(frames=1)


def test_density_runaway_and_solver_streak_are_caught(monkeypatch):
    import warpsph.health as health
    from conftest import make_sim
    from warpsph.simulation import InstabilityError

    monkeypatch.setattr(health, "DENSITY_HARD_LIMIT", 0.5)  # every particle is "too dense"
    sim = make_sim(tank_scene(radius=0.05))
    with pytest.raises(InstabilityError, match="density above"):
        sim.run(frames=1)
    monkeypatch.setattr(health, "DENSITY_HARD_LIMIT", 1.5)
    monkeypatch.setattr(health, "MAX_ITERATION_STREAK", 3)
    sim = make_sim(tank_scene(radius=0.03, solver={"min_iterations": 0, "max_iterations": 1,
                                                   "density_max_error": 1e-6}))
    with pytest.raises(InstabilityError, match="density solver hit max_iterations 3 steps in a row"):
        sim.run(frames=2)


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_finishes_the_frame_saves_and_resume_completes(tmp_path, signum, code):
    data = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 50, "frames": 400})
    scene = write_scene(tmp_path, data)
    out = tmp_path / "long.usdc"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--device", "cpu", "--out", str(out),
                             "--particles-h5"],
                            stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    stats = out.with_suffix(".stats.csv")
    deadline = time.time() + 120
    while time.time() < deadline and (not stats.exists() or len(stats.read_text().splitlines()) < 4):
        time.sleep(0.2)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err
    assert signal.Signals(signum).name in err and "resume" in err
    checkpoint = out.with_suffix(".checkpoint.h5")
    assert checkpoint.exists() and out.exists()
    done = time_samples(out)
    assert done == [float(f) for f in range(len(done))] and 3 <= len(done) < 401
    rows = len(stats.read_text().splitlines())
    assert main(["resume", str(checkpoint), "--device", "cpu", "--frames", str(len(done) + 1), "--quiet"]) == 0
    assert time_samples(out) == [float(f) for f in range(len(done) + 2)]
    assert len(stats.read_text().splitlines()) == rows + 2
    import h5py

    with h5py.File(out.with_suffix(".particles.h5"), "r") as f:  # the frame data went on after the resume
        assert sorted(f["frames"]) == [f"{n:06d}" for n in range(len(done) + 2)]
        last = f["frames"][f"{len(done) + 1:06d}"]
        assert last["x"].shape == (45, 3) and last.attrs["time"] > 0 and "density" in last


def test_mesh_problems_name_the_file(tmp_path):
    (tmp_path / "empty.obj").write_text("# nothing here\n")
    big = trimesh.creation.box(extents=[1000.0, 1000.0, 1000.0])  # millimetres by mistake
    big.export(tmp_path / "big.stl")
    tiny = trimesh.creation.box(extents=[1e-4, 1e-4, 1e-4])
    tiny.export(tmp_path / "tiny.ply")
    from warpsph.simulation import Simulation

    for name, words in [("empty.obj", "no triangles"), ("big.stl", "wrong units"), ("tiny.ply", "smaller than one particle")]:
        scene = load_scene(write_scene(tmp_path, tank_scene(obstacles=[{"mesh": name}])))
        with pytest.raises(SceneError, match=words) as info:
            Simulation(scene, device="cpu")
        assert name in str(info.value)


def run_cli(*args):
    return main([*map(str, args), "--device", "cpu", "--quiet"])


def test_overwrite_replaces_only_warpsph_outputs(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 1}))
    folder = tmp_path / "renders"
    folder.mkdir()
    (folder / "mine.txt").write_text("keep me")
    assert run_cli("run", scene, "--out", folder, "--overwrite") == 2
    assert "is a directory" in capsys.readouterr().err and (folder / "mine.txt").read_text() == "keep me"
    notes = tmp_path / "notes.usda"  # a file warpsph did not write, even a valid USD layer
    stage = Usd.Stage.CreateNew(str(notes))
    UsdGeom.Cube.Define(stage, "/Cube")
    stage.GetRootLayer().Save()
    before = notes.read_bytes()
    assert run_cli("run", scene, "--out", notes, "--overwrite") == 2
    assert "not written by warpsph" in capsys.readouterr().err and notes.read_bytes() == before
    out = tmp_path / "o.usdc"
    assert run_cli("run", scene, "--out", out, "--clips", "--particles-h5", "--checkpoint-every", "1") == 0
    assert run_cli("run", scene, "--out", out, "--clips", "--particles-h5", "--overwrite") == 0  # its own: replaced
    out.with_suffix(".stats.csv").write_text("my spreadsheet\n")  # a user's file where a side file goes
    (tmp_path / "o.clips" / "readme.txt").write_text("mine")
    stamp = out.stat().st_mtime_ns
    assert run_cli("run", scene, "--out", out, "--overwrite") == 2
    assert "not written by warpsph" in capsys.readouterr().err
    assert out.stat().st_mtime_ns == stamp and out.with_suffix(".stats.csv").read_text() == "my spreadsheet\n"
    assert (tmp_path / "o.clips" / "readme.txt").exists() and (tmp_path / "o.clips" / "frame.000001.usdc").exists()


def test_dry_run_reports_disk_and_an_output_the_run_would_refuse(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.02, output={"frames": 4}))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "of disk" in text and "would write" in text
    out.write_text("not a cache")
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--dry-run", "--overwrite"]) == 0
    assert "would refuse" in capsys.readouterr().out and out.read_text() == "not a cache"


def test_resume_works_from_any_directory(tmp_path, monkeypatch):
    project, elsewhere = tmp_path / "project", tmp_path / "elsewhere"
    (project / "meshes").mkdir(parents=True)
    elsewhere.mkdir()
    trimesh.creation.box(extents=[0.12, 0.12, 0.12]).export(project / "meshes" / "box.obj")
    obstacle = {"mesh": "meshes/box.obj", "translation": [0.2, 0.5, 0.2]}
    write_scene(project, tank_scene(radius=0.05, block=(0.4, 0.3, 0.4), obstacles=[obstacle]))
    monkeypatch.chdir(project)
    assert run_cli("run", "scene.json", "--out", "out/r.usdc", "--frames", 2, "--checkpoint-every", 1) == 0
    (project / "scene.json").rename(project / "renamed.json")  # the checkpoint holds the scene
    monkeypatch.chdir(elsewhere)
    assert run_cli("resume", project / "out" / "r.checkpoint.h5", "--frames", 3) == 0
    assert time_samples(project / "out" / "r.usdc") == [0.0, 1.0, 2.0, 3.0]
    assert not list(elsewhere.iterdir())


def stats_frames(path):
    import csv

    with open(path) as f:
        return [int(row["frame"]) for row in csv.DictReader(f)]


@pytest.mark.parametrize("clips", [False, True])
def test_resume_is_idempotent(tmp_path, clips):
    import h5py

    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 3}))
    out = tmp_path / "o.usdc"
    extra = ["--clips"] if clips else []
    assert run_cli("run", scene, "--out", out, "--checkpoint-every", 2, "--particles-h5", *extra) == 0
    checkpoint = out.with_suffix(".checkpoint.h5")
    # a finished run resumed again; then on to frame 5 (a checkpoint at 4), twice; then the stored 5 frames
    for frames, last in [([], 3), ([], 3), (["--frames", 5], 5), (["--frames", 5], 5), ([], 5)]:
        assert run_cli("resume", checkpoint, *frames) == 0
        assert stats_frames(out.with_suffix(".stats.csv")) == list(range(last + 1))
        assert time_samples(out) == [float(f) for f in range(last + 1)]
        with h5py.File(out.with_suffix(".particles.h5"), "r") as f:
            assert sorted(f["frames"]) == [f"{n:06d}" for n in range(last + 1)]


def test_frames_must_be_at_least_one(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 2}))
    out = tmp_path / "o.usdc"
    for frames in ("0", "-3"):
        assert run_cli("run", scene, "--out", out, "--frames", frames) == 2
        assert "--frames" in capsys.readouterr().err and not list(tmp_path.glob("o*"))
    assert run_cli("run", scene, "--out", out, "--checkpoint-every", 1) == 0
    assert run_cli("resume", out.with_suffix(".checkpoint.h5"), "--frames", 0) == 2
    assert "--frames" in capsys.readouterr().err


@pytest.mark.parametrize("model, key, value", [("vorticity_refinement", "alpha", 1e9), ("vorticity_refinement", "alpha", -1),
                                               ("rankine", "beta", 2.0), ("rankine", "viscosity", 1e4),
                                               ("micropolar", "transfer_coefficient", 1e6),
                                               ("micropolar", "inverse_inertia", 1e9),
                                               ("micropolar", "viscosity_omega", 50.0)])
def test_model_parameters_outside_their_range_are_refused(tmp_path, capsys, model, key, value):
    scene = write_scene(tmp_path, tank_scene(radius=0.05, models=[{"type": model, key: value}]))
    assert run_cli("run", scene, "--out", tmp_path / "o.usdc") == 2
    err = capsys.readouterr().err
    assert f"models[0].{key}: expected" in err and "a number in" in err
    assert not list(tmp_path.glob("o*"))


@pytest.mark.slow
def test_sigkill_leaves_a_readable_cache_and_a_recent_checkpoint(tmp_path):
    import h5py

    data = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 50, "frames": 400})
    scene = write_scene(tmp_path, data)
    out = tmp_path / "long.usdc"
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--device", "cpu", "--out", str(out),
                             "--checkpoint-every", "2", "--quiet"], stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    stats = out.with_suffix(".stats.csv")
    deadline = time.time() + 120
    while time.time() < deadline and (not stats.exists() or len(stats.read_text().splitlines()) < 7):
        time.sleep(0.05)
    proc.kill()
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    done = time_samples(tmp_path / "long.partial.usdc")  # saved while cheap and at each checkpoint (frame 4 at least)
    assert done == [float(f) for f in range(len(done))] and len(done) >= 5
    checkpoint = out.with_suffix(".checkpoint.h5")
    with h5py.File(checkpoint, "r") as f:
        assert len(done) - 1 - 2 <= f.attrs["frame"] <= len(done) - 1
    last = len(done) + 1
    assert main(["resume", str(checkpoint), "--device", "cpu", "--frames", str(last), "--quiet"]) == 0
    assert time_samples(out) == [float(f) for f in range(last + 1)]
    assert stats_frames(stats) == list(range(last + 1))


@pytest.mark.slow
def test_no_cuda_driver_warning_on_a_machine_without_a_gpu(tmp_path):
    scene = write_scene(tmp_path, tank_scene(radius=0.05))
    result = subprocess.run([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--device", "auto", "--dry-run"],
                            capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "CUDA driver" not in result.stderr and "fluid" in result.stdout


@pytest.mark.parametrize("clips", [False, True])
def test_a_write_error_is_a_clear_error_and_keeps_the_frames_written(tmp_path, monkeypatch, capsys, clips):
    import errno

    from conftest import fail_frame_writes

    cls, original = fail_frame_writes(monkeypatch, clips, 3, OSError(errno.ENOSPC, "No space left on device"))
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 5}))
    out = tmp_path / "o.usdc"
    assert run_cli("run", scene, "--out", out, "--checkpoint-every", 2, *(["--clips"] if clips else [])) == 2
    err = capsys.readouterr().err
    assert "warpsph: error: cannot write frame 3: No space left on device" in err and "keeps the frames" in err
    assert time_samples(out) == [0.0, 1.0, 2.0] and stats_frames(out.with_suffix(".stats.csv")) == [0, 1, 2]
    monkeypatch.setattr(cls, "write_frame", original)  # space again: the run goes on from its checkpoint
    assert run_cli("resume", out.with_suffix(".checkpoint.h5")) == 0
    assert time_samples(out) == [float(f) for f in range(6)] and stats_frames(out.with_suffix(".stats.csv")) == list(range(6))


TINY = {"name": "tiny", "particle_radius": 0.05, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.4]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}], "output": {"frames": 2}}


@pytest.mark.slow
def test_a_sweep_into_its_own_folder_keeps_the_users_files(tmp_path, monkeypatch, capsys):
    """`warpsph sweep sweep.json --out .` wrote its normalised spec over sweep.json: the next identical command
    failed ("unknown key"). The spec is now sweep.normalised.json; a table.md the sweep did not write is refused."""
    monkeypatch.chdir(tmp_path)
    write_scene(tmp_path, TINY, "s.json")
    text = json.dumps({"name": "sw", "scene": "s.json", "time": 0.05, "axes": {"fluid.viscosity": [0.01, 0.02]}})
    (tmp_path / "sweep.json").write_text(text)
    for _ in range(2):  # the rerun finds its own outputs and replaces them
        assert main(["sweep", "sweep.json", "--out", ".", "-q"]) == 0
        assert (tmp_path / "sweep.json").read_text() == text
    assert json.loads((tmp_path / "sweep.normalised.json").read_text())["sweep"]["name"] == "sw"
    (tmp_path / "table.md").write_text("# my notes\n")
    capsys.readouterr()
    assert main(["sweep", "sweep.json", "--out", ".", "-q"]) == 2
    assert "table.md" in capsys.readouterr().err and (tmp_path / "table.md").read_text() == "# my notes\n"


@pytest.mark.parametrize("argv", [["schema", "--out"], ["validate", "taylor-green", "--resolutions", "8", "--json"],
                                  ["plot", "slice", "no.usdc", "--out"], ["plot", "energy", "no.usdc", "--out"]])
def test_verbs_replace_an_existing_file_only_with_overwrite(tmp_path, capsys, argv):
    """One rule on every verb that writes a file: an existing file is kept (exit 2, named) unless --overwrite; a
    directory is refused; missing folders are created."""
    mine = tmp_path / "mine.txt"
    mine.write_text("keep me")
    assert main(argv + [str(mine)]) == 2
    err = capsys.readouterr().err
    assert "mine.txt" in err and "--overwrite" in err and mine.read_text() == "keep me"
    assert main(argv + [str(tmp_path)]) == 2 and "is a directory" in capsys.readouterr().err
    if argv[0] == "schema":
        assert main(argv + [str(mine), "--overwrite"]) == 0 and json.loads(mine.read_text())
        assert main(argv + [str(tmp_path / "new" / "dir" / "schema.json")]) == 0
        assert json.loads((tmp_path / "new" / "dir" / "schema.json").read_text())


SPLISH_MICROPOLAR = {"Configuration": {"particleRadius": 0.025, "simulationMethod": 4, "stopAt": 0.1},
                     "Materials": [{"id": "Fluid", "vorticityMethod": 1, "Bender et al. 2017": {"vorticity": 0.05}}],
                     "FluidBlocks": [{"start": [-0.5, 0, -0.5], "end": [0, 0.5, 0]}]}


@pytest.mark.parametrize("data, words", [
    ({**TINY, "name": "../../x"}, "name: expected a file name"),
    ({**TINY, "output": {"frames": 10**30}}, "output.frames"),
    ({**TINY, "particle_radius": list(range(200_000))}, "particle_radius: expected"),
    ({**SPLISH_MICROPOLAR, "Configuration": {"particleRadius": 0}}, "Configuration.particleRadius: expected a number > 0"),
    # SPlisHSPlasH values warpsph cannot take are named by the file's key (they named time.cfl / time.dt_min)
    ({**SPLISH_MICROPOLAR, "Configuration": {"cflFactor": 5}}, "Configuration.cflFactor: expected a number in (0, 1]"),
    ({**SPLISH_MICROPOLAR, "Configuration": {"cflMaxTimeStepSize": -1}}, "Configuration.cflMaxTimeStepSize: expected"),
])
def test_hostile_scenes_get_one_short_error_and_write_nothing(tmp_path, capsys, data, words):
    """Each used to write outside out/, accept 1e30 frames, echo a 1.3 MB array back, or end in an OverflowError."""
    scene = write_scene(tmp_path, data)
    assert main(["run", str(scene), "--device", "cpu", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err) < 2000 and "Traceback" not in err  # a SPlisHSPlasH file adds its notes
    assert list(tmp_path.iterdir()) == [scene]


def test_dry_run_of_a_micropolar_splishsplash_scene(tmp_path, capsys):
    """The disk estimate knew no size for micropolar's angular_velocity field (KeyError)."""
    scene = write_scene(tmp_path, SPLISH_MICROPOLAR)
    assert main(["run", str(scene), "--device", "cpu", "--dry-run"]) == 0
    assert "would write" in capsys.readouterr().out


@pytest.mark.parametrize("content, words", [
    (json.dumps({"scene": "s.json", "time": 0.05, "device": "tpu:7", "axes": {"fluid.viscosity": [0.01]}}).encode(),
     "device: unknown device 'tpu:7'"),
    ('{"name": "caf\xe9", "scene": "s.json"}'.encode("latin-1"), "not UTF-8"),
    (('{"axes": ' + "[" * 100_000 + "]" * 100_000 + "}").encode(), "nested too deeply"),
    (json.dumps({"scene": "s.json", "time": 0.05, "axes": {"fluid.viscosity": [0.01] * 200_000}}).encode(),
     "bytes; a sweep file is at most 1,048,576 bytes"),  # before: read and parsed whole (a 50 MB one took 42 s)
])
def test_bad_sweep_files_are_refused_before_any_cell(tmp_path, capsys, content, words):
    write_scene(tmp_path, TINY, "s.json")
    sweep = tmp_path / "sweep.json"
    sweep.write_bytes(content)
    assert main(["sweep", str(sweep), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_killed_sweep_cell_is_recorded_and_the_sweep_goes_on(tmp_path, monkeypatch):
    """SIGKILL of one cell's process used to break the whole pool (BrokenProcessPool: no table, the other cells never
    ran). Now the cell is failed with its signal, the rest finish, and a rerun retries only that cell."""
    from warpsph.sweep import run_sweep

    monkeypatch.setenv("SWEEP_TEST_SURVIVE", str(tmp_path / "survive"))
    monkeypatch.syspath_prepend(os.path.dirname(__file__))
    sweep = {"name": "killed", "base": {"function": "sweep_cells:die_or_square"}, "axes": {"x": [1, 2, 3, 4]},
             "measures": ["square"], "warm_up": False}
    out = tmp_path / "out"
    table = run_sweep(sweep, out, workers=2, log=lambda line: None)
    status = {r["x"]: (r["status"], r.get("error", "")) for r in table["rows"]}
    assert [status[x][0] for x in (1, 3, 4)] == ["done"] * 3
    assert status[2][0] == "failed" and "signal 9 (SIGKILL)" in status[2][1]
    assert not table["complete"] and (out / "table.md").exists()
    (tmp_path / "survive").touch()
    lines = []
    table = run_sweep(sweep, out, workers=2, log=lines.append)
    assert "[1 to run" in lines[0] and table["complete"]
    assert {r["x"]: r["square"] for r in table["rows"]} == {1: 1, 2: 4, 3: 9, 4: 16}


def test_a_second_run_on_the_same_output_is_refused_while_the_first_writes(tmp_path, capsys):
    """Two runs on one --out interleaved, and --overwrite deleted the first run's live cache. OUT.lock (pid, host)
    now refuses the second, --overwrite or not; a lock whose process is gone is taken over and removed at the end."""
    import socket

    scene = write_scene(tmp_path, TINY)
    out = tmp_path / "o.usdc"
    lock = tmp_path / "o.usdc.lock"
    lock.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))  # a live writer: this process
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--overwrite", "-q"]) == 2
    err = capsys.readouterr().err
    assert f"pid {os.getpid()}" in err and "o.usdc.lock" in err and not out.exists()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    lock.write_text(json.dumps({"pid": gone.pid, "host": socket.gethostname()}))  # its run is gone
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "-q"]) == 0
    assert "stale lock" in capsys.readouterr().err and out.exists() and not lock.exists()


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_to_the_process_group_stops_a_surface_run_cleanly(tmp_path, signum, code):
    """Ctrl-C in a terminal reaches the whole process group: the mesher's workers took it too, and the run ended in
    four chained tracebacks, exit 1, no checkpoint, the cache left partial. The workers now ignore it."""
    pytest.importorskip("pysplashsurf", reason="--surface meshes with pysplashsurf (pip install 'warpsph[surface]')")
    data = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 50, "frames": 400})
    scene = write_scene(tmp_path, data)
    out = tmp_path / "long.usdc"
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--device", "cpu", "--out", str(out),
                             "--surface"], stderr=subprocess.PIPE, text=True, cwd=tmp_path, start_new_session=True)
    stats = out.with_suffix(".stats.csv")
    deadline = time.time() + 120
    while time.time() < deadline and (not stats.exists() or len(stats.read_text().splitlines()) < 4):
        time.sleep(0.2)
    os.killpg(proc.pid, signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code and "Traceback" not in err, err
    assert "resume" in err and out.with_suffix(".checkpoint.h5").exists()
    done = time_samples(out)
    assert done == [float(f) for f in range(len(done))] and len(done) >= 3


def _children(pid):
    """The pids of the live processes whose parent is ``pid`` (read from /proc: no psutil here)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = open(f"/proc/{entry}/stat").read()
            except OSError:
                continue
            state, ppid = stat.rsplit(")", 1)[1].split()[:2]
            if int(ppid) == pid and state != "Z":
                found.append(int(entry))
    return found


def _alive(pid):
    """Whether ``pid`` runs (a zombie, dead but not yet reaped by its new parent, does not)."""
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _cmdline(pid):
    try:
        return open(f"/proc/{pid}/cmdline", "rb").read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _start_surface_run(tmp_path, *extra):
    """A long ``run --surface --surface-method preview`` on the CPU in a session of its own, once it has written a
    few frames (and, with --checkpoint-every, its first checkpoint); (process, out, its mesher worker's pid)."""
    data = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 50, "frames": 400})
    scene = write_scene(tmp_path, data)
    out = tmp_path / "long.usdc"
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--device", "cpu", "--out", str(out),
                             "--surface", "--surface-method", "preview", *extra], stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path, start_new_session=True)
    stats = out.with_suffix(".stats.csv")
    # on a loaded machine the mesher lags: a worker killed before the first checkpoint leaves none to name
    checkpoint = out.with_suffix(".checkpoint.h5") if "--checkpoint-every" in extra else None
    workers = []
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and (
            not workers or not stats.exists() or len(stats.read_text().splitlines()) < 4
            or (checkpoint is not None and not checkpoint.exists())):
        workers = [pid for pid in _children(proc.pid) if "spawn_main" in _cmdline(pid)]
        time.sleep(0.2)
    if proc.poll() is not None or len(workers) != 1:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail(f"no mesher worker found: {workers}, {proc.communicate()[1]}")
    return proc, out, workers[0]


@pytest.mark.slow
def test_a_run_killed_alone_leaves_no_mesher_worker(tmp_path):
    """The out-of-memory killer SIGKILLs the run's process alone, not its group. Its mesher worker, which ignores
    SIGINT and SIGTERM, and multiprocessing's resource tracker then ran for ever under pid 1. The worker now exits
    when its parent dies (a thread watching os.getppid()), and the tracker when its pipe's last writer is gone."""
    proc, out, worker = _start_surface_run(tmp_path, "-q")
    left = _children(proc.pid)  # the worker and the resource tracker
    try:
        proc.kill()  # the run alone
        proc.wait(timeout=60)  # not communicate(): a worker left holds the stderr pipe open
        proc.stderr.close()
        assert proc.returncode == -signal.SIGKILL
        deadline = time.time() + 10
        while time.time() < deadline and any(_alive(pid) for pid in left):
            time.sleep(0.1)
        assert not [pid for pid in left if _alive(pid)], [(pid, _cmdline(pid)) for pid in left if _alive(pid)]
    finally:
        for pid in left:  # the whole group is gone with the session (on the old code, the worker is still there)
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_killed_mesher_worker_ends_the_run_with_one_line_and_a_finished_cache(tmp_path):
    """A mesher worker SIGKILLed (out of memory) during run --surface: before, a BrokenProcessPool traceback, exit 1,
    the cache left as long.partial.usdc. Now exit 2, one line naming the dead worker, the cache finished."""
    proc, out, worker = _start_surface_run(tmp_path, "--checkpoint-every", "2", "-q")
    try:
        os.kill(worker, signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 2, err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("Warp ")]  # no CUDA here
    assert len(lines) == 1 and "a mesher worker process died" in lines[0] and "Traceback" not in err, err
    assert "keeps the frames before it" in lines[0] and "last checkpoint: " in lines[0]
    assert out.exists() and not (tmp_path / "long.partial.usdc").exists()
    done = time_samples(out)
    assert done == [float(f) for f in range(len(done))] and len(done) >= 3
    assert not [pid for pid in _children(os.getpid()) if _alive(pid) and "spawn_main" in _cmdline(pid)]


@pytest.mark.slow
def test_ctrl_c_of_validate_is_one_line_and_writes_no_json(tmp_path):
    """SIGINT to the process group of ``validate`` during its study: exit 130, ``warpsph: interrupted``, no traceback,
    no --json file."""
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "validate", "taylor-green", "--resolutions", "16",
                             "24", "--device", "cpu", "--json", "v.json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path, start_new_session=True,
                            preexec_fn=as_in_a_terminal, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        seen = []
        while not (seen and seen[-1].startswith("[1/2]")) and len(seen) < 20:  # "[1/2] taylor-green ...": it runs
            seen.append(proc.stderr.readline())
        assert seen[-1].startswith("[1/2]"), seen
        time.sleep(1.0)
    finally:
        err = signal_group(proc, signal.SIGINT, timeout=120)
    assert proc.returncode == 130, err
    assert [line for line in err.splitlines() if line.strip() and not line.startswith("Warp ")] == [
        "warpsph: interrupted"], err
    assert not (tmp_path / "v.json").exists()


def test_a_filling_disk_stops_the_run_before_the_cache_is_damaged(tmp_path, monkeypatch, capsys):
    """A single-file cache whose save ran out of space was truncated: USD could not open it and resume ended in a
    traceback. The free space is now checked before each frame: the run stops with ENOSPC and the numbers, the
    cache holds the frames before, and resume continues once there is room."""
    import shutil
    from collections import namedtuple

    import warpsph.io.usd as usd

    real = shutil.disk_usage
    usage = namedtuple("usage", "total used free")
    frames_seen = []
    original = usd.UsdPointCache.write_frame

    def counting(self, frame, *args, **kwargs):
        frames_seen.append(frame)
        return original(self, frame, *args, **kwargs)

    def filling(path):  # the file system fills when frame 3 comes
        return usage(1 << 30, 1 << 30, 1024) if frames_seen and frames_seen[-1] >= 3 else real(path)

    monkeypatch.setattr(usd.UsdPointCache, "write_frame", counting)
    monkeypatch.setattr(shutil, "disk_usage", filling)
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 5}))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--checkpoint-every", "2", "-q"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and "MiB free" in err and "frame 3" in err
    assert time_samples(out) == [0.0, 1.0, 2.0]
    monkeypatch.setattr(shutil, "disk_usage", real)
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "-q"]) == 0
    assert time_samples(out) == [float(f) for f in range(6)]


def test_resume_of_a_damaged_cache_says_so(tmp_path, capsys):
    scene = write_scene(tmp_path, tank_scene(radius=0.05, output={"frames": 3}))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--checkpoint-every", "1", "-q"]) == 0
    data = out.read_bytes()
    out.write_bytes(data[: len(data) // 2])  # what a save cut short by a full disk leaves
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--frames", "5", "-q"]) == 2
    err = capsys.readouterr().err
    assert "USD cannot open this cache" in err and "Traceback" not in err and out.exists()


def _cache_without_velocities(path, nan_at=None):
    grid = np.stack(np.meshgrid(*[np.arange(8) * 0.04] * 3, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    stage = Usd.Stage.CreateNew(str(path))
    points = UsdGeom.Points.Define(stage, "/World/Fluid")
    for t in (0, 1):
        frame = grid.copy()
        if t == nan_at:
            frame[5] = np.nan
        points.GetPointsAttr().Set(frame, t)
    points.GetWidthsAttr().Set(np.full(len(grid), 0.04, np.float32), 0)
    stage.GetRootLayer().Save()
    return path


def test_a_frame_with_nan_positions_is_a_clear_error_for_surface_and_plot(tmp_path, capsys):
    """An unstable run's last frame holds NaN positions: `surface` panicked in splashsurf and `plot slice` raised a
    TypeError. Both now name the frame and exit 2; `surface` keeps the frames meshed before it."""
    pytest.importorskip("pysplashsurf", reason="warpsph surface meshes with pysplashsurf")
    cache = _cache_without_velocities(tmp_path / "c.usdc", nan_at=1)
    assert main(["surface", str(cache), "--out", str(tmp_path / "c.surface.usdc")]) == 2
    err = capsys.readouterr().err
    assert "frame 1 are NaN" in err and "Traceback" not in err and (tmp_path / "c.surface.usdc").exists()
    pytest.importorskip("matplotlib", reason="plot needs matplotlib")
    assert main(["plot", "slice", str(cache), "--frame", "1", "--out", str(tmp_path / "s.png")]) == 2
    assert "frame 1 are NaN" in capsys.readouterr().err and not (tmp_path / "s.png").exists()


def test_plot_slice_of_a_cache_without_velocities(tmp_path, capsys):
    """A cache written with --fields points has no velocities to colour by: the slice is coloured by height."""
    pytest.importorskip("matplotlib", reason="plot needs matplotlib")
    cache = _cache_without_velocities(tmp_path / "c.usdc")
    assert main(["plot", "slice", str(cache), "--out", str(tmp_path / "s.png")]) == 0
    assert (tmp_path / "s.png").stat().st_size > 0


@pytest.mark.slow
def test_a_signal_stops_a_run_over_several_subdomains_and_resume_completes(tmp_path):
    """``--devices`` (two slabs on the CPU here): SIGINT finishes the frame, writes the checkpoint, exits 130 with the
    resume hint, and the resume over the same subdomains completes the cache."""
    data = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.3, 0.3, 0.2), output={"fps": 50, "frames": 400})
    scene = write_scene(tmp_path, data)
    out = tmp_path / "slabs.usdc"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "run", str(scene), "--devices", "cpu,cpu", "--out",
                             str(out)], stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    stats = out.with_suffix(".stats.csv")
    deadline = time.time() + 180
    while time.time() < deadline and (not stats.exists() or len(stats.read_text().splitlines()) < 4):
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=180)
    assert proc.returncode == 130, err
    assert "SIGINT" in err and "resume" in err and "Traceback" not in err
    checkpoint = out.with_suffix(".checkpoint.h5")
    assert checkpoint.exists() and out.exists()
    done = time_samples(out)
    assert done == [float(f) for f in range(len(done))] and 3 <= len(done) < 401
    assert main(["resume", str(checkpoint), "--devices", "cpu,cpu", "--frames", str(len(done) + 1), "--quiet"]) == 0
    assert time_samples(out) == [float(f) for f in range(len(done) + 2)]
