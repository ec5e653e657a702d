"""The DFSPH pressure solver (Bender & Koschier 2015/2017): divergence and density.

Both solvers share one loop: warm start, then iterate {apply pressure, recompute the
source and stiffness, average the error, decide} until the average error is below the
tolerance and the minimum iterations are done, or the maximum is reached. The decision
is made on the device (:func:`update_solver_status`) and the loop is a
``wp.capture_while``: on CUDA inside a captured graph no iteration waits on the host.

With ``solver.clamp_pressure`` false (confined flows: a closed or fully periodic box filled
with fluid) the sources are signed, less their mean, and the Jacobi step is relaxed (see
:func:`remove_mean_source`); particle shifting (``solver.shifting``, :func:`compute_shift`)
after the position update keeps the particles from pairing up under the negative pressure.
"""

from __future__ import annotations

import warp as wp

from warpsph.kernels.density_solver import compute_density_source
from warpsph.kernels.divergence_solver import compute_divergence_source
from warpsph.kernels.pressure import (
    REDUCE_THREADS,
    apply_pressure_acceleration,
    scale_warm_start,
    reduce_error,
    reduce_source_sum,
    remove_mean_source,
    update_solver_status,
)
from warpsph.kernels.shifting import apply_shift, compute_shift, compute_transport_shift, transport_velocity_correction

DIVERGENCE, DENSITY = 0, 1
# The largest per-particle error may be this many times the average tolerance (density:
# 0.01 % average, 1 % peak). Without it a 1M-particle dam break converged in 2 iterations on
# the average while its bottom layer was crushed to 2.2 rho0 within 5 steps and exploded.
PEAK_ERROR_RATIO = 100.0
# share of the last step's pressure that warm-starts each solver
# Share of the last step's pressure that warm-starts each solver. In a resting 10-layer tank
# (r = 0.02 m) the density solver takes 34 iterations a step cold, 23.5 at 0.5 and 6.8 at 0.9,
# and 1.0 lets the pressure ping-pong until the tank boils. But in a decaying vortex (dt 4 ms)
# 0.9 and 0.7 injected energy (KE rose to 122 % and 56 % where a cold start has 48 %); 0.5
# follows the cold-start decay within 1 %, so trust wins over speed here.
WARM_START_FACTOR = {DIVERGENCE: 0.5, DENSITY: 0.5}
# Confined mode (solver.clamp_pressure false): signed sources less their mean (see
# remove_mean_source), Jacobi relaxed by this factor (the clamped solve is plain Jacobi). Measured
# on Taylor-Green at 16 across (branch confined-solver, tools/results/CONFINED_NOTES.md): 1.0 and
# 0.6-0.8 blew up, 0.5: KE ratio 0.603 and 24.4 density iterations a step, 0.4: 0.589 and 28.5.
CONFINED_RELAXATION = 0.5
# Default solver.shifting (coefficient A of D = A h max|v| dt) in the confined mode. Taylor-Green
# (nu = 0.01, T = 0.3 s, dt = dt_max so max|v| dt = 0.1 spacing) at 16 across, mean rho/rho0 and KE
# ratio (analytic 0.623): A = 0 (no shifting) 1.364 / 0.603, 0.5: 1.134 / 0.655, 1: 1.063 / 0.678,
# 2: 1.014 / 0.646, 3: 1.021 / 1.14 (energy injected), 4: 1.010 / 0.725. At 24 across, A = 2: 1.0055 /
# 0.614. Lind et al.'s anti-pairing term (R = 0.2) and the Taylor velocity correction both injected
# energy (KE above 1 mid-run), so neither is used (tools/results/CONFINED_NOTES.md).
DEFAULT_SHIFTING = 2.0
# largest shift a step, in particle spacings (0.02: mean rho/rho0 1.149 at A = 2; 0.2: as 0.1)
MAX_SHIFT = 0.1


# Transport velocity (solver.transport_velocity = B, Adami, Hu & Adams 2013): particles move by
# dt v + dt^2 a_b, a_b the acceleration of a background pressure p_b = B rho0 max|v|^2, used for the
# position only; v is moved with them ((shift . grad) v, first order), and the density solver
# corrects only this share of the density error rho/rho0 - 1 a step (its velocity-divergence part is
# whole): with the full error it turned each displacement back into velocity (Taylor-Green KE rose
# above 1 mid-run at B >= 20, as with shifting). Measured at 16 across (tools/results/CONFINED_NOTES.md):
# weight 1: B = 5 KE fine, mean rho 1.10; B = 20: KE +33 % at 0.15 s; 0.05 with B = 40 and the velocity
# correction: KE within 6 % of analytic at 0.09, 0.15 and 0.3 s, mean rho 1.009; weight 0 lets the
# mean rise (B = 20: 1.038) and loses 7-16 %.
TRANSPORT_DENSITY_WEIGHT = 0.05


