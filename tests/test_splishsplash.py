"""SPlisHSPlasH scene files run as their authors meant (read as SPlisHSPlasH 2.19 reads them), or are
refused naming each key; run anyway on request, with the list kept. Scenes written here in the
format of pysplishsplash 2.19.0's data/Scenes, at tiny scale."""

import copy
import json

import numpy as np
import pytest
import trimesh

from warpsph import SceneError, load_scene, sampling
from warpsph.io.splishsplash import RUN_ANYWAY_ENV, SplishSplashWarning, conversion_of, convert, translate
from warpsph.simulation import Simulation, count_particles, sample_scene

# SPlisHSPlasH 2.16+ form: solver and non-pressure parameters in their blocks
DAM_BREAK = {
    "Configuration": {
        "particleRadius": 0.03, "numberOfStepsPerRenderUpdate": 4, "simulationMethod": 4, "gravitation": [0, -9.81, 0],
        "timeStepSize": 0.001, "cflMethod": 1, "cflFactor": 0.4, "cflMaxTimeStepSize": 0.004, "stopAt": 0.2,
        "boundaryHandlingMethod": 2, "enablePartioExport": False,
        "DFSPH": {"minIterations": 2, "maxIterations": 80, "maxError": 0.05, "maxIterationsV": 50, "maxErrorV": 0.1,
                  "enableDivergenceSolver": True},
    },
    "Materials": [{"id": "Fluid", "density0": 1000, "viscosityMethod": 1, "Standard viscosity": {"viscosity": 0.01},
                   "colorMapType": 1}],
    "RigidBodies": [{"geometryFile": "../models/UnitBox.obj", "translation": [0, 0.5, 0], "scale": [1.2, 1, 0.5],
                     "isDynamic": False, "isWall": True, "mapInvert": True, "color": [0.1, 0.4, 0.6, 1.0],
                     "mapThickness": 0.0, "mapResolution": [20, 20, 20]}],
    "FluidBlocks": [{"denseMode": 0, "start": [-0.6, 0.0, -0.2], "end": [-0.3, 0.4, 0.2], "translation": [0, 0, 0],
                     "scale": [1, 1, 1]}],
}


@pytest.fixture
def scenes(tmp_path):
    """A Scenes/ folder beside models/ with a closed unit box, as pysplishsplash lays them out."""
    (tmp_path / "models").mkdir()
    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "models" / "UnitBox.obj")
    (tmp_path / "Scenes").mkdir()
    return tmp_path / "Scenes"


def write(folder, data, name="DamBreak"):
    path = folder / f"{name}.json"
    path.write_text(json.dumps(data))
    return path


def edited(**changes):
    data = copy.deepcopy(DAM_BREAK)
    for path, value in changes.items():
        *keys, last = path.split("__")
        node = data
        for k in keys:
            node = node[int(k)] if isinstance(node, list) else node[k]
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return data


def load_quiet(path):
    with pytest.warns(SplishSplashWarning):
        return load_scene(path)


# --- 1. parameters, read as SPlisHSPlasH 2.19 reads them ------------------------------------------------


def test_nested_blocks_are_read_and_the_scene_runs(scenes):
    scene = load_quiet(write(scenes, DAM_BREAK))
    assert scene.particle_radius == 0.03 and scene.time.cfl == 0.4 and scene.time.dt_max == 0.004
    assert scene.time.dt_min == 0.0001  # SPlisHSPlasH's default, not warpsph's
    inset = 0.03 * 1.4013  # where the volume map holds the fluid: the walls' test below
    assert scene.domain.min == pytest.approx((-0.6 + inset, inset, -0.25 + inset), abs=1e-5)
    assert scene.domain.max == pytest.approx((0.6 - inset, 1.0 - inset, 0.25 - inset), abs=1e-5)
    assert scene.solver.max_iterations == 80 and scene.solver.density_max_error == 0.05
    assert scene.solver.divergence_max_iterations == 50
    assert scene.fluid.viscosity == 0.01  # "Standard viscosity": {"viscosity": 0.01}, not warpsph's 0.05
    assert scene.output.frames == 5  # stopAt 0.2 s at 25 fps
    c = conversion_of(scene)
    assert c.refused == [] and any("Standard viscosity.viscosity -> fluid.viscosity = 0.01" in m for m in c.mapped)
    assert any("boundaryHandlingMethod 2" in n for n in c.notes)
    sim = Simulation(scene, device="cpu").run(frames=1)
    assert sim.num_fluid == c.splishsplash_particles == 4 * 6 * 6  # round(0.3 / 0.06) - 1, round(0.4 / 0.06) - 1


