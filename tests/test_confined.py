"""The confined-flow pressure mode (scene ``solver.clamp_pressure`` false): signed pressure, sources less
their mean, particle shifting (``solver.shifting``) or the transport velocity, and the packed start.
Taylor-Green in a full periodic box, 16 x 16 x 6 particles, plain DFSPH, T = 0.3 s (analytic KE(T)/KE(0) =
exp(-16 pi^2 nu T) = 0.62 at nu = 0.01); about 20 s on one CPU core for the six runs. Numbers:
tools/results/CONFINED_NOTES.md."""

import numpy as np
import pytest

from warpsph.validation.taylor_green import PACK_STEPS, taylor_green

T = 0.3
SOLVERS = {"clamped": None, "confined": {"clamp_pressure": False},
           "unshifted": {"clamp_pressure": False, "shifting": 0},
           "transport": {"clamp_pressure": False, "transport_velocity": 40}}
# KE(t)/KE(0) per frame of the clamped (default) solver at 16 across on the CPU: the confined mode must
# not change it. Recorded at main 14770c0 (the kernel gradient with one division moved the chaotic
# middle frames of this unstable run from the values recorded at 5e14e5e; the last 0.036 -> 0.032).
CLAMPED_KE = [1.0, 0.7287838042639748, 5.725874318517991, 1.5079221203261959, 0.5715520501979057,
              0.4705120431171146, 0.35407109330315323, 0.21547546479836222, 0.11620482729627969,
              0.060273950674213976, 0.03174051457476677]


@pytest.fixture(scope="module")
def runs():
    return {name: taylor_green([], resolution=16, nu=0.01, T=T, device="cpu", solver=solver)
            for name, solver in SOLVERS.items()}


def mean_density(sim):
    return float(sim.host(sim.fluid.density).mean() / sim.rest_density)


def test_clamped_default_is_unchanged(runs):
    rows, sim = runs["clamped"]
    assert [r["ke_ratio"] for r in rows] == pytest.approx(CLAMPED_KE, rel=1e-6, abs=0)
    assert sim.scene.solver.clamp_pressure and sim.pressure_solver.shifting == 0.0


def test_confined_energy_is_closer_to_analytic_than_clamped(runs):
    """Measured: KE ratio 0.647 confined, 0.036 clamped, 0.623 analytic."""
    rows, _ = runs["confined"]
    clamped, _ = runs["clamped"]
    exact = rows[-1]["ke_ratio_exact"]
    assert abs(rows[-1]["time"] - T) < 0.01
    error = abs(rows[-1]["ke_ratio"] / exact - 1)
    assert error < 0.1
    assert error < 0.2 * abs(clamped[-1]["ke_ratio"] / clamped[-1]["ke_ratio_exact"] - 1)


def test_confined_solver_converges(runs):
    """The signed solve reaches its tolerance (11 density iterations a step; the clamped one takes 77)."""
    _, sim = runs["confined"]
    div_it, div_n, dens_it, dens_n = sim.pressure_solver.iteration_totals()
    assert dens_n == sim.step_count and div_n == sim.step_count
    assert dens_it / dens_n < 0.25 * sim.scene.solver.max_iterations
    assert int(sim.pressure_solver.max_iteration_streak.numpy().max()) == 0


def test_shifting_holds_the_mean_density(runs):
    """The box is full and periodic: its volume cannot change, so the mean SPH density should stay at rho0.
    Without shifting the particles pair up under the signed pressure and the mean rises to 1.364 rho0
    (the mean removal hides it); with shifting it is 1.014 at 16 across (1.0055 at 24)."""
    unshifted = mean_density(runs["unshifted"][1])
    shifted = mean_density(runs["confined"][1])
    assert unshifted > 1.2
    assert abs(shifted - 1) < 0.02
    assert abs(shifted - 1) < 0.1 * (unshifted - 1)


