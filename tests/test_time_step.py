"""The adaptive time step is SPlisHSPlasH's CFL rule (Simulation::updateTimeStepSizeCFL, 2.19):
dt = clamp(cflFactor * 0.4 * 2r / u, cflMinTimeStepSize, cflMaxTimeStepSize), u the largest of |v + g h| over the fluid
(h the last step) and |v| over the moving bodies' samples; warpsph keeps the explicit viscosity within its limit by
sub-steps (``solver.viscosity_substeps``), which imported SPlisHSPlasH files take as many as they need."""

import json
import math

import numpy as np
import pytest
import trimesh
import warp as wp

from conftest import make_sim, tank_scene
from warpsph import load_scene
from warpsph.kernels.integration import compute_max_body_speed, compute_max_speed, compute_time_step
from warpsph.kernels.pressure import REDUCE_THREADS
from warpsph.simulation import viscous_substeps

GRAVITY = np.array([0.0, -9.81, 0.0])


def splishsplash_dt(v, h, radius, cfl, dt_min, dt_max, bodies=()):
    """SPlisHSPlasH's CFL step of velocities ``v`` after a step ``h`` (its acceleration here gravity alone)."""
    speed = max([np.linalg.norm(np.asarray(v) + GRAVITY * h, axis=1).max()]
                + [np.linalg.norm(b) for b in bodies])
    return min(max(cfl * 0.4 * 2.0 * radius / max(speed, 1e-9), dt_min), dt_max)


def test_a_step_takes_splishsplash_cfl_step_of_its_velocities(device):
    """A tank whose fluid falls at 2 m/s and the last step 10 ms: u = |v + g h| = 2.098 m/s, not |v| = 2 m/s."""
    r, cfl, h = 0.02, 0.5, 0.01
    sim = make_sim(tank_scene(r, fluid={"viscosity": 0.0}, time={"cfl": cfl, "dt_min": 1e-5, "dt_max": 0.05}), device)
    v = np.zeros((sim.num_fluid, 3), np.float32)
    v[:, 1] = -2.0
    v[7] = (1.5, 0.5, 0.0)  # slower than the falling ones once gravity's h is added: the max is theirs
    sim.fluid.v[: sim.num_fluid].assign(v)
    sim.dt.assign(np.array([h], np.float32))
    sim.step()
    expected = splishsplash_dt(v, h, r, cfl, 1e-5, 0.05)
    assert float(sim.dt.numpy()[0]) == pytest.approx(expected, rel=1e-5)
    assert float(sim.dt_previous.numpy()[0]) == pytest.approx(h)
    # the fluid's own largest speed (particle shifting, the rest checks) stays max |v|
    assert math.sqrt(float(sim.max_speed_sq.numpy()[0])) == pytest.approx(np.linalg.norm(v, axis=1).max(), rel=1e-5)


def test_moving_bodies_speeds_bound_the_step(device):
    """The CFL speed takes the moving bodies' samples too, without gravity's term (SPlisHSPlasH's
    dynamic and animated bodies); the clamp to [dt_min, dt_max] is the last word."""
    with wp.ScopedDevice(device):
        fluid = wp.array(np.array([[0.0, -1.0, 0.0], [0.3, 0.0, 0.0]], np.float32), dtype=wp.vec3)
        body = wp.array(np.array([[0.0, 0.0, 4.0], [1.0, 0.0, 0.0]], np.float32), dtype=wp.vec3)
        last = wp.array(np.array([0.002], np.float32), dtype=float)
        speed = wp.zeros(2, dtype=float)
        wp.launch(compute_max_speed, REDUCE_THREADS, [fluid, 2, wp.vec3(*GRAVITY), last, wp.empty(0, dtype=float),
                                                      speed])
        assert math.sqrt(float(speed.numpy()[1])) == pytest.approx(1.0 + 9.81 * 0.002, rel=1e-5)
        wp.launch(compute_max_body_speed, REDUCE_THREADS, [body, 2, speed])
        assert math.sqrt(float(speed.numpy()[1])) == pytest.approx(4.0, rel=1e-5)
        assert math.sqrt(float(speed.numpy()[0])) == pytest.approx(1.0, rel=1e-5)  # the fluid's, untouched
        empty_i, empty_f = wp.empty(0, dtype=wp.int32), wp.empty(0, dtype=float)
        for dt_min, dt_max in ((1e-4, 5e-3), (1e-4, 1e-3), (3e-3, 5e-3)):
            dt, previous = wp.array(np.array([0.002], np.float32), dtype=float), wp.zeros(1, dtype=float)
            wp.launch(compute_time_step, 1, [speed, 0.05, 1.0, dt_min, dt_max, 0.0, 1.0e30, 1, 1.0, previous, dt,
                                             empty_i, empty_f])
            expected = splishsplash_dt([[0.0, -1.0, 0.0]], 0.002, 0.025, 1.0, dt_min, dt_max, bodies=[(0, 0, 4)])
            assert float(dt.numpy()[0]) == pytest.approx(expected, rel=1e-5)