def test_each_material_block_maps(scenes):
    data = edited(Materials__0__viscosityMethod=1)
    data["Materials"][0].update({"Standard viscosity": {"viscosity": 0.02, "viscosityBoundary": 0.3},
                                 "vorticityMethod": 1,
                                 "Bender et al. 2017": {"vorticity": 0.15, "viscosityOmega": 0.05, "inertiaInverse": 0.4}})
    scene = load_quiet(write(scenes, data))
    assert (scene.fluid.viscosity, scene.fluid.boundary_viscosity) == (0.02, 0.3)
    (model,) = scene.models
    assert type(model).__name__ == "Micropolar"
    assert (model.transfer_coefficient, model.viscosity_omega, model.inverse_inertia) == (0.15, 0.05, 0.4)

    data["Materials"][0].update({"vorticityMethod": 3, "Liu et al. 2021": {"vorticity": 0.7, "kinetmaticViscosity": 0.02}})
    (model,) = load_quiet(write(scenes, data)).models
    assert type(model).__name__ == "VorticityRefinement" and (model.alpha, model.viscosity) == (0.7, 0.02)


def test_defaults_are_splishsplashs(scenes):
    """No viscosityMethod: inviscid, as SPlisHSPlasH runs it; an empty method block: its defaults."""
    scene = load_quiet(write(scenes, edited(Materials__0__viscosityMethod=None)))
    assert scene.fluid.viscosity == 0.0
    data = edited(**{"Materials__0__Standard viscosity": None})
    data["Materials"][0].update({"vorticityMethod": 1})
    scene = load_quiet(write(scenes, data))
    assert scene.fluid.viscosity == 0.01  # Viscosity_Standard's default
    (model,) = scene.models
    assert (model.transfer_coefficient, model.viscosity_omega, model.inverse_inertia) == (0.01, 0.1, 0.5)
    data = edited(Configuration__DFSPH=None)
    scene = load_quiet(write(scenes, data))
    assert (scene.solver.max_iterations, scene.solver.density_max_error, scene.solver.divergence_max_iterations) == (100, 0.01, 100)


def test_flat_pre_216_keys_are_ignored_as_splishsplash_219_ignores_them(scenes):
    """SPlisHSPlasH 2.19 reads a method's parameters only from its block: flat keys give its defaults (the same
    file ran nu 0.03 / max error 0.05 % in warpsph and 0.01 / 0.01 % in SPlisHSPlasH), and a note names each."""
    data = copy.deepcopy(DAM_BREAK)
    config = data["Configuration"]
    config.update(config.pop("DFSPH"))
    data["Materials"][0] = {"id": "Fluid", "density0": 998, "viscosityMethod": 1, "viscosity": 0.03,
                            "vorticityMethod": 1, "vorticity": 0.2, "viscosityOmega": 0.07, "inertiaInverse": 0.6}
    scene = load_quiet(write(scenes, data))
    assert scene.solver.max_iterations == 100 and scene.solver.density_max_error == 0.01  # SPlisHSPlasH's defaults
    assert scene.fluid.density == 998 and scene.fluid.viscosity == 0.01
    assert (scene.models[0].transfer_coefficient, scene.models[0].inverse_inertia) == (0.01, 0.5)
    notes = [n for n in conversion_of(scene).notes if n.startswith("flat (pre-2.16) parameters")]
    assert len(notes) == 1
    for key in ("Configuration.maxIterations = 80", "Configuration.maxError = 0.05", "Materials[0].viscosity = 0.03",
                "Materials[0].vorticity = 0.2", "Materials[0].inertiaInverse = 0.6"):
        assert key in notes[0]
    # the block gives the value, as in SPlisHSPlasH 2.19
    data["Materials"][0]["Standard viscosity"] = {"viscosity": 0.004}
    assert load_quiet(write(scenes, data)).fluid.viscosity == 0.004


def test_material_is_chosen_by_id(scenes):
    data = copy.deepcopy(DAM_BREAK)
    data["Materials"].insert(0, {"id": "Other", "density0": 500, "viscosityMethod": 1,
                                 "Standard viscosity": {"viscosity": 0.3}})
    scene = load_quiet(write(scenes, data))
    assert scene.fluid.density == 1000 and scene.fluid.viscosity == 0.01
    assert any("Materials[0] (id 'Other') belongs to no fluid" in n for n in conversion_of(scene).notes)


# --- 2. particle counts by SPlisHSPlasH's rule -------------------------------------------------------------


