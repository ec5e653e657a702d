"""SPlisHSPlasH scene files run as they are; unsupported keys are listed in one warning."""

import json

import pytest

from warpsph import SceneError, load_scene
from warpsph.io.splishsplash import SplishSplashWarning
from warpsph.simulation import Simulation

DAM_BREAK = {
    "Configuration": {
        "particleRadius": 0.03, "timeStepSize": 0.001, "cflMethod": 1, "cflFactor": 0.4, "cflMaxTimeStepSize": 0.004,
        "gravitation": [0, -9.81, 0], "simulationMethod": 4, "boundaryHandlingMethod": 0, "stopAt": 0.2,
        "numberOfStepsPerRenderUpdate": 4, "enablePartioExport": False,
        "DFSPH": {"maxIterations": 80, "maxError": 0.05, "maxIterationsV": 50, "maxErrorV": 0.1,
                  "enableDivergenceSolver": True},
    },
    "Materials": [{"id": "Fluid", "density0": 1000, "viscosity": 0.01, "vorticityMethod": 1, "vorticity": 0.1,
                   "viscosityOmega": 0.05, "inertiaInverse": 0.5, "colorMapType": 1}],
    "RigidBodies": [{"geometryFile": "../models/UnitBox.obj", "translation": [0, 0.5, 0], "scale": [1.2, 1, 0.4],
                     "isDynamic": False, "isWall": True, "mapInvert": True, "color": [0.1, 0.4, 0.6, 1.0]}],
    "FluidBlocks": [{"denseMode": 0, "start": [-0.6, 0.0, -0.2], "end": [-0.3, 0.4, 0.2], "translation": [0, 0, 0],
                     "scale": [1, 1, 1]}],
}


def write(tmp_path, data):
    path = tmp_path / "DamBreak.json"
    path.write_text(json.dumps(data))
    return path


def test_splishsplash_dam_break_converts_and_runs(tmp_path):
    with pytest.warns(SplishSplashWarning) as record:
        scene = load_scene(write(tmp_path, DAM_BREAK))
    message = str(record[0].message)
    for key in ("numberOfStepsPerRenderUpdate", "enablePartioExport", "colorMapType", "denseMode", "RigidBodies[0].color"):
        assert key in message
    assert len(record) == 1
    assert scene.particle_radius == 0.03 and scene.time.cfl == 0.4 and scene.time.dt_max == 0.004
    assert (scene.domain.min, scene.domain.max) == ((-0.6, 0.0, -0.2), (0.6, 1.0, 0.2))
    assert scene.solver.max_iterations == 80 and scene.solver.density_max_error == 0.05
    assert scene.solver.divergence_max_iterations == 50 and scene.fluid.viscosity == 0.01
    (model,) = scene.models
    assert type(model).__name__ == "Micropolar" and model.transfer_coefficient == 0.1 and model.viscosity_omega == 0.05
    assert scene.output.frames == 5  # stopAt 0.2 s at 25 fps
    sim = Simulation(scene, device="cpu").run(frames=1)
    assert sim.num_fluid == 5 * 6 * 6


def test_older_flat_solver_keys_and_vorticity_refinement(tmp_path):
    data = json.loads(json.dumps(DAM_BREAK))
    config = data["Configuration"]
    config.update(config.pop("DFSPH"))
    data["Materials"][0] = {"id": "Fluid", "density0": 998, "vorticityMethod": 3}
    with pytest.warns(SplishSplashWarning, match="numberOfStepsPerRenderUpdate"):
        scene = load_scene(write(tmp_path, data))
    assert scene.solver.max_iterations == 80 and scene.fluid.density == 998
    assert type(scene.models[0]).__name__ == "VorticityRefinement"


def test_unsupported_method_and_missing_container_are_errors(tmp_path):
    data = json.loads(json.dumps(DAM_BREAK))
    data["Configuration"]["simulationMethod"] = 2
    with pytest.raises(SceneError, match="simulationMethod.*DFSPH"):
        load_scene(write(tmp_path, data))
    data = json.loads(json.dumps(DAM_BREAK))
    data["RigidBodies"] = []
    with pytest.raises(SceneError, match="container"):
        load_scene(write(tmp_path, data))
