"""The IISPH pressure solver (Ihmsen et al. 2014), as SPlisHSPlasH's TimeStepIISPH: the Rankine paper's baseline.

One density solve a step, after the non-pressure forces (the stepper's order serves both solvers: it calls
:meth:`IISPHSolver.correct_density` on v_adv). Its loop: the diagonal a_ii, d_ii and the source once, last
step's pressure halved as the start, then relaxed Jacobi iterations (omega ``solver.relaxation``, 0.5 as SPlisHSPlasH's; p >= 0
everywhere) until the
average |density error| of the rows with pressure is below ``solver.density_max_error`` (and the largest below
``PEAK_ERROR_RATIO`` times it, as the DFSPH solves), within ``solver.min_iterations .. max_iterations``; then
the pressure acceleration. The decision is made on the device and the loop is a ``wp.capture_while``, as in
:class:`warpsph.solvers.dfsph.DFSPHSolver`, whose interface this class has: the stepper, the health check and the
statistics read either. No divergence solve, free-surface detection or shifting (SPlisHSPlasH's IISPH has
none), no DFSPH factor.
"""

from __future__ import annotations

import warp as wp

from warpsph.kernels.iisph import (
    MIN_DIAGONAL,
    compute_iisph_coefficients,
    compute_pressure_displacement,
    start_pressure_solve,
    update_iisph_pressure,
)
from warpsph.kernels.particles import SymmetricMatrix
from warpsph.kernels.pressure import REDUCE_THREADS, apply_pressure_acceleration, reduce_error, update_solver_status
from warpsph.keys import key, schema
from warpsph.solvers.base import IISPH_FLUID_STATE, IISPH_SOLVER, PressureSolver, register_solver
from warpsph.solvers.dfsph import DENSITY, PEAK_ERROR_RATIO

WARM_START = 0.5  # SPlisHSPlasH: the first iterate is half of last step's pressure


@schema
class IISPHParameters:
    """IISPH's own keys of the scene's solver block."""

    relaxation: float = key(0.5, doc="relaxation omega of the Jacobi iterations (Ihmsen et al. 2014, section 3.2; "
                                     "SPlisHSPlasH's 0.5)", gt=0, le=1)