def test_block_rule_reproduces_splishsplash_counts():
    # DamBreakModel: a unit cube at r = 0.025 -> 19^3 = 6859, as SPlisHSPlasH prints
    assert len(sampling.splishsplash_block([-1.95, 0.05, -0.5], [-0.95, 1.05, 0.5], 0.025)) == 6859
    # rounding, not flooring: 0.75 / 0.05 = 15 steps of which the first and last are dropped
    assert len(sampling.splishsplash_block([-1.5, 0.0, -1.5], [-0.5, 0.75, -0.5], 0.025)) == 19 * 14 * 19
    x = sampling.splishsplash_block([0, 0, 0], [1, 1, 1], 0.025)
    assert np.allclose(x.min(axis=0), 0.05) and np.allclose(x.max(axis=0), 0.95)  # 2r inside each face
    assert len(sampling.splishsplash_block([0, 0, 0], [1, 1, 1], 0.025, sim2d=True)) == 19 * 19
    assert len(sampling.splishsplash_block([0, 0, 0], [0.1, 1, 1], 0.025)) == 0  # 1 step: SPlisHSPlasH skips it
    dense = sampling.splishsplash_block([0, 0, 0], [1, 1, 1], 0.025, mode=1)
    assert len(dense) == np.prod(sampling.splishsplash_block_counts([0, 0, 0], [1, 1, 1], 0.025, 1)) > 6859


def test_imported_block_has_splishsplashs_lattice(scenes):
    data = edited(FluidBlocks__0__start=[-0.5, 0.0, -0.5], FluidBlocks__0__end=[0.5, 1.0, 0.5],
                  FluidBlocks__0__translation=[0.0, 0.1, 0.0], FluidBlocks__0__scale=[0.5, 0.5, 0.3],
                  Configuration__particleRadius=0.0125)
    scene = load_quiet(write(scenes, data))
    fluid_x = sample_scene(scene)[0]
    theirs = sampling.splishsplash_block([-0.25, 0.1, -0.15], [0.25, 0.6, 0.15], 0.0125)
    assert count_particles(scene)[0] == len(fluid_x) == len(theirs) == 19 * 19 * 11
    key = lambda p: np.round(np.asarray(p, np.float64) / 1e-5).astype(np.int64)  # noqa: E731
    assert sorted(map(tuple, key(fluid_x))) == sorted(map(tuple, key(theirs)))


def test_dense_modes_are_refused_and_run_anyway_on_the_cubic_lattice(scenes, monkeypatch):
    data = edited(FluidBlocks__0__denseMode=2)
    with pytest.raises(SceneError, match=r"FluidBlocks\[0\].denseMode: 2 \(a staggered") as refused:
        load_scene(write(scenes, data))
    # no count where the rule is not SPlisHSPlasH 2.19's (it makes 1120 / 1260 in ReadWriteStateTest's block where
    # createFluidBlocks' 2.x rule gives 1408 / 1760)
    assert "particles" not in str(refused.value).split("denseMode: 2", 1)[1].split("\n", 1)[0]
    assert translate(data, "x.json").splishsplash_particles is None
    monkeypatch.setenv(RUN_ANYWAY_ENV, "1")
    with pytest.warns(SplishSplashWarning, match="RUN ANYWAY, left out: FluidBlocks"):
        scene = load_scene(write(scenes, data))
    assert count_particles(scene)[0] > 0


def test_fluid_models_fill_meshes_as_splishsplash_does(scenes):
    """A FluidModels entry with an OBJ: the scaled mesh filled from its bounding box's corner plus r, rotated and
    translated (VolumeSampling::sampleMesh); pysplishsplash 2.19.0 puts 1416 particles in this ellipsoid."""
    trimesh.creation.icosphere(subdivisions=4, radius=1.0).export(scenes.parent / "models" / "sphere.obj")
    data = edited(FluidBlocks=None, Configuration__particleRadius=0.025)
    data["RigidBodies"][0].update(translation=[0, 1, 0], scale=[2, 2, 2])
    data["FluidModels"] = [{"particleFile": "../models/sphere.obj", "translation": [0.3, 1.0, 0.1],
                            "scale": [0.4, 0.3, 0.35], "rotationAxis": [0, 0, 1], "rotationAngle": 0.5,
                            "initialVelocity": [0, -1, 0], "resolutionSDF": [20, 20, 20]}]
    scene = load_quiet(write(scenes, data))
    (m,) = scene.fluid_meshes
    assert (m.mesh, m.scale, m.rotation_axis, m.velocity) == ("../models/sphere.obj", (0.4, 0.3, 0.35), (0, 0, 1), (0, -1, 0))
    x = sample_scene(scene)[0].astype(np.float64)
    assert count_particles(scene)[0] == len(x) == 1416
    rot = sampling.rotation_matrix([0, 0, 1], 0.5)
    local = (x - [0.3, 1.0, 0.1]) @ rot  # back into the scaled mesh's frame
    assert np.all(np.sum((local / [0.4, 0.3, 0.35]) ** 2, axis=1) < 1.0)
    lattice = (local - (np.array([-0.4, -0.3, -0.35]) + 0.025)) / 0.05  # the bounding box corner + r
    assert np.allclose(lattice, np.round(lattice), atol=1e-3)
    sim = Simulation(load_quiet(write(scenes, data)), device="cpu")
    sim.run(frames=1)
    assert sim.num_fluid == 1416


