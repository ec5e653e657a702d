"""A box the fluid fills, with walls (a full tank): the corrected kernel gradient in its single density solve,
the shift's particle-scale part and the corrected viscous operator (warpsph/solvers/dfsph.py, kernels/shifting.py,
kernels/viscosity.py), against the Lamb-Oseen vortex and analytic fields."""

import numpy as np
import pytest
import warp as wp

from conftest import make_sim, tank_scene


def _full_tank(device, radius=0.025, viscosity=0.01):
    """A closed 0.5 x 0.5 x 0.2 m box filled with water at rest, no gravity: 10 x 10 x 4 particles."""
    return make_sim(tank_scene(radius=radius, domain=(0.5, 0.5, 0.2), block=(0.5, 0.5, 0.2), gravity=[0, 0, 0],
                               fluid={"viscosity": viscosity}), device=device)


@pytest.mark.slow
def test_lamb_oseen_error_falls_with_resolution_on_the_cpu():
    """The L1 error of u_theta at T falls from 16 across to 24 and 32 with the default solver, the core's peak
    vorticity is within 5 % of the analytic one at 32 across. Measured: 4.39 / 1.34 / 0.98 % with the bulk's
    viscosity as the divergence of the strain rate (2.60 / 1.40 / 1.29 % with the componentwise Laplacian before it;
    3.67 / 1.85 / 2.05 % before the corrected operators); the summation density, whose mean the sealed box's solve
    removes, ends ~1.5 % above rho0."""
    from warpsph.validation.cases import lamb_oseen_row

    rows = [lamb_oseen_row([], n, "cpu") for n in (16, 24, 32)]
    errors = [r["error_pct"] for r in rows]
    assert errors[0] > max(errors[1:]), errors
    assert max(errors[1:]) < 1.5, errors
    assert errors[2] < 0.33 * errors[0]
    assert abs(rows[2]["omega_ratio"] - 1.0) < 0.05
    assert abs(rows[2]["density_error_mean_pct"]) < 2.2  # measured +1.47 %: the removed mean drift creeps


def test_corrected_viscosity_is_right_for_a_shear_along_the_particle_rows(device):
    """v = (c y^2, 0, 0) on the lattice: nu laplacian v = (2 c nu, 0, 0). Eq 4 damps a shear along the particle
    rows as if nu were 0.7 nu (docs/notes/solver.md); the corrected operator of a full tank gets it within 5 %
    away from the walls."""
    nu, c = 0.01, 3.0
    sim = _full_tank(device, radius=0.0125, viscosity=nu)
    sim.step()  # neighbours and density
    x = sim.fluid.x.numpy()
    sim.fluid.v.assign(np.stack([c * x[:, 1] ** 2, 0 * x[:, 1], 0 * x[:, 1]], axis=1).astype(np.float32))
    inner = np.all((x[:, :2] > 0.1) & (x[:, :2] < 0.4), axis=1) & (x[:, 2] > 0.05) & (x[:, 2] < 0.15)
    assert inner.sum() > 100
    exact = 2 * c * nu
    got = {}
    for corrected in (True, False):
        model = sim.viscosity_model
        model.corrected = corrected
        sim.fluid.acceleration.zero_()
        model.step(sim.model_context)
        got[corrected] = sim.fluid.acceleration.numpy()[inner]
    assert abs(np.mean(got[True][:, 0]) / exact - 1) < 0.05
    assert np.abs(got[True][:, 1:]).max() < 0.05 * exact
    assert np.mean(got[False][:, 0]) / exact < 0.8  # eq 4 (the check can fail)


def test_shift_moves_only_the_particle_scale_part(device):
    """In a full tank the shift follows grad C less its kernel-weighted mean over the bulk neighbours: a grad C
    that is the same at every particle (the curvature of particle rows about a vortex reads so) moves no bulk
    particle; one that alternates from particle to particle (by lattice parity) moves them."""
    from warpsph.kernels.free_surface import BULK
    from warpsph.kernels.shifting import compute_shift

    sim = _full_tank(device, radius=0.0125)
    sim.fluid.v.fill_(wp.vec3(0.1, 0.0, 0.0))
    sim.step()
    solver, n = sim.pressure_solver, sim.num_fluid
    bulk = solver.surface.numpy()[:n] == BULK
    assert bulk.sum() > 50
    x = sim.fluid.x.numpy()[:n]
    lattice = np.round(x / sim.scene.particle_diameter).astype(int)
    alternating = np.where(lattice.sum(1) % 2 == 0, 1.0, -1.0)
    dt = float(sim.dt.numpy()[0])
    for pattern, moves in ((np.ones(n), False), (alternating, True)):
        gradient = np.zeros((n, 3), dtype=np.float32)
        gradient[:, 0] = 10.0 * pattern
        solver.concentration_gradient.assign(np.concatenate(
            [gradient, np.zeros((solver.concentration_gradient.shape[0] - n, 3), dtype=np.float32)]))
        sim.launch(compute_shift, n, [solver.concentration_gradient, sim.fluid.x, sim.neighbours.lists, solver.surface,
                                      solver.free_surface, sim.support_radius, sim.dt, sim.max_speed_sq,
                                      solver.shifting, 1.0, 1, solver.shift])
        shift = np.linalg.norm(solver.shift.numpy()[:n][bulk], axis=1)
        speed = float(np.sqrt(sim.max_speed_sq.numpy()[0]))
        full = solver.shifting * 0.5 * sim.support_radius * speed * dt * 10.0  # |D grad C| of the unfiltered field
        if moves:
            assert np.median(shift) > 0.5 * full
        else:
            assert shift.max() < 1e-3 * full
