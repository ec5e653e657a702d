"""A pressure solver plug-in defined in this file alone (warpsph.solvers): its registration is the one line that
makes the scene schema, the memory check, the kernel warm-up, the CLI and the stepper take it, as a model's does
(tests/test_plugins.py)."""

import json

import numpy as np
import pytest

from warpsph import SceneError, Simulation, scene_from_dict
from warpsph.cli import main
from warpsph.resources import estimate_bytes
from warpsph.scene import scene_json_schema
from warpsph.solver import DFSPHSolver
from warpsph.solvers import SOLVERS, register_solver, solver_names
from warpsph.warmup import scene_modules
from conftest import tank_scene


class DensityOnly(DFSPHSolver):
    """DFSPH without its divergence solve (what ``solver.divergence_solver`` false does, as a solver of its own):
    the density solve alone keeps the fluid incompressible; it launches no divergence-solve kernel."""

    summary = "DFSPH's density solve alone (a test plug-in)"
    splishsplash_method = None

    def correct_divergence(self):
        pass

    @staticmethod
    def kernel_modules(scene):
        return [m for m in DFSPHSolver.kernel_modules(scene) if not m.endswith("divergence_solver")]


@pytest.fixture
def density_only():
    register_solver("test_density_only")(DensityOnly)
    yield DensityOnly
    del SOLVERS["test_density_only"]


def scene(method, **extra):
    data = tank_scene(radius=0.04, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 40, "frames": 4},
                      **extra)
    data["solver"] = {"method": method}
    return data


def test_a_solver_defined_in_a_test_file_is_a_scene_s_solver(density_only, device):
    assert "test_density_only" in solver_names() and solver_names()[0] == "dfsph"
    schema = scene_json_schema()
    assert "test_density_only" in schema["$defs"]["Solver"]["properties"]["method"]["enum"]
    ours, theirs = scene_from_dict(scene("test_density_only")), scene_from_dict(scene("dfsph"))
    assert estimate_bytes(ours, 1000, 100) == estimate_bytes(theirs, 1000, 100)
    modules = scene_modules(ours)
    assert "warpsph.kernels.density_solver" in modules and "warpsph.kernels.divergence_solver" not in modules
    assert "warpsph.kernels.divergence_solver" in scene_modules(theirs)
    sims = {}
    for name, s in (("ours", ours), ("theirs", theirs), ("off", scene_from_dict(
            {**scene("dfsph"), "solver": {"method": "dfsph", "divergence_solver": False}}))):
        sim = Simulation(s, device=device)
        for _ in range(20):
            sim.step()
        sims[name] = sim
    assert isinstance(sims["ours"].pressure_solver, DensityOnly)
    # the same as DFSPH with its divergence solve switched off (bit for bit on the CPU; on a GPU the cell lists fill
    # through atomic counters, so sums run in other orders), not as DFSPH with it (1.4e-2 m apart on the CPU)
    off = np.abs(sims["ours"].positions() - sims["off"].positions()).max()
    assert off == 0.0 if device == "cpu" else off < 1e-5
    assert np.abs(sims["ours"].positions() - sims["theirs"].positions()).max() > 2e-3
    assert sims["ours"].statistics()["divergence_iterations"] == 0


def test_a_solver_plug_in_runs_from_the_command_line(density_only, tmp_path):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene("test_density_only")))
    assert main(["run", str(path), "--device", "cpu", "--out", str(tmp_path / "out.usdc"), "-q"]) == 0
    assert (tmp_path / "out.usdc").exists()


def test_an_unknown_solver_is_named_with_the_closest_known_one():
    with pytest.raises(SceneError) as err:
        scene_from_dict(scene("dfsp"))
    assert err.value.key == "solver.method" and "unknown pressure solver \"dfsp\"; did you mean 'dfsph'?" in str(err.value)