def test_fluid_models_from_particle_files_are_refused(scenes):
    data = edited(FluidModels=[{"particleFile": "../models/bunny.bgeo", "translation": [0, 0.5, 0]}])
    with pytest.raises(SceneError, match=r"FluidModels\[0\].particleFile: '../models/bunny.bgeo': fluid read from a "
                                         r"particle file"):
        load_scene(write(scenes, data))


def test_walls_stand_where_splishsplashs_hold_the_fluid(scenes):
    """A volume-map container (boundaryHandlingMethod 2) holds a fluid at rest 2.40 r from its surface (pysplishsplash
    2.19.0, a tank at rest after 1.5 s: the floor's layer 2.35 r, the side walls' 2.45 r); warpsph's wall layer holds
    it 2.20 r from itself: the layer stands 0.20 r inside the box, the domain's faces 1.2 r inside that. Boundary
    particles (method 0) lie on the surface, as warpsph's layer."""
    from warpsph.io.splishsplash import volume_map_standoff, wall_layer_standoff

    assert volume_map_standoff() == pytest.approx(2.40, abs=0.005)
    assert wall_layer_standoff() == pytest.approx(2.20, abs=0.005)
    box = np.array([[-0.6, 0.0, -0.25], [0.6, 1.0, 0.25]])
    layer = volume_map_standoff() - wall_layer_standoff()  # radii inside the box
    for method, thickness, inside in ((2, 0.0, layer), (2, 0.006, layer - 0.2), (0, 0.006, 0.0)):
        data = edited(Configuration__boundaryHandlingMethod=method, RigidBodies__0__mapThickness=thickness)
        scene = load_quiet(write(scenes, data))
        inset = (inside + 1.2) * 0.03
        assert scene.domain.min == pytest.approx(box[0] + inset) and scene.domain.max == pytest.approx(box[1] - inset)
        walls = sample_scene(scene)[2]
        assert walls.min(axis=0) == pytest.approx(box[0] + inside * 0.03, abs=1e-6)
        assert walls.max(axis=0) == pytest.approx(box[1] - inside * 0.03, abs=1e-6)
        # the block SPlisHSPlasH starts 2r from the left wall and the floor, inside the band its walls push the
        # fluid out of, moves into the domain with all its particles
        (block,) = scene.fluid_blocks
        assert block.start[:2] == pytest.approx(scene.domain.min[:2]) and block.start[2] == pytest.approx(-0.17)
        assert count_particles(scene)[0] == conversion_of(scene).splishsplash_particles == 4 * 6 * 6
        assert any("FluidBlocks[0] starts inside the band" in n for n in conversion_of(scene).notes) == (inset > 0.03)


def test_blocks_wider_than_the_walls_hold_keep_the_layers_that_fit(scenes):
    """SPlisHSPlasH fills 6 layers across this 0.4 m box, where its walls hold 5 at rest: it starts them compressed
    (a particle 1.33 r from the wall); warpsph fills the 5 that fit and says so."""
    scene = load_quiet(write(scenes, edited(RigidBodies__0__scale=[1.2, 1, 0.4])))
    (block,) = scene.fluid_blocks
    assert block.start[2] >= scene.domain.min[2] and block.end[2] <= scene.domain.max[2]
    assert count_particles(scene)[0] == 4 * 6 * 5 and conversion_of(scene).splishsplash_particles == 4 * 6 * 6
    assert any("wider along z" in n and "120 particles of 144" in n for n in conversion_of(scene).notes)
    sim = Simulation(scene, device="cpu").run(frames=1)
    assert sim.num_fluid == 120


# --- 3. physics: mapped, or refused by name ---------------------------------------------------------------


def test_dynamic_bodies_become_warpsph_dynamic_bodies(scenes):
    data = copy.deepcopy(DAM_BREAK)
    data["RigidBodies"].append({"geometryFile": "../models/UnitBox.obj", "translation": [0.3, 0.5, 0],
                                "scale": [0.15, 0.15, 0.15], "isDynamic": True, "density": 400,
                                "velocity": [0, -1, 0], "friction": 0.1, "collisionObjectType": 2})
    data["RigidBodies"].append({"geometryFile": "../models/UnitBox.obj", "translation": [0.3, 0.15, 0],
                                "scale": [0.1, 0.1, 0.1], "isDynamic": True})
    scene = load_quiet(write(scenes, data))
    heavy, light = scene.obstacles
    assert heavy.dynamics.density == 400 and heavy.dynamics.velocity == (0, -1, 0)
    assert light.dynamics.density == 1.0  # PositionBasedDynamics' default density
    # contact: PositionBasedDynamics multiplies the restitutions and adds the frictions of the body and the container
    container = next(b for b in data["RigidBodies"] if b.get("mapInvert"))
    e_walls, mu_walls = container.get("restitution", 0.6), container.get("friction", 0.2)
    assert heavy.dynamics.restitution == pytest.approx(0.6 * e_walls)
    assert heavy.dynamics.friction == pytest.approx(0.1 + mu_walls)
    assert light.dynamics.friction == pytest.approx(0.2 + mu_walls)
    assert any("PositionBasedDynamics contact" in n for n in conversion_of(scene).notes)
    sim = Simulation(scene, device="cpu")
    assert sum(b.kind == "dynamic" for b in sim.bodies) == 2