@pytest.mark.xfail(strict=True, reason="known gap (tools/results/CONFINED_NOTES.md): at 16 across the shifted mean "
                                       "density is 1.014 rho0 at T, over the 1 % goal (24 across: 1.0055)")
def test_mean_density_within_one_percent(runs):
    assert abs(mean_density(runs["confined"][1]) - 1) < 0.01


def test_transport_velocity_follows_the_decay_and_holds_the_density(runs):
    """solver.transport_velocity 40 (replaces shifting): KE(t)/KE(0) at t = 0.09, 0.15, 0.3 s measured
    0.813, 0.753, 0.582 (analytic 0.862, 0.789, 0.623: -6, -5, -7 %) with no mid-run rise, mean density
    1.0086 rho0 at T."""
    rows, sim = runs["transport"]
    assert sim.pressure_solver.shifting == 0.0 and sim.pressure_solver.transport == 40
    for frame in (3, 5, 10):
        assert abs(rows[frame]["ke_ratio"] / rows[frame]["ke_ratio_exact"] - 1) < 0.1, rows[frame]
    ke = [r["ke_ratio"] for r in rows]
    assert all(b < a for a, b in zip(ke, ke[1:]))  # decays every frame (shifting: flat / rising 0.09-0.18 s)
    assert abs(mean_density(sim) - 1) < 0.01


@pytest.fixture(scope="module")
def packed():
    """Taylor-Green from the particle packing, 16 across, plain DFSPH, with the Pareto study's solver
    (transport velocity 40, density tolerance 0.05 %)."""
    solver = dict(SOLVERS["transport"], density_max_error=0.05)
    return taylor_green([], resolution=16, nu=0.01, T=T, device="cpu", solver=solver, pack_steps=PACK_STEPS)


def _density_range(sim):
    sim.neighbours.update(sim.fluid.x)
    sim._compute_density()
    return np.abs(sim.host(sim.fluid.density) / sim.rest_density - 1.0).max()


def test_packing_evens_out_a_jittered_lattice():
    """The packing jitters the lattice by up to 0.1 spacing (one packing step leaves the summation density
    0.88-1.12 rho0 at 16 across) and relaxes it at rest: after 40 steps 0.984-1.021 rho0, and the positions
    are no longer a lattice."""
    from warpsph.validation.taylor_green import build

    one, _ = build([], resolution=16, T=T, device="cpu", solver=SOLVERS["transport"], pack_steps=1)
    sim, ke0 = build([], resolution=16, T=T, device="cpu", solver=SOLVERS["transport"], pack_steps=PACK_STEPS)
    jittered, relaxed = _density_range(one), _density_range(sim)
    assert jittered > 0.08 and relaxed < 0.03 and relaxed < 0.25 * jittered, (jittered, relaxed)
    x = sim.host(sim.fluid.x)
    offset = np.mod(x / (2 * sim.scene.particle_radius) - 0.5, 1.0)  # lattice sites sit at half spacings
    assert np.mean(np.minimum(offset, 1 - offset)) > 0.02
    assert ke0 > 0 and np.isfinite(ke0)


def test_packed_start_follows_the_decay_at_every_frame(packed):
    """From the packing the energy stays within 4.5 % of the analytic decay at every frame (measured -1.6 to
    -3.5 %; from the lattice -6 / -5 / -7 % at 0.09 / 0.15 / 0.3 s, and at 128+ across on the H100 the lattice
    shook apart with KE 12-30 % above the analytic curve), decays every frame and holds the mean density
    (1.004 rho0). With the default tolerance 0.01 % the loss grows to -7.3 % at T at this coarse size."""
    rows, sim = packed
    for r in rows[1:]:
        assert abs(r["ke_ratio"] / r["ke_ratio_exact"] - 1) < 0.045, r
    ke = [r["ke_ratio"] for r in rows]
    assert all(b < a for a, b in zip(ke, ke[1:]))
    assert abs(mean_density(sim) - 1) < 0.01