@register_solver("iisph")
class IISPHSolver(PressureSolver):
    Parameters = IISPHParameters
    summary = ("Ihmsen et al. 2014, as SPlisHSPlasH: one density solve, p >= 0 everywhere; no divergence solve, "
               "free-surface detection or shifting")
    needs_factor = False  # the density pass writes no DFSPH factor
    # d_ii (3), the pressure displacement c (3), a_ii, the source, q = p / rho^2 and the error: all live within
    # the solve, in the scratch pool the models use before it
    scratch_columns = 10
    splishsplash_method = 3
    decomposable = False

    @staticmethod
    def pool_columns(scene):
        """Scratch columns the memory check adds for it (shared with the models')."""
        return IISPHSolver.scratch_columns

    @staticmethod
    def kernel_modules(scene):
        return ["warpsph.kernels.iisph"]

    @staticmethod
    def solve_passes(divergence_iterations, density_iterations):
        """The coefficients 1, 2 an iteration, the pressure acceleration 1."""
        return 2 + 2 * density_iterations

    @staticmethod
    def bytes_per_particle(scene):
        return IISPH_FLUID_STATE + IISPH_SOLVER

    def __init__(self, ctx):
        super().__init__(ctx)
        z = ctx.zeros
        self.d_ii = ctx.scratch(wp.vec3, 0)
        self.displacement = ctx.scratch(wp.vec3, 3)
        self.a_ii = ctx.scratch(float, 6)
        self.source = ctx.scratch(float, 7)
        self.stiffness = ctx.scratch(float, 8)
        self.error = ctx.scratch(float, 9)
        self.pressure = ctx.per_particle()  # p / rho0 of the last solve: the next step's warm start
        self.no_gradient_correction = z(0, dtype=SymmetricMatrix)  # DFSPH's periodic box only
        self.no_coupling = z(0)  # its bodies take the step's impulse after the solve (no strong coupling)
        self.error_stats = z(3)  # sum |error|, max |error| (update_solver_status resets them)
        self.average_error = z(1)
        self.condition = z(1, dtype=wp.int32)  # read by wp.capture_while
        self.iterations = z(1, dtype=wp.int32)
        # as DFSPHSolver's: [divergence iterations, solves, density iterations, solves]; the first two stay 0
        self.totals = z(4, dtype=wp.int64)
        self.max_iteration_streak = z(2, dtype=wp.int32)
        self._no_outputs = [z(0), z(0, dtype=wp.vec3)]
        carry = ctx.state.carry
        carry("solver/totals", self.totals)
        carry("solver/max_iteration_streak", self.max_iteration_streak)
        carry("solver/pressure", self.pressure)

    def density_pass_outputs(self):
        """Nothing besides density: empty position divergence and concentration gradient."""
        return self._no_outputs

    def reorder(self, order):
        self.ctx.permute(self.pressure, order)

    def detect_free_surface(self):
        """None: p >= 0 everywhere."""

    def correct_divergence(self):
        """None: IISPH has no divergence solve."""

    def shift_particles(self):
        """None: SPlisHSPlasH's IISPH does not shift."""

    def correct_density(self):
        """v := v_adv + dt a_p, with p from relaxed Jacobi on the density-invariance system (Ihmsen et al. 2014,
        Algorithm 1: PREDICT ADVECTION's coefficients, PRESSURE SOLVE, the pressure force of INTEGRATION)."""
        ctx = self.ctx
        s, rho0 = ctx.parameters, ctx.constants.rest_density
        f, n, nb, bnd = ctx.fluid, ctx.num_fluid, ctx.neighbour_lists(), ctx.boundary.samples
        V, H = ctx.constants.fluid_volume, ctx.constants.support_radius
        max_error = s.density_max_error * 0.01
        ctx.launch(compute_iisph_coefficients, n,
                   [f.x, f.v, nb, bnd, f.density, V, rho0, H, ctx.dt, WARM_START if s.warm_start else 0.0,
                    self.d_ii, self.a_ii, self.source, self.pressure, self.stiffness])
        ctx.launch(start_pressure_solve, 1, [self.condition, self.iterations])

        def iteration():
            ctx.launch(compute_pressure_displacement, n,
                       [f.x, nb, V, H, self.d_ii, self.pressure, self.stiffness, self.displacement])
            ctx.launch(update_iisph_pressure, n,
                       [f.x, nb, f.density, V, rho0, H, MIN_DIAGONAL / (H * H), ctx.dt, s.relaxation,
                        self.d_ii, self.a_ii, self.source, self.displacement, self.pressure, self.stiffness, self.error])
            ctx.launch(reduce_error, REDUCE_THREADS, [self.error, n, self.error_stats])
            ctx.launch(update_solver_status, 1,
                       [self.error_stats, n, max_error, max_error * PEAK_ERROR_RATIO, 0, 0.0, 0.0, ctx.dt, s.min_iterations,
                        s.max_iterations, 0, DENSITY, self.average_error, self.condition, self.iterations, self.totals,
                        self.max_iteration_streak, self.no_coupling, 0.0])

        wp.capture_while(self.condition, iteration)
        # a_p of the final pressures: q = p / rho^2 is the DFSPH stiffness, so DFSPH's kernel applies it (and
        # hands dynamic bodies their reaction)
        ctx.launch(apply_pressure_acceleration, n,
                   [self.stiffness, f.x, nb, bnd, V, H, ctx.dt, 0, self.stiffness, self.no_gradient_correction, f.v])

    # -- statistics (host reads, outside the step) -----------------------------------------
    def iteration_totals(self):
        """(0, 0, density iterations, density solves) so far: DFSPHSolver's layout, without a divergence solve."""
        return tuple(int(v) for v in self.totals.numpy())

    def last_errors(self):
        """(0, the last solve's average density error)."""
        return 0.0, float(self.average_error.numpy()[0])

    def pressure_field(self):
        """Pressure [Pa] of the last solve per particle (host copy)."""
        return self.ctx.host(self.pressure) * self.ctx.constants.rest_density