def test_bodies_hold_the_fluid_where_splishsplashs_do(scenes):
    """A body's volume map (boundaryHandlingMethod 2) holds the fluid 2.40 r from its surface (mapThickness
    further), its boundary particles (method 0) 2.20 r: warpsph samples an imported body 0.20 r outside its
    surface (on it for method 0) so its layer, which holds the fluid 2.20 r from itself, stands where SPlisHSPlasH's
    boundary does. warpsph's own 1.2 r inset held it 1.0 r from the surface: in DamBreakWithObjects (r = 0.05 m,
    tools/results/splishsplash_bodies_*.json on the `results` branch) the torus and sphere rode 0.11 and 0.08 m
    deeper than in SPlisHSPlasH at 0.5 s (13.8 and 7.7 % of their travel; 1.0 and 1.7 % with this mapping)."""
    from warpsph.io.splishsplash import volume_map_standoff, wall_layer_standoff

    r, half = 0.03, 0.075
    for method, thickness, outside in ((2, 0.0, volume_map_standoff() - wall_layer_standoff()),
                                       (2, 0.006, volume_map_standoff() - wall_layer_standoff() + 0.2), (0, 0.006, 0.0)):
        data = edited(Configuration__boundaryHandlingMethod=method)
        data["RigidBodies"] += [{"geometryFile": "../models/UnitBox.obj", "translation": [0.3, 0.5, 0],
                                 "scale": [2 * half] * 3, "isDynamic": dynamic, "density": 400,
                                 "mapThickness": thickness} for dynamic in (True, False)]
        data["RigidBodies"][2]["translation"] = [0.0, 0.5, 0]
        scene = load_quiet(write(scenes, data))
        assert conversion_of(scene).body_insets == pytest.approx([-outside] * 2)
        bodies = sample_scene(scene)[4]
        for body in bodies:  # samples `outside` r beyond each face of the box
            extent = np.abs(body.samples).max(axis=0) if body.kind == "dynamic" else None
            if extent is not None:
                assert extent == pytest.approx(half + outside * r, abs=1e-5)
        static = bodies[1].world_samples() - np.array([0.0, 0.5, 0.0])
        assert np.abs(static).max(axis=0) == pytest.approx(half + outside * r, abs=1e-5)
        assert bodies[0].mass == pytest.approx(400 * (2 * half) ** 3)  # the mesh's volume, as PositionBasedDynamics'


def test_emitters_map_to_warpsph_emitters(scenes):
    data = copy.deepcopy(DAM_BREAK)
    # SPlisHSPlasH's Emitter.json style: 3x2 particles, emitting along the rotated x axis (-x by pi about y)
    data["Emitters"] = [{"width": 3, "height": 2, "translation": [0.4, 0.5, 0.0], "rotationAxis": [0, 1, 0],
                         "rotationAngle": 3.141592653589793, "velocity": 1.5, "emitStartTime": 0.05,
                         "emitEndTime": 10, "type": 0}]
    data["Materials"][0]["maxEmitterParticles"] = 6 * 3  # three layers
    scene = load_quiet(write(scenes, data))
    (e,) = scene.emitters
    d = 0.06
    assert e.velocity == pytest.approx((-1.5, 0.0, 0.0)) and e.start == 0.05
    assert e.min[0] == pytest.approx(0.4 - d / 2) and e.max[0] == pytest.approx(0.4 + d / 2)
    assert (e.max[2] - e.min[2], e.max[1] - e.min[1]) == (pytest.approx(3 * d), pytest.approx(2 * d))
    # maxEmitterParticles: three layers, d / v apart, then the emitter stops
    assert e.end == pytest.approx(0.05 + 2.5 * d / 1.5)
    from warpsph.inflow import layer_points

    assert len(layer_points(e, d)) == 6
    sim = Simulation(scene, device="cpu")
    sim.run(frames=5)  # to 0.2 s
    assert sim.num_fluid == 144 + 18