def transport_coefficient(solver):
    """The scene's transport-velocity coefficient B: 0 (off) unless set in the confined mode."""
    if solver.clamp_pressure or solver.transport_velocity is None:
        return 0.0
    return solver.transport_velocity


def shifting_coefficient(solver):
    """The scene's particle-shifting coefficient: 0 in the clamped (free-surface) mode and with the
    transport velocity (which replaces it)."""
    if solver.clamp_pressure or transport_coefficient(solver) > 0.0:
        return 0.0
    return DEFAULT_SHIFTING if solver.shifting is None else solver.shifting


class DFSPHSolver:
    scratch_columns = 2  # stiffness and error live within a solve: they share the models' scratch pool

    @staticmethod
    def columns(scene):
        """Scratch columns this scene's solver needs: shifting holds a vector after the solves, the
        transport velocity two (the displacement and the corrected velocity)."""
        if transport_coefficient(scene.solver) > 0.0:
            return 6
        return 3 if shifting_coefficient(scene.solver) > 0.0 else DFSPHSolver.scratch_columns

    def __init__(self, sim):
        self.sim = sim
        z = sim.zeros
        self.stiffness = sim.scratch(float, 0)
        self.error = sim.scratch(float, 1)
        self.clamp = int(sim.scene.solver.clamp_pressure)
        self.shifting = shifting_coefficient(sim.scene.solver)
        self.transport = transport_coefficient(sim.scene.solver)
        if self.shifting > 0.0 or self.transport > 0.0:  # after the solves: the pool is free again
            self.shift = sim.scratch(wp.vec3, 0)
        if self.transport > 0.0:
            self.moved_velocity = sim.scratch(wp.vec3, 3)
        # share of the density error rho/rho0 - 1 in the density source
        self.density_weight = TRANSPORT_DENSITY_WEIGHT if self.transport > 0.0 else 1.0
        # accumulated stiffness of the last solve of each kind, for the warm start
        self.pressure_sum = [sim.per_particle("pressure"), sim.per_particle("pressure")]
        self.error_stats = z("pressure", 3)  # sum |error|, max |error|, sum of the signed source (confined)
        self.average_error = [z("pressure", 1), z("pressure", 1)]
        self.condition = z("pressure", 1, dtype=wp.int32)  # read by wp.capture_while
        self.iterations = z("pressure", 1, dtype=wp.int32)
        # per solver: [iterations summed over steps, solves]
        self.totals = z("pressure", 4, dtype=wp.int64)
        self.max_iteration_streak = z("pressure", 2, dtype=wp.int32)

    def reorder(self, sim, order):
        for a in self.pressure_sum:
            sim.permute(a, order)

    # -- Algorithm 1: the two projection loops -------------------------------------------
    def correct_divergence(self):
        """v~ := v~ + dt a_correct until D rho/Dt ~ 0 (divergence correction)."""
        s = self.sim.scene.solver
        if not s.divergence_solver:
            return
        self._solve(DIVERGENCE, compute_divergence_source, self._divergence_inputs(),
                    s.divergence_max_error * 0.01, s.divergence_min_iterations, s.divergence_max_iterations)

    def correct_density(self):
        """v~ := v~ + dt a_proj until rho*(x + dt v~) ~ rho0 (projection)."""
        s = self.sim.scene.solver
        self._solve(DENSITY, compute_density_source, self._density_inputs(),
                    s.density_max_error * 0.01, s.min_iterations, s.max_iterations)

    # -------------------------------------------------------------------------------------
    def _common(self):
        sim = self.sim
        return [sim.fluid.x, sim.fluid.v, sim.neighbours.lists, sim.boundary.samples]

    def _divergence_inputs(self):
        sim = self.sim
        return self._common() + [sim.fluid.factor, sim.fluid_volume, sim.support_radius, sim.dt, self.clamp]

    def _density_inputs(self):
        sim = self.sim
        return self._common() + [sim.fluid.density, sim.fluid.factor, sim.fluid_volume, sim.rest_density,
                                 sim.support_radius, sim.dt, self.clamp, self.density_weight]

    def _apply(self, kind, accumulate):
        sim = self.sim
        sim.launch(apply_pressure_acceleration, sim.num_fluid,
                   [self.stiffness, sim.fluid.x, sim.neighbours.lists, sim.boundary.samples, sim.fluid_volume,
                    sim.support_radius, sim.dt, accumulate, self.pressure_sum[kind], sim.fluid.v])

    def _measure(self, kind, source_kernel, inputs, max_error, min_it, max_it, first):
        sim = self.sim
        sim.launch(source_kernel, sim.num_fluid, inputs + [self.error, self.stiffness])
        if not self.clamp:  # confined: signed source less its mean (compatibility condition), relaxed
            sim.launch(reduce_source_sum, min(sim.num_fluid, REDUCE_THREADS), [self.error, sim.num_fluid, self.error_stats])
            sim.launch(remove_mean_source, sim.num_fluid,
                       [self.error_stats, sim.num_fluid, sim.fluid.factor, sim.dt, int(kind == DIVERGENCE),
                        CONFINED_RELAXATION, self.error, self.stiffness])
        sim.launch(reduce_error, min(sim.num_fluid, REDUCE_THREADS), [self.error, sim.num_fluid, self.error_stats])
        sim.launch(update_solver_status, 1,
                   [self.error_stats, sim.num_fluid, max_error, max_error * PEAK_ERROR_RATIO, int(kind == DIVERGENCE), sim.dt, min_it, max_it,
                    int(first), kind, self.average_error[kind], self.condition, self.iterations, self.totals,
                    self.max_iteration_streak])

    def _solve(self, kind, source_kernel, inputs, max_error, min_it, max_it):
        sim = self.sim
        if sim.scene.solver.warm_start:
            sim.launch(scale_warm_start, sim.num_fluid,
                       [self.pressure_sum[kind], sim.dt, sim.dt_previous, int(kind == DIVERGENCE),
                        WARM_START_FACTOR[kind], self.stiffness])
            self._apply(kind, 0)
        else:
            self.pressure_sum[kind].zero_()
        self._measure(kind, source_kernel, inputs, max_error, min_it, max_it, True)

        def iteration():
            self._apply(kind, 1)
            self._measure(kind, source_kernel, inputs, max_error, min_it, max_it, False)

        wp.capture_while(self.condition, iteration)

    def transport_velocity(self):
        """Transport velocity, before the position update: the displacement dt^2 a_b at x^n (neighbour
        lists of the step) and v_i := v_i + (shift_i . grad) v_i; :meth:`shift_particles` then moves
        the particles by it. No-op when it is off."""
        if self.transport <= 0.0:
            return
        sim, f = self.sim, self.sim.fluid
        sim.launch(compute_transport_shift, sim.num_fluid,
                   [f.x, sim.neighbours.lists, sim.boundary.samples, f.density, sim.fluid_volume, sim.rest_density,
                    sim.support_radius, sim.dt, sim.max_speed_sq, self.transport,
                    MAX_SHIFT * sim.scene.particle_diameter, self.shift])
        sim.launch(transport_velocity_correction, sim.num_fluid,
                   [f.x, f.v, self.shift, sim.neighbours.lists, sim.fluid_volume, sim.support_radius,
                    self.moved_velocity])
        wp.copy(f.v, self.moved_velocity, count=sim.num_fluid)

    def shift_particles(self):
        """Confined mode: particle shifting after the position update (two passes: the shifts
        from the neighbour lists of this step, then the move), or the transport velocity's
        displacement; no-op when both are off."""
        sim, f = self.sim, self.sim.fluid
        if self.transport > 0.0:
            sim.launch(apply_shift, sim.num_fluid, [self.shift, sim.neighbours.lower, sim.neighbours.period, f.x])
            return
        if self.shifting <= 0.0:
            return
        sim.launch(compute_shift, sim.num_fluid,
                   [f.x, sim.neighbours.lists, sim.boundary.samples, sim.fluid_volume, sim.support_radius,
                    sim.dt, sim.max_speed_sq, self.shifting,
                    MAX_SHIFT * sim.scene.particle_diameter, self.shift])
        sim.launch(apply_shift, sim.num_fluid, [self.shift, sim.neighbours.lower, sim.neighbours.period, f.x])

    # -- statistics (host reads, outside the step) -----------------------------------------
    def iteration_totals(self):
        """(divergence iterations, divergence solves, density iterations, density solves) so far."""
        return tuple(int(v) for v in self.totals.numpy())

    def last_errors(self):
        return float(self.average_error[DIVERGENCE].numpy()[0]), float(self.average_error[DENSITY].numpy()[0])
