"""One solver for every scene (#37): the corrected operators wherever a particle's support is whole, plain ones on
the free surface and its band; sealed tanks at rest under gravity; a warm start that a dt drop does not turn into
a kick; validation with free surfaces (a vortex below one, a standing wave)."""

import numpy as np
import pytest

from conftest import make_sim, tank_scene

pytestmark = pytest.mark.slow  # every test runs a tank, a wave or a vortex for seconds of simulated time


def test_vortex_below_a_free_surface_converges_on_the_cpu():
    """The Lamb-Oseen vortex in a box filled to 0.88 L under gravity (``warpsph validate vortex-surface``). Before
    the corrected operators reached free-surface scenes the error was flat at ~38 % (38.5 % at 16 across on the
    CPU, 38.7 / 38.0 / 38.1 % at 64 / 128 / 256 on an H100). Measured here: 5.74 / 1.52 % at 16 / 24 across with the
    bulk's viscosity as the divergence of the strain rate (10.1 / 3.02 % with the componentwise Laplacian before it).
    The kinetic energy at r < 0.35 L at 24 across: 1.028 of the analytic vortex's, started as the vortex below a lid
    at the surface (lamb_oseen.boxed_velocity); 1.070 from the unbounded vortex, whose net momentum along x and flow
    through the surface started the tank's first sloshing mode."""
    from warpsph.validation.cases import vortex_surface_row

    rows = [vortex_surface_row([], n, "cpu") for n in (16, 24)]
    errors = [r["error_pct"] for r in rows]
    assert errors[1] < 0.75 * errors[0], errors
    assert errors[1] < 2.2, errors
    assert abs(rows[1]["density_error_mean_pct"]) < 0.5
    r = rows[1]
    assert r["ke_exact_ratio"] < 1.05, r["ke_exact_ratio"]
    # the angular momentum about the axis at 24 across: 0.710 of the start, of which the walls' pressure took 24.8 %
    # and gravity 4.2 % (external: a square box, and a surface that moves the centre of mass off the axis; gravity's
    # was 16.8 % while the unbounded start made the tank slosh), the fluid's own forces +0.002 % (+0.013 % at 16):
    # eq 4 with the pair's mean volume. With m / rho_j from each side (unequal central pair forces across the
    # surface's density drop) they took -0.43 % (-0.36 % at 16); -2.9 % with the componentwise Laplacian, whose pair
    # forces lie along v_ij
    assert r["angular_momentum_wall_share"] < -0.1 and -0.1 < r["angular_momentum_gravity_share"] < 0
    assert abs(r["angular_momentum_internal_share"]) < 1e-4, r
    assert abs(rows[0]["angular_momentum_internal_share"]) < 2e-4, rows[0]


def test_angular_momentum_budget_closes_without_viscosity():
    """The Lamb-Oseen vortex in the full tank at 16 across, without viscosity and shift: the fluid's own forces (the
    corrected pressure, whose pair torques cancel because L_i = M_i^-T: sum_j x_ij x L_i grad W_ij = 0) leave the
    angular momentum alone, so what the walls' pressure and gravity did (lamb_oseen.AngularMomentumBudget) is the
    whole change: measured 0.8998 of the start, all of it the walls' (-10.0 %), 0.0000 left; with the default
    viscosity (the divergence of the strain rate, also torque-free) the fluid's own share is +0.04 %."""
    from warpsph.validation.cases import lamb_oseen_row

    r = lamb_oseen_row([], 16, "cpu", overrides={"fluid.viscosity": 0.0, "solver.shifting": 0.0})
    assert r["angular_momentum_wall_share"] < -0.05
    assert abs(r["angular_momentum_internal_share"]) < 1e-3, r
    assert abs(r["angular_momentum_ratio"] - 1.0 - r["angular_momentum_wall_share"]) < 1e-3


def _sealed_tank(device, fill=1.0, fixed_dt=None, n=8):
    side = 0.16
    data = tank_scene(radius=side / (2 * n), domain=(side, side, side), block=(side, fill * side, side),
                      fluid={"viscosity": 0.01}, output={"fps": 20})
    if fixed_dt:
        data["time"] = {"fixed_dt": fixed_dt}
    return make_sim(data, device=device), side


def _max_speed(sim):
    return float(np.linalg.norm(sim.velocities(), axis=1).max())


def test_sealed_tank_under_gravity_stays_at_rest(device):
    """A closed box of water filled to the lid under gravity. The mean of the density source used to be removed in
    every box without free surface; with Akinci walls that mean is real compression and the tank blew up within
    ~20 steps. Its bulk solves for p >= 0 like any scene under gravity: with signed pressure whenever no particle
    was on a free surface it pulled at -4.3 kPa (the floor's load is 1.6 kPa) in 29 density iterations a step, and
    at 32 across the step where the last gap particle closed switched the whole tank and shot it to 36 m/s.
    Measured (CPU, 8 across, 1 s): mean density 1.0001 rho0, max |v| 1.36e-2 sqrt(gH) (the goal of #37 is 1e-3,
    not reached), least pressure 0, 12.8 density iterations a step."""
    sim, side = _sealed_tank(device)
    least = []
    sim.run(until_time=1.0, on_step=lambda *_: least.append(sim.pressure_solver.pressure_field().min()))
    assert sim.pressure_solver.free_surface_count() == 0
    assert min(least) >= 0.0
    density = sim.host(sim.fluid.density) / sim.rest_density
    assert abs(density.mean() - 1.0) < 1e-3
    assert _max_speed(sim) < 0.02 * np.sqrt(9.81 * side)