@pytest.mark.parametrize("change, refused", [
    ({"Configuration__sim2D": True}, "Configuration.sim2D: a 2D simulation"),
    ({"Materials__0__elasticityMethod": 2, "Materials__0__Peer et al. 2018": {"youngsModulus": 2e5}},
     "Materials[0].elasticityMethod: 2 (Peer et al. 2018): an elastic solid"),
    ({"Materials__0__surfaceTensionMethod": 4}, "Materials[0].surfaceTensionMethod: 4 (Jeske et al. 2023): surface tension"),
    ({"Materials__0__dragMethod": 2}, "Materials[0].dragMethod: 2 (Gissler et al. 2017)"),
    ({"Materials__0__viscosityMethod": 6, "Materials__0__Weiler et al. 2018": {"viscosity": 5}},
     "Materials[0].viscosityMethod: 6 (Weiler et al. 2018, an implicit viscosity solver, viscosity 5)"),
    ({"Materials__0__vorticityMethod": 2}, "Materials[0].vorticityMethod: 2 (vorticity confinement)"),
    ({"Materials__0__XSPH": {"xsph": 0.1}}, "Materials[0].XSPH.xsph: 0.1: XSPH"),
    ({"Configuration__simulationMethod": 0}, "Configuration.simulationMethod: 0 (WCSPH)"),
    ({"Configuration__scriptFile": "drive.py"}, "Configuration.scriptFile"),
    ({"FluidBlocks__0__initialAngularVelocity": [0, 1, 0]}, "FluidBlocks[0].initialAngularVelocity"),
    ({"AnimationFields": [{"particleField": "velocity", "expression_x": "1"}]}, "AnimationFields: 1 fields"),
    ({"FluidModels": [{"particleFile": "../models/bunny.bgeo"}]}, "FluidModels[0].particleFile: '../models/bunny.bgeo'"),
    ({"TargetVelocityMotorHingeJoints": [{"bodyID1": 1, "bodyID2": 0, "position": [0, 0, 0], "axis": [0, 1, 0],
                                          "target": 2}]},
     "TargetVelocityMotorHingeJoints: 1 of 1 motor joints warpsph cannot drive ([0] bodyID1 1 names no body)"),
    ({"BallJoints": [{"bodyID1": 1, "bodyID2": 0, "position": [0, 0, 0]}]}, "BallJoints: 1 joints between rigid bodies"),
])
def test_unsupported_physics_is_refused_by_key(scenes, change, refused):
    path = write(scenes, edited(**change))
    with pytest.raises(SceneError, match="physics warpsph does not simulate") as info:
        load_scene(path)
    assert refused in str(info.value) and "WARPSPH_SPLISHSPLASH_RUN_ANYWAY" in str(info.value)


def test_an_iisph_scene_runs_with_iisph_and_its_block(scenes):
    """simulationMethod 3 is IISPH (solver.method "iisph"), with the IISPH block's iteration limits and maxError;
    the DFSPH block of the same file is left unread, as SPlisHSPlasH leaves it."""
    data = edited(Configuration__simulationMethod=3)
    data["Configuration"]["IISPH"] = {"minIterations": 3, "maxIterations": 60, "maxError": 0.02}
    path = write(scenes, data)
    scene = load_scene(path)
    assert scene.solver.method == "iisph"
    assert (scene.solver.min_iterations, scene.solver.max_iterations, scene.solver.density_max_error) == (3, 60, 0.02)
    mapped = "\n".join(conversion_of(scene).mapped)
    assert "Configuration.simulationMethod -> solver.method = \"iisph\"" in mapped
    assert "Configuration.IISPH.maxError -> solver.density_max_error = 0.02" in mapped
    sim = Simulation(scene, device="cpu")
    for _ in range(5):
        sim.step()
    assert sim.check_health() is None and "iisph" in type(sim.pressure_solver).__name__.lower()


def test_extra_phases_are_refused_and_run_anyway_from_the_file(scenes):
    data = copy.deepcopy(DAM_BREAK)
    data["FluidBlocks"].append({"id": "oil", "start": [0.1, 0.0, -0.2], "end": [0.4, 0.3, 0.2]})
    data["Materials"].append({"id": "oil", "density0": 800})
    with pytest.raises(SceneError, match=r"2 fluid phases \('Fluid', 'oil'\)"):
        load_scene(write(scenes, data))
    data["warpsph"] = {"run_anyway": True}
    with pytest.warns(SplishSplashWarning, match="RUN ANYWAY, left out: .*2 fluid phases"):
        scene = load_scene(write(scenes, data))
    c = conversion_of(scene)
    assert c.run_anyway and len(c.refused) == 1 and scene.fluid.density == 1000
    assert len(scene.fluid_blocks) == 2  # both blocks, as the first phase