def test_viscous_rate_bound_shortens_the_step(device):
    """The density pass's bound on the viscosity's largest rate (max_speed_sq[2]) caps the step at 1.9 / rate where
    that is below the lattice limit ``viscous_dt``, and sets the sub-steps' count from it."""
    with wp.ScopedDevice(device):
        fluid = wp.array(np.array([[0.0, -1.0, 0.0], [0.3, 0.0, 0.0]], np.float32), dtype=wp.vec3)
        rate = wp.array(np.array([1000.0, 2500.0], np.float32), dtype=float)
        speed, last = wp.zeros(3, dtype=float), wp.array(np.array([0.001], np.float32), dtype=float)
        wp.launch(compute_max_speed, REDUCE_THREADS, [fluid, 2, wp.vec3(*GRAVITY), last, rate, speed])
        assert float(speed.numpy()[2]) == pytest.approx(2500.0)
        for viscous_dt, substeps, expected_dt, expected_n in ((1e-3, 1, 1.9 / 2500, 1), (5e-4, 1, 5e-4, 1),
                                                              (1e-3, 4, 4 * 1.9 / 2500, 4)):
            dt, previous = wp.array(np.array([0.001], np.float32), dtype=float), wp.zeros(1, dtype=float)
            n, sub_dt = wp.zeros(1, dtype=wp.int32), wp.zeros(1, dtype=float)
            wp.launch(compute_time_step, 1, [speed, 0.05, 1.0, 1e-5, 1.0, 0.0, viscous_dt, substeps, 1.0, previous, dt,
                                             n, sub_dt])
            assert float(dt.numpy()[0]) == pytest.approx(expected_dt, rel=1e-5)
            assert int(n.numpy()[0]) == expected_n


@pytest.mark.parametrize("method", ["iisph", "dfsph"])
def test_dam_break_at_the_viscous_limit_stays_stable(method):
    """A dam break at the viscous limit (r = 1 cm, nu = 0.05: 0.125 (H/2)^2 / nu = 1 ms) with VR, to 0.32 s. At that
    lattice limit the flow's compressed pairs made the viscosity 1.3x stiffer than on the lattice, a pair of
    particles oscillated step to step and was thrown out at 4.6 (IISPH) / 5.2 (DFSPH) m/s; Ritter's front moves at
    2 sqrt(gH) = 3.4 m/s. With the step capped by the density pass's bound the fastest particle stays at 1.62 / 1.50
    m/s."""
    sim = make_sim(tank_scene(radius=0.01, domain=(0.61, 0.4, 0.12), block=(0.2, 0.3, 0.12),
                              models=[{"type": "vorticity_refinement"}], solver={"method": method}))
    fastest = []
    sim.run(until_time=0.3, on_step=lambda s: fastest.append(np.linalg.norm(s.velocities(), axis=1).max()))
    assert max(fastest) < 2.4


def test_viscosity_substeps_0_lets_the_step_follow_the_cfl_rule_alone():
    """``solver.viscosity_substeps`` 0: as many sub-steps as the longest step needs within the explicit limit, so the
    viscous limit no longer shortens the step. A tank at rest (r = 20 mm, nu = 0.1: limit 2 ms, dt_max 4 ms) steps
    at dt_max with 2 viscosity sub-steps a step, where the plain rule keeps the limit."""
    scene = tank_scene(0.02, fluid={"viscosity": 0.1}, time={"dt_max": 0.004}, solver={"viscosity_substeps": 0})
    sim = make_sim(scene)
    assert sim.viscous_dt == pytest.approx(0.002)
    assert sim.max_viscous_substeps == 4 == viscous_substeps(sim.scene, sim.viscous_dt)  # room for compressed pairs
    for _ in range(3):
        sim.step()
    assert float(sim.dt.numpy()[0]) == pytest.approx(0.004)
    assert sim.launches["add_corrected_viscosity_acceleration"] == 2 * sim.step_count
    assert sim.check_health() is None
    plain = make_sim(dict(scene, solver={"viscosity_substeps": 1}))
    plain.step()
    assert float(plain.dt.numpy()[0]) == pytest.approx(plain.viscous_dt, rel=1e-2)  # the lattice: at most that
    # never more than 64, however small the limit against dt_max
    stiff = make_sim(tank_scene(0.02, fluid={"viscosity": 50.0}, time={"dt_max": 0.004},
                                solver={"viscosity_substeps": 0}))
    assert stiff.max_viscous_substeps == 64


def test_splishsplash_files_take_viscosity_substeps_as_needed(tmp_path):
    """An imported SPlisHSPlasH scene runs its CFL rule alone, as SPlisHSPlasH does: its explicit viscosity
    sub-steps within the limit instead of shortening the step."""
    (tmp_path / "models").mkdir()
    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "models" / "UnitBox.obj")
    (tmp_path / "Scenes").mkdir()
    data = {
        "Configuration": {"particleRadius": 0.03, "simulationMethod": 4, "cflMethod": 1, "cflFactor": 1,
                          "cflMaxTimeStepSize": 0.005, "boundaryHandlingMethod": 2},
        "Materials": [{"id": "Fluid", "viscosityMethod": 1, "Standard viscosity": {"viscosity": 0.01}}],
        "RigidBodies": [{"geometryFile": "../models/UnitBox.obj", "translation": [0, 0.5, 0], "scale": [1.2, 1, 0.5],
                         "isDynamic": False, "isWall": True, "mapInvert": True}],
        "FluidBlocks": [{"start": [-0.6, 0.0, -0.2], "end": [-0.3, 0.4, 0.2]}],
    }
    path = tmp_path / "Scenes" / "DamBreak.json"
    path.write_text(json.dumps(data))
    with pytest.warns(Warning):
        scene = load_scene(path)
    assert scene.solver.viscosity_substeps == 0
    assert (scene.time.cfl, scene.time_step_bounds) == (1.0, (0.0001, 0.005))