def test_a_dt_drop_does_not_kick_a_settled_tank(device):
    """A pool settles at a fixed dt, then takes one step at a tenth of it. The bulk's warm start was rescaled by
    (dt_prev / dt)^2 = 100: the settled tank jumped from 0.012 to 0.23 m/s."""
    sim, side = _sealed_tank(device, fill=0.75, fixed_dt=0.002)
    sim.run(until_time=0.8)
    before = _max_speed(sim)
    sim._dt_scale = 0.1  # what an on-instability retry does (Simulation._advance_to)
    sim.step()
    sim._dt_scale = 1.0
    sim.step()
    assert _max_speed(sim) < max(2.0 * before, 0.02), (before, _max_speed(sim))


def test_every_scene_launches_the_corrected_operators_with_plain_ones_at_the_surface(device):
    """No scene regime: a pool and a full tank launch the same kernels; L_i is the identity on the surface and its
    band and a proper inverse in the bulk."""
    from warpsph.kernels.density_solver import compute_corrected_density_source
    from warpsph.kernels.free_surface import BAND, SURFACE
    from warpsph.kernels.particles import symmetric_matrices
    from warpsph.solvers.dfsph import DENSITY

    pool = make_sim(tank_scene(fluid={"viscosity": 0.01}), device=device)
    full, _ = _sealed_tank(device)
    for sim in (pool, full):
        sim.step()
        for kernel in ("compute_gradient_correction", "compute_strain_rate",
                       "add_corrected_viscosity_acceleration", "compute_shift"):
            assert sim.launches[kernel] >= 1, kernel
        assert sim.pressure_solver._source(DENSITY) is compute_corrected_density_source
    flags = pool.host(pool.pressure_solver.surface)
    correction = symmetric_matrices(pool.host(pool.pressure_solver.gradient_correction))
    at_surface = (flags == int(SURFACE)) | (flags == int(BAND))
    assert at_surface.sum() > 50 and (~at_surface).sum() > 50
    np.testing.assert_allclose(correction[at_surface], np.broadcast_to(np.eye(3), correction[at_surface].shape))
    assert np.abs(correction[~at_surface] - np.eye(3)).max() > 1e-3


def test_standing_wave_frequency_and_decay_follow_linear_theory():
    """The first sloshing mode of a tank 1 m long, 0.5 m deep (``warpsph validate standing-wave``) at 16 across:
    frequency against w^2 = g k tanh(k h), amplitude decay against 2 nu k^2. Measured: +0.4 % and 3.2x the
    viscous rate (the numerical dissipation of 8 particles in depth); 44aa455 gave +6.5 % and 4.3x. At this size the
    run is sensitive to rounding: the same pressure force summed in another order gives -0.5 % and 3.8x, L_i stored
    as its six entries -2.2 % and 4.0x."""
    from warpsph.validation.standing_wave import standing_wave

    t, amps, sim, s = standing_wave(16, "cpu")
    assert amps[0] == pytest.approx(1.0, rel=0.01)
    assert abs(s["frequency_error_pct"]) < 5.4
    assert 1.0 < s["decay_rate"] / s["decay_rate_theory"] < 4.8


def test_tanks_rest_for_five_seconds():
    """`warpsph validate tank-at-rest` at 6 across: a sealed box and pools (5 of 6 layers) rest under gravity for 5 s.
    Measured: the largest speed of the last second 1.77 % of sqrt(gH) sealed, 1.55 % in the pools (0.90 / 0.33 % with
    the componentwise viscous Laplacian before the divergence of the strain rate; the goal of #37 is 0.1 %, not
    reached); mean density error 0.010 / 0.015 %; no surface particle in the sealed box, 32 in a pool."""
    from warpsph.validation.cases import validate

    row = validate("tank-at-rest", [6])["rows"][0]
    assert not row.get("unstable") and len(row["tanks"]) == 4
    sealed, pools = row["tanks"][0], row["tanks"][1:]
    assert sealed["surface_particles_end"] == 0 and all(p["surface_particles_end"] > 0 for p in pools)
    assert sealed["max_speed_over_sqrt_gH"] < 0.027
    assert all(p["max_speed_over_sqrt_gH"] < 0.024 for p in pools)
    assert all(abs(t["density_error_mean_pct"]) < 0.025 for t in row["tanks"])


def _channel(device, radius=0.015):
    """A channel periodic in x, walled in y and z, filled, without gravity; a slab of it moves at 0.5 m/s."""
    data = {"name": "channel", "particle_radius": radius, "gravity": [0, 0, 0],
            "domain": {"min": [0, 0, 0], "max": [0.6, 0.4, 0.4], "periodic": ["x"]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [0.24, 0.4, 0.4]},
                             {"start": [0.24, 0, 0], "end": [0.36, 0.4, 0.4], "velocity": [0.5, 0, 0]},
                             {"start": [0.36, 0, 0], "end": [0.6, 0.4, 0.4]}]}
    return make_sim(data, device=device)


def test_a_walled_channel_keeps_its_momentum(device):
    """Along a periodic axis nothing acts on the fluid from outside: its momentum stays. With the corrected or the
    plain viscous operator chosen per particle (bulk or surface band), a pair's two forces differed, and the channel
    gained about 5 % in 0.22 s (5.9 % in 0.45 s); a pair now weighs the two the same from both sides. Measured: 0.55 %."""
    sim = _channel(device)
    p0 = sim.velocities()[:, 0].sum()
    for _ in range(100):
        sim.step()
    assert abs(sim.velocities()[:, 0].sum() / p0 - 1.0) < 0.008
