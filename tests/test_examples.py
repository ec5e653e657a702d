"""The public API as a user calls it, and every script in examples/ at a tiny scale on the CPU
(each in a subprocess, outputs in a temporary directory)."""

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
TINY = ["--scale", "0.005", "--device", "cpu"]


def run_example(name, *args, cwd):
    done = subprocess.run([sys.executable, str(EXAMPLES / name), *args], cwd=cwd, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def usd_fluid_counts(path):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr()
    frames = range(int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode()) + 1)
    arrays = [np.asarray(points.Get(t)) for t in frames]
    assert all(np.isfinite(a).all() for a in arrays)
    return [len(a) for a in arrays]


def test_import_is_light_and_exports_the_api():
    code = ("import sys, warpsph; assert 'warp' not in sys.modules and 'pxr' not in sys.modules, 'heavy import'; "
            "print(warpsph.__version__, sorted(warpsph.__all__))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    for name in ("Scene", "Simulation", "io", "__version__"):
        assert name in out


def test_version_and_module_entry_point():
    import warpsph

    out = subprocess.run([sys.executable, "-m", "warpsph", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"warpsph {warpsph.__version__}"


def test_public_api(tmp_path):
    import warpsph

    scene = warpsph.Scene.load(ROOT / "scenes" / "dam_break.json", scale=0.005)
    assert scene == warpsph.load_scene(ROOT / "scenes" / "dam_break.json", scale=0.005)
    sim = warpsph.Simulation(scene, device="cpu")
    frames = []
    with warpsph.io.UsdWriter(tmp_path / "dam.usdc", sim) as usd:
        sim.run(frames=2, on_frame=lambda s, f: (usd(s, f), frames.append(f)))
    assert frames == [0, 1, 2] and usd.frames == 3
    x, v, rho, ids = sim.positions(), sim.velocities(), sim.densities(), sim.ids()
    assert x.shape == v.shape == (sim.num_fluid, 3) and rho.shape == ids.shape == (sim.num_fluid,)
    assert np.isfinite(x).all() and sorted(ids) == list(range(sim.num_fluid))
    x[:] = 0  # a copy: the simulation's particles do not move
    assert np.isfinite(sim.kinetic_energy()) and sim.positions().any()
    assert usd_fluid_counts(tmp_path / "dam.usdc") == [sim.num_fluid] * 3
    small = warpsph.Scene.from_dict({"particle_radius": 0.05, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
                                     "fluid_blocks": [{"start": [0, 0, 0], "end": [0.5, 0.5, 0.5]}]})
    assert isinstance(small, warpsph.Scene)
    with pytest.raises(warpsph.SceneError):
        warpsph.Scene.from_dict({"particle_radius": 0.05, "domian": {}})


@pytest.mark.slow
def test_dam_break_usd_and_read_back(tmp_path):
    run_example("dam_break_usd.py", *TINY, "--frames", "3", "--out", "d.usdc", cwd=tmp_path)
    counts = usd_fluid_counts(tmp_path / "d.usdc")
    assert len(counts) == 4 and counts[0] > 0
    out = run_example("read_usd_cache.py", "d.usdc", "--out", "summary.csv", cwd=tmp_path)
    rows = list(csv.DictReader((tmp_path / "summary.csv").open()))
    assert [int(r["particles"]) for r in rows] == counts, out
    assert all(math.isfinite(float(r["mean_speed"])) for r in rows)


@pytest.mark.slow
def test_compare_models_energy(tmp_path):
    run_example("compare_models_energy.py", *TINY, "--frames", "3", "--out", "e.csv", cwd=tmp_path)
    rows = list(csv.DictReader((tmp_path / "e.csv").open()))
    assert len(rows) == 4 and set(rows[0]) == {"frame", "time", "dfsph", "rankine"}
    energies = np.array([[float(r["dfsph"]), float(r["rankine"])] for r in rows])
    assert np.isfinite(energies).all() and (energies[-1] > 0).all()  # the column falls: energy grows


@pytest.mark.slow
def test_custom_emitter(tmp_path):
    out = run_example("custom_emitter.py", "--scale", "0.02", "--device", "cpu", "--frames", "4", "--out", "j.usdc",
                      cwd=tmp_path)
    counts = usd_fluid_counts(tmp_path / "j.usdc")
    assert counts[-1] > counts[1] > 0, out  # the emitter adds layers


@pytest.mark.slow
def test_viscosity_sweep(tmp_path):
    run_example("viscosity_sweep.py", *TINY, "--frames", "2", "--viscosities", "0", "0.1", "--out", "s.json",
                cwd=tmp_path)
    rows = json.loads((tmp_path / "s.json").read_text())
    assert [r["viscosity"] for r in rows] == [0.0, 0.1]
    assert all(math.isfinite(r["front_x"]) and math.isfinite(r["kinetic_energy"]) for r in rows)
