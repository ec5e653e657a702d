"""A pressure solver plug-in defined in this file alone (warpsph.solvers): its registration is the one line that
makes the scene schema, the memory check, the kernel warm-up, the CLI and the stepper take it, as a model's does
(tests/test_plugins.py); its own keys of the solver block (its ``Parameters``) reach the schema, the reference
and the solver, and a key of another solver is refused naming it."""

import json

import numpy as np
import pytest

from warpsph import SceneError, Simulation, scene_from_dict
from warpsph.cli import main
from warpsph.resources import estimate_bytes
from warpsph.scene import key, reference_markdown, schema, scene_json_schema
from warpsph.solvers import SOLVERS, register_solver, solver_names
from warpsph.solvers.dfsph import DFSPHParameters, DFSPHSolver
from warpsph.warmup import scene_modules
from conftest import tank_scene


@schema
class DensityOnlyParameters(DFSPHParameters):
    """DFSPH's keys, and one of its own."""

    with_divergence: bool = key(False, doc="run DFSPH's divergence solve all the same")


class DensityOnly(DFSPHSolver):
    """DFSPH without its divergence solve (what ``solver.divergence_solver`` false does, as a solver of its own):
    the density solve alone keeps the fluid incompressible; it launches no divergence-solve kernel. Its own key
    ``solver.with_divergence`` brings the divergence solve back (DFSPH again)."""

    Parameters = DensityOnlyParameters
    summary = "DFSPH's density solve alone (a test plug-in)"
    splishsplash_method = None

    def correct_divergence(self):
        if self.ctx.parameters.with_divergence:
            super().correct_divergence()

    @staticmethod
    def kernel_modules(scene):
        modules = DFSPHSolver.kernel_modules(scene)
        return modules if scene.solver.with_divergence else [m for m in modules if not m.endswith("divergence_solver")]


@pytest.fixture
def density_only():
    register_solver("test_density_only")(DensityOnly)
    yield DensityOnly
    del SOLVERS["test_density_only"]


def scene(method, **solver):
    data = tank_scene(radius=0.04, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 40, "frames": 4})
    data["solver"] = {"method": method, **solver}
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


def test_a_solver_s_own_key_reaches_the_schema_and_the_solver(density_only, device):
    """``solver.with_divergence``, a key of the test solver's Parameters alone: in the JSON Schema and the
    reference with the solvers that have it, on ``scene.solver``, and read by the solver (DFSPH again: bit for bit
    on the CPU)."""
    block = scene_json_schema()["$defs"]["Solver"]
    assert block["properties"]["with_divergence"]["description"].startswith("(test_density_only) ")
    assert block["properties"]["shifting"]["description"].startswith("(dfsph, test_density_only) ")
    text = reference_markdown()
    assert '## solver: "method": "test_density_only"' in text and "| `solver.with_divergence` |" in text
    ours = scene_from_dict(scene("test_density_only", with_divergence=True, shifting=1.0))
    assert ours.solver.with_divergence is True and ours.solver.shifting == 1.0
    assert scene_from_dict(scene("test_density_only")).solver.with_divergence is False
    assert "warpsph.kernels.divergence_solver" in scene_modules(ours)
    sims = [Simulation(s, device=device) for s in (ours, scene_from_dict(scene("dfsph", shifting=1.0)))]
    for sim in sims:
        for _ in range(10):
            sim.step()
    assert sims[0].statistics()["divergence_iterations"] > 0
    apart = np.abs(sims[0].positions() - sims[1].positions()).max()
    assert apart == 0.0 if device == "cpu" else apart < 1e-5


@pytest.mark.parametrize("method, key, theirs", [("dfsph", "with_divergence", "test_density_only"),
                                                 ("iisph", "shifting", "dfsph and test_density_only"),
                                                 ("iisph", "divergence_max_error", "dfsph and test_density_only"),
                                                 ("dfsph", "relaxation", "iisph")])
def test_a_key_of_another_solver_is_refused_naming_it(density_only, method, key, theirs):
    with pytest.raises(SceneError) as err:
        scene_from_dict(scene(method, **{key: 1.0 if key != "with_divergence" else True}))
    assert err.value.key == f"solver.{key}"
    plural = "s" if " and " in theirs else ""
    assert f'a key of the {theirs} pressure solver{plural}, not of "{method}" (solver.method)' in str(err.value)


def test_a_key_of_dfsph_with_iisph_is_refused_by_the_schema_too(capsys):
    jsonschema = pytest.importorskip("jsonschema", reason="validating against the JSON Schema needs jsonschema")
    validator = jsonschema.Draft202012Validator(scene_json_schema())
    with pytest.raises(SceneError, match=r"solver\.shifting: a key of the dfsph pressure solver, not of \"iisph\""):
        scene_from_dict(scene("iisph", shifting=0.0))
    assert list(validator.iter_errors(scene("iisph", shifting=0.0)))
    assert list(validator.iter_errors(scene("dfsph", relaxation=0.4)))
    assert not list(validator.iter_errors(scene("iisph", relaxation=0.4)))
    assert not list(validator.iter_errors({**scene("dfsph", shifting=0.0), "solver": {"shifting": 0.0}}))
    assert scene_from_dict(scene("iisph", relaxation=0.4)).solver.relaxation == 0.4
    assert not hasattr(scene_from_dict(scene("iisph")).solver, "shifting")


def test_iisph_reads_its_relaxation(device):
    """``solver.relaxation``, IISPH's own key: the Jacobi iterations' omega (0.5, SPlisHSPlasH's, by default)."""
    runs = {}
    for omega in (0.5, 0.3, None):
        sim = Simulation(scene_from_dict(scene("iisph") if omega is None else scene("iisph", relaxation=omega)),
                         device=device)
        for _ in range(5):
            sim.step()
        runs[omega] = sim.positions()
    assert np.array_equal(runs[0.5], runs[None]) and not np.array_equal(runs[0.5], runs[0.3])


def test_a_solver_plug_in_runs_from_the_command_line(density_only, tmp_path):
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene("test_density_only")))
    assert main(["run", str(path), "--device", "cpu", "--out", str(tmp_path / "out.usdc"), "-q"]) == 0
    assert (tmp_path / "out.usdc").exists()


def test_an_unknown_solver_is_named_with_the_closest_known_one():
    with pytest.raises(SceneError) as err:
        scene_from_dict(scene("dfsp"))
    assert err.value.key == "solver.method" and "unknown pressure solver \"dfsp\"; did you mean 'dfsph'?" in str(err.value)