def test_run_anyway_argument_and_no_container_is_an_open_domain(scenes):
    """Without a container (no mapInvert body) the scene runs in an open domain around its fluid and bodies:
    no walls, particles that leave it are removed (and counted)."""
    data = edited(Configuration__sim2D=True)
    with pytest.warns(SplishSplashWarning, match="sim2D"):
        out = convert(data, write(scenes, data), run_anyway=True)
    assert out["fluid_blocks"]
    data = edited(RigidBodies=[])
    c = translate(data, write(scenes, data))
    assert not c.errors and any("no container" in m for m in c.mapped)
    domain = c.scene["domain"]
    assert domain["walls"] is False
    for block in c.scene["fluid_blocks"]:
        assert all(lo < s and e < hi for lo, s, e, hi in zip(domain["min"], block["start"], block["end"], domain["max"]))
    with pytest.warns(SplishSplashWarning, match="approximations"):
        scene = load_scene(write(scenes, data))
    assert not scene.domain.walls


@pytest.mark.parametrize("clips", [False, True])
def test_run_anyway_flag_records_what_is_left_out(scenes, tmp_path, capsys, clips):
    """warpsph run refuses a scene with physics it does not simulate, naming the key; with --run-anyway it runs,
    prints the list and records it in the cache's metadata and beside the stats CSV (which stays plain CSV)."""
    from pxr import Sdf

    from warpsph.cli import main
    from warpsph.diagnostics import read_csv, read_metadata

    path = write(scenes, edited(Materials__0__surfaceTensionMethod=2, Configuration__stopAt=0.04))
    out = tmp_path / "run.usdc"
    args = ["run", str(path), "--device", "cpu", "--out", str(out), "--scale", "0.3"] + (["--clips"] if clips else [])
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "Materials[0].surfaceTensionMethod: 2 (Akinci et al. 2013): surface tension" in err and not out.exists()
    assert main(args + ["--run-anyway"]) == 0
    err = capsys.readouterr().err
    assert "RUN ANYWAY, left out: Materials[0].surfaceTensionMethod" in err and "warpsph:import_dropped" in err
    (item,) = Sdf.Layer.OpenAsAnonymous(str(out)).customLayerData["warpsph:import_dropped"]
    assert item.startswith("Materials[0].surfaceTensionMethod: 2 (Akinci et al. 2013): surface tension")
    assert read_metadata(out.with_suffix(".stats.csv")) == {"warpsph:import_dropped": [item]}
    assert list(read_csv(out.with_suffix(".stats.csv"))["frame"]) == [0, 1]
    # an ordinary run over it: no list, and the old one is gone
    assert main(["run", str(write(scenes, DAM_BREAK)), "--device", "cpu", "--out", str(out), "--scale", "0.3",
                 "--frames", "1", "--overwrite"] + (["--clips"] if clips else [])) == 0
    assert "warpsph:import_dropped" not in Sdf.Layer.OpenAsAnonymous(str(out)).customLayerData
    assert read_metadata(out.with_suffix(".stats.csv")) == {}


def test_every_key_is_accounted_for(scenes):
    """Nothing is dropped silently: each key of the file is mapped, refused or noted."""
    data = copy.deepcopy(DAM_BREAK)
    data["Configuration"]["imteStepSize"] = 0.001  # a typo: SPlisHSPlasH does not read it either
    c = translate(data, write(scenes, data))
    text = "\n".join(c.mapped + c.refused + c.notes)
    for key in ("numberOfStepsPerRenderUpdate", "enablePartioExport", "imteStepSize", "colorMapType",
                "RigidBodies[0].color", "mapResolution", "timeStepSize", "Standard viscosity.viscosity",
                "DFSPH.maxIterationsV", "density0", "FluidBlocks[0]"):
        assert key in text, key


# --- 5. the tolerance means the same thing: volume convention and density error measure ----------------

# pysplishsplash 2.19.0 on its DamBreakModel (r = 0.025 m, density0 1000), measured by
# tools/splishsplash_side_by_side.py through its Python API: FluidModel.getVolume(0) and getMass(0), and the
# median density of the block's particles after the first step (the bulk of the lattice of spacing 2r).
# SPlisHSPlasH up to 2.16 (FluidModel::initMasses) gave fluid particles 0.8 (2r)^3; 2.19 gives (2r)^3.
SPLISHSPLASH_219 = {"radius": 0.025, "volume": 1.25e-4, "mass": 0.125, "bulk_density": 0.9999721}


def _cubic(r, H):
    """SPlisHSPlasH's CubicKernel::W and gradW (support radius H), written out here in numpy."""
    q = r / H
    k, l = 8.0 / (np.pi * H**3), 48.0 / (np.pi * H**3)
    w = np.where(q <= 0.5, k * (6 * q**3 - 6 * q**2 + 1), np.where(q <= 1.0, 2 * k * (1 - q) ** 3, 0.0))
    dw = np.where(q <= 0.5, l * q * (3 * q - 2), np.where(q <= 1.0, -l * (1 - q) ** 2, 0.0)) / H  # dW/dr
    return w, dw


def _splishsplash_average_density_error(x, v, xb, vb_volume, volume, h, H):
    """TimeStepDFSPH (SPlisHSPlasH 2.16 source, Akinci boundary): densityAdv_i = rho_i / rho0 + h (V sum_j
    (v_i - v_j).gradW_ij + sum_b V_b v_i.gradW_ib); the first iteration's avg_density_err / rho0 (p = 0)
    is the mean over all fluid particles of -min(1 - densityAdv_i, 0), compared with maxError * 0.01."""
    d = x[:, None, :] - x[None, :, :]
    r = np.linalg.norm(d, axis=2)
    w, dw = _cubic(r, H)
    grad = np.where(r[..., None] > 1e-9, dw[..., None] * d / np.maximum(r, 1e-12)[..., None], 0.0)
    db = x[:, None, :] - xb[None, :, :]
    rb = np.linalg.norm(db, axis=2)
    wb, dwb = _cubic(rb, H)
    gradb = np.where(rb[..., None] > 1e-9, dwb[..., None] * db / np.maximum(rb, 1e-12)[..., None], 0.0)
    density = volume * w.sum(1) + (vb_volume[None, :] * wb).sum(1)  # rho / rho0, self term included (r = 0)
    rate = volume * np.einsum("ijk,ijk->i", v[:, None, :] - v[None, :, :], grad)
    rate += np.einsum("ik,ijk->i", v, vb_volume[None, :, None] * gradb)
    density_adv = density + h * rate
    return float(np.mean(-np.minimum(1.0 - density_adv, 0.0))), density


def test_fluid_volume_is_splishsplash_219s(scenes):
    data = edited(Configuration__particleRadius=SPLISHSPLASH_219["radius"], FluidBlocks__0__end=[-0.1, 0.4, 0.2])
    scene = load_quiet(write(scenes, data))
    sim = Simulation(scene, device="cpu")
    assert sim.fluid_volume == pytest.approx(SPLISHSPLASH_219["volume"], rel=1e-6)
    assert sim.particle_mass == pytest.approx(SPLISHSPLASH_219["mass"], rel=1e-6)
    # the same lattice has the same bulk density in both (SPlisHSPlasH 2.16's 0.8 (2r)^3 would give 0.8):
    # particles a support radius inside the block, away from its free faces and the walls
    x = sim.fluid.x.numpy()[: sim.num_fluid]
    inside = np.all((x > x.min(0) + sim.support_radius) & (x < x.max(0) - sim.support_radius), axis=1)
    rho = sim.fluid.density.numpy()[: sim.num_fluid][inside] / sim.rest_density
    assert inside.sum() > 10 and np.median(rho) == pytest.approx(SPLISHSPLASH_219["bulk_density"], abs=2e-4)


def test_density_error_is_splishsplashs_measure_and_max_error_maps_one_to_one(scenes):
    from warpsph.solvers.dfsph import DENSITY

    scene = load_quiet(write(scenes, DAM_BREAK))
    assert scene.solver.density_max_error == DAM_BREAK["Configuration"]["DFSPH"]["maxError"]  # factor 1, in %
    sim = Simulation(scene, device="cpu")
    n = sim.num_fluid
    x = sim.fluid.x.numpy()[:n].astype(np.float64)
    # a compressing, shearing velocity field towards the floor and the left wall: errors of both signs
    rng = np.random.default_rng(3)
    v = -0.8 * (x - x.mean(0)) + np.array([-0.3, -1.0, 0.0]) + 0.2 * rng.standard_normal(x.shape)
    sim.fluid.v.assign(v.astype(np.float32))
    h = 0.004
    sim.dt.fill_(h)
    sim.update_densities()
    solver = sim.pressure_solver
    solver.detect_free_surface()
    assert solver.free_surface_count() > 0  # free-surface flow: p >= 0 everywhere, as in SPlisHSPlasH
    solver._measure(DENSITY, solver._density_inputs(), 1e-4, 2, 100, True)
    ours = solver.last_errors()[1]

    xb = sim.boundary.x.numpy().astype(np.float64)
    vb = sim.boundary.volume.numpy().astype(np.float64)
    theirs, density = _splishsplash_average_density_error(x, v, xb, vb, (2 * scene.particle_radius) ** 3, h,
                                                         sim.support_radius)
    np.testing.assert_allclose(sim.fluid.density.numpy()[:n] / sim.rest_density, density, rtol=2e-5)
    assert theirs > 1e-3  # the field compresses: the comparison is not of zeros
    assert ours == pytest.approx(theirs, rel=1e-3)
