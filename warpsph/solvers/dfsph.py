"""The DFSPH pressure solver (Bender & Koschier 2015/2017): divergence and density.

Both solvers share one loop: warm start, then iterate {apply pressure, recompute the
source and stiffness, average the error, decide} until the average error is below the
tolerance and the minimum iterations are done, or the maximum is reached. The decision
is made on the device (:func:`update_solver_status`) and the loop is a
``wp.capture_while``: on CUDA inside a captured graph no iteration waits on the host.

One solver serves every scene, decided per particle each step. The density pass's divergence of position,
density and concentration gradient classify each particle as surface, band, wall or bulk
(:func:`classify_free_surface`). Bulk particles solve with the corrected kernel gradient L_i
(:func:`compute_gradient_correction`, blended to the identity towards the band), the others with the plain one.
A step with free-surface particles keeps p >= 0 everywhere, as SPlisHSPlasH does (:func:`clamped` says why); a
step without one has signed pressure (relaxed Jacobi), so a vortex keeps its low-pressure core. The source's
mean is removed where the problem is singular or nearly so (:meth:`DFSPHSolver._removes_mean`). Particle shifting
(:func:`compute_shift`, Lind et al. 2012) keeps the bulk's arrangement even; beside walls and in the band it is
tangential, on the surface off.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from warpsph.kernels.density_solver import compute_corrected_density_source, compute_density_source
from warpsph.kernels.divergence_solver import compute_corrected_divergence_source, compute_divergence_source
from warpsph.kernels.free_surface import classify_free_surface
from warpsph.kernels.integration import advect_positions
from warpsph.kernels.particles import SymmetricMatrix
from warpsph.kernels.pressure import (
    REDUCE_THREADS,
    apply_corrected_pressure_acceleration,
    apply_pressure_acceleration,
    compute_gradient_correction,
    reduce_error,
    reduce_source_sum,
    remove_mean_source,
    update_solver_status,
    warm_start_bulk,
    warm_start_pressure,
)
from warpsph.kernels.shifting import apply_shift, compute_shift
from warpsph.solvers.base import CORRECTED, FLUID_STATE, SOLVER, PressureSolver, register_solver
from warpsph.models.viscosity import Viscosity
from warpsph.keys import key, schema

DIVERGENCE, DENSITY, DRIFT = 0, 1, 2
# In a periodic box the density solve is split (DFSPHSolver.correct_density). Its rate half's tolerance is per unit
# time: RATE_TOLERANCE_PER_SECOND x dt of solver.density_max_error, between RATE_TOLERANCE_FLOOR and
# RATE_TOLERANCE_FACTOR of it; its drift half stops after at most DRIFT_MAX_ITERATIONS. Taylor-Green at 256 across: 7.5 %
# at the full per-step tolerance, 0.67 % at 0.1 of it, 0.55 % at 0.03 (this rate); a fixed 0.03 ran into
# max_iterations at 16-24 across on the CPU, and 0.01 at 128-256 across on the GPU (docs/notes/solver.md).
RATE_TOLERANCE_FACTOR = 0.1
RATE_TOLERANCE_PER_SECOND = 160.0  # [1/s]: 0.03 at the 0.19 ms viscous step of 256 across, 0.1 from 0.6 ms up
RATE_TOLERANCE_FLOOR = 0.03
DRIFT_MAX_ITERATIONS = 30
# The largest per-particle error may be this many times the average tolerance (density:
# 0.01 % average, 1 % peak). Without it a 1M-particle dam break converged in 2 iterations on
# the average while its bottom layer was crushed to 2.2 rho0 within 5 steps and exploded.
PEAK_ERROR_RATIO = 100.0
# Divergence of position below which a particle is on the free surface: DualSPHysics' 3D value
# (2.75 between the bulk's 3 and a flat surface's 2.2 for the cubic spline at support 4r).
FREE_SURFACE_THRESHOLD = 2.75
# ... and density (rho / rho0) below which, or grad C along gravity above which (in units of 1 / particle spacing)
# (kernels/free_surface.py says why)
FREE_SURFACE_DENSITY = 0.95
FREE_SURFACE_GRADIENT = 0.25
# largest shift a step, in particle spacings
MAX_SHIFT = 0.1


def fully_periodic(periodic):
    """Whether a domain periodic across the axes ``periodic`` (``Constants.periodic``, ``scene.domain.periodic``) is
    periodic along x, y and z (no walls): the only box whose pressure problem is singular (pure Neumann: a constant
    pressure moves nothing): its density solve is split (:meth:`DFSPHSolver.correct_density`). The scene rejects an
    axis named twice."""
    return len(periodic) == 3


@schema
class DFSPHParameters:
    """DFSPH's own keys of the scene's solver block: the divergence solve's and particle shifting's."""

    divergence_solver: bool = key(True, doc="run the divergence solve (DFSPH's velocity correction)")
    divergence_max_error: float = key(0.1, doc="average divergence error the divergence solve stops at",
                                      unit="% of rho0 per second", gt=0)
    divergence_min_iterations: int = key(1, doc="divergence solve: fewest iterations", ge=0)
    divergence_max_iterations: int = key(100, doc="divergence solve: most iterations", ge=1)
    shifting: float = key(2.0, doc="particle shifting coefficient (Lind et al. 2012): x += -D grad C in the bulk, "
                                   "tangential near the free surface, off on it; D = shifting x h max|v| dt; 0: off", ge=0)


@register_solver("dfsph")
class DFSPHSolver(PressureSolver):
    Parameters = DFSPHParameters
    summary = ("Bender & Koschier 2017: a divergence and a density solve, the corrected operators in the bulk, "
               "shifting")
    needs_factor = True  # the density pass writes the DFSPH factor
    detects_free_surface = True  # detect_free_surface: surface, band, wall-side bulk and bulk per particle
    scratch_columns = 2  # stiffness and error live within a solve: they share the models' scratch pool
    splishsplash_method = 4
    decomposable = True
    couples_bodies = True  # the dynamic bodies move inside both solves' iterations (:meth:`_couple`)

    @staticmethod
    def columns(scene):
        """Scratch columns this scene's solver needs: shifting holds a vector after the solves."""
        return 3 if scene.solver.shifting > 0.0 else DFSPHSolver.scratch_columns

    @staticmethod
    def pool_columns(scene):
        """Scratch columns the memory check adds for it: none, its stiffness and error are in its own bytes."""
        return 0

    @staticmethod
    def kernel_modules(scene):
        solver = scene.solver
        names = ["free_surface", "density_solver"]
        names += ["divergence_solver"] if solver.divergence_solver else []
        names += ["shifting"] if solver.shifting > 0.0 else []
        return [f"warpsph.kernels.{n}" for n in names]

    @staticmethod
    def solve_passes(divergence_iterations, density_iterations):
        """Each solve: the warm start 1 and the source 1, then 2 an iteration."""
        return 4 + 2 * divergence_iterations + 2 * density_iterations

    @staticmethod
    def bytes_per_particle(scene):
        # the corrected viscosity's strain rate
        corrected_viscosity = Viscosity.takes_corrected_operator(scene, DFSPHSolver.detects_free_surface)
        return FLUID_STATE + SOLVER + CORRECTED + (Viscosity.corrected_bytes_per_particle if corrected_viscosity else 0)

    def __init__(self, ctx):
        super().__init__(ctx)
        z = ctx.zeros
        self.stiffness = ctx.scratch(float, 0)
        self.error = ctx.scratch(float, 1)
        self.position_divergence = self.error  # written by the density pass, read before the solves
        self.shifting = ctx.parameters.shifting
        # the periodic box (no walls): its density drift is corrected through the positions (correct_density)
        self.drift_by_positions = fully_periodic(ctx.constants.periodic)
        # grad C from the density pass: the free-surface test and the shift (after the solves)
        self.concentration_gradient = ctx.per_particle(wp.vec3)
        if self.shifting > 0.0:
            self.shift = ctx.scratch(wp.vec3, 0)
        self.surface = ctx.per_particle(wp.int32)  # BULK / BAND / SURFACE / WALL
        self.surface_count = z(1, dtype=wp.int32)  # surface particles this step (statistics)
        # this step: 1 = p >= 0 everywhere (under gravity, or a free surface exists); 0 = signed in the bulk (clamped())
        self.free_surface = z(1, dtype=wp.int32)
        self.free_surface_known = None
        # accumulated stiffness of the last solve of each kind, for the warm start
        self.pressure_sum = [ctx.per_particle(), ctx.per_particle()]
        self.error_stats = z(3)  # sum |error|, max |error|, sum of the signed source
        self.average_error = [z(1), z(1)]
        self.condition = z(1, dtype=wp.int32)  # read by wp.capture_while
        self.iterations = z(1, dtype=wp.int32)
        # per solver: [iterations summed over steps, solves]
        self.totals = z(4, dtype=wp.int64)
        self.max_iteration_streak = z(2, dtype=wp.int32)
        # the corrected kernel gradient of every bulk particle (:meth:`_corrected`), recomputed every step
        self.gradient_correction = ctx.per_particle(SymmetricMatrix)  # L_i
        self.corrected_factor = ctx.per_particle()  # ... and the factor of the corrected solves
        self.no_gradient_correction = z(0, dtype=SymmetricMatrix)
        self.no_coupling = z(0)  # no bodies' residual in the loop's decision (:meth:`_residual`)
        if self.drift_by_positions:  # the drift solve's velocity, and its stiffness for the warm start
            self.drift_velocity = ctx.per_particle(wp.vec3)
            self.pressure_sum.append(ctx.per_particle())
            self.average_error.append(z(1))
            # its statistics apart: a drift solve that stops at its cap leaves the rest to the next step, so
            # it does not count towards the health check's streak of solves at max_iterations
            self.drift_totals = z(2, dtype=wp.int64)
            self.drift_streak = z(1, dtype=wp.int32)
        carry = ctx.state.carry  # what the next step reads: the warm start and the iteration statistics
        carry("solver/totals", self.totals)
        carry("solver/max_iteration_streak", self.max_iteration_streak)
        # the drift half's warm start (a periodic box) is not kept: checkpoints stay as they were
        for n, a in enumerate(self.pressure_sum[:2]):
            carry(f"solver/pressure_sum_{n}", a)

    def density_pass_outputs(self):
        """What the density pass writes for the solver besides density and factor."""
        return [self.position_divergence, self.concentration_gradient]

    def reorder(self, order):
        for a in self.pressure_sum:
            self.ctx.permute(a, order)

    def detect_free_surface(self):
        """Flags the surface, its band, the wall-side bulk and the bulk, and counts the surface particles, from
        the density pass's divergence of position and density."""
        ctx, c = self.ctx, self.ctx.constants
        self.surface_count.zero_()
        # under gravity the bulk is clamped whether or not a particle is on a free surface this step (kernels/
        # pressure.py clamped): no regime that a closing gap switches for the whole tank
        if self._removes_mean():
            self.free_surface.zero_()
        else:
            self.free_surface.fill_(1)
        ctx.exchange(self.position_divergence, self.concentration_gradient)  # read at the neighbours (the band)
        ctx.launch(classify_free_surface, ctx.num_fluid,
                   [self.position_divergence, ctx.fluid.density, self.concentration_gradient, self._down(),
                    ctx.neighbour_lists(),
                    FREE_SURFACE_THRESHOLD, FREE_SURFACE_DENSITY * c.rest_density,
                    FREE_SURFACE_GRADIENT / c.particle_diameter, self.surface, self.surface_count,
                    self.free_surface])
        combined = ctx.allreduce((self.surface_count, "s"), (self.free_surface, "m"), read=True)
        # on subdomains the regime is known on the host: a free-surface step skips the mean source's reduction
        self.free_surface_known = None if combined is None else int(combined[1][0])
        ctx.exchange(self.surface)  # read at the neighbours: L_i's blend, the viscous pairs, the shift
        # L_i of the corrected solves (:meth:`_corrected`): the identity on the surface and its band
        ctx.launch(compute_gradient_correction, ctx.num_fluid,
                   [ctx.fluid.x, ctx.neighbour_lists(), ctx.boundary.samples, self.surface, c.fluid_volume,
                    c.support_radius, self.gradient_correction, self.corrected_factor])
        ctx.exchange(self.gradient_correction)  # L_j of the pressure force

    # -- Algorithm 1: the two projection loops -------------------------------------------
    def correct_divergence(self):
        """v~ := v~ + dt a_correct until D rho/Dt ~ 0 (divergence correction)."""
        s = self.ctx.parameters
        if not s.divergence_solver:
            return
        self._solve(DIVERGENCE, self._divergence_inputs(), s.divergence_max_error * 0.01, s.divergence_min_iterations,
                    s.divergence_max_iterations)

    def correct_density(self):
        """v~ := v~ + dt a_proj until rho*(x + dt v~) ~ rho0 (projection).

        In a box periodic along x, y and z (no walls, no free surface) the solve is split in two. The first
        half drives only this step's density change, dt D(rho/rho0)/Dt of v~, to zero, at a tolerance per unit
        time (RATE_TOLERANCE_PER_SECOND): its pressure is the flow's and its velocity stays. The second drives the density error
        the step starts with, rho/rho0 - 1, to zero with a velocity of its own that moves the positions in
        :meth:`shift_particles` and is then dropped. Kept in the velocity, that correction is a particle-scale
        kick every step which the viscosity has to take out again: it held Taylor-Green's error at 2 % from 128
        across up (docs/notes/solver.md). The rate half and the divergence solve use the corrected kernel
        gradient (:func:`compute_gradient_correction`) in their divergence, in their pressure force (its negative
        adjoint, :data:`apply_corrected_pressure_acceleration`) and in their Jacobi factor: the flow's strain makes the
        particle arrangement anisotropic, and there the plain SPH divergence of a divergence-free field, and the
        plain gradient of a smooth pressure, are smooth errors of order one (Taylor-Green at 16 / 24 / 32 across:
        7.00 / 4.01 / 2.88 % plain, 2.39 / 1.55 / 1.19 % corrected). The drift half keeps the plain operators of
        the summation density it corrects. With walls the drift half does not converge (the Akinci walls' density
        is a standing drift; Lamb-Oseen ran into its cap every step at 256 across), so every other box keeps the
        single solve, with the corrected gradient in the bulk: the plain one's pressure force, on the arrangement a
        vortex shears, has a part along the streamlines that took 2-3 % of the angular momentum inside Lamb-Oseen's
        core region by T and grew with resolution (L1 0.92 / 1.33 / 2.17 % at 128 / 256 / 512 across; corrected
        0.69 / 0.39 / 0.19 %), and below a free surface it lost 38 % of u_theta at every resolution (0.36 % at 256
        across corrected; docs/notes/solver.md).
        """
        s = self.ctx.parameters
        tolerance = s.density_max_error * 0.01
        if self.drift_by_positions:
            self._solve(DENSITY, self._density_inputs(DENSITY, drift_weight=0.0),
                        tolerance * RATE_TOLERANCE_FACTOR, s.min_iterations, s.max_iterations,
                        rate=(tolerance * RATE_TOLERANCE_PER_SECOND, tolerance * RATE_TOLERANCE_FLOOR))
            self.drift_velocity.zero_()
            self._solve(DRIFT, self._density_inputs(DRIFT, self.drift_velocity), tolerance,
                        min(s.min_iterations, DRIFT_MAX_ITERATIONS), min(s.max_iterations, DRIFT_MAX_ITERATIONS),
                        velocity=self.drift_velocity)
            return
        self._solve(DENSITY, self._density_inputs(), tolerance, s.min_iterations, s.max_iterations)

    # -------------------------------------------------------------------------------------
    def _common(self, velocity=None):
        ctx = self.ctx
        return [ctx.fluid.x, ctx.fluid.v if velocity is None else velocity, ctx.neighbour_lists(), ctx.boundary.samples]

    def _divergence_inputs(self):
        ctx, c = self.ctx, self.ctx.constants
        return self._common() + [self._factor(DIVERGENCE), self.surface, self.free_surface, c.fluid_volume,
                                 c.support_radius, ctx.dt, self._correction(DIVERGENCE)]

    def _density_inputs(self, kind=DENSITY, velocity=None, drift_weight=1.0):
        ctx, c = self.ctx, self.ctx.constants
        return self._common(velocity) + [ctx.fluid.density, self._factor(kind), self.surface, self.free_surface,
                                         c.fluid_volume, c.rest_density, c.support_radius, ctx.dt, drift_weight,
                                         self._correction(kind)]

    def _down(self):
        """The unit vector of gravity now (zero without it): the free-surface test's direction."""
        g = np.asarray(self.ctx.gravity(), dtype=np.float64)
        return wp.vec3(*(g / np.linalg.norm(g) if g.any() else g))

    def _removes_mean(self):
        """Whether a step without free surface solves for its source less the source's mean: in a fully periodic
        box, or without gravity (gravity now: a ramp sets it between steps). There the pressure problem is
        singular or nearly so: a constant pressure moves nothing, or only the particles beside the walls, and a
        source with a non-zero mean (the density drift of a disordered arrangement, which no velocity in a sealed
        box changes) has no solution; Jacobi drifts. Under gravity the mean is the fluid's real compression
        against the floor: removed, a tank filled to its lid blew up within ~20 steps; kept, it stays at rest."""
        return self.drift_by_positions or not any(self.ctx.gravity())

    def _bulk_first(self, kind):
        """Whether a solve of ``kind`` applies the bulk's warm start before its first measure (kernels/pressure.py
        warm_start_bulk): the density solve of a free-surface scene."""
        return kind == DENSITY and not self._removes_mean()

    def _corrected(self, kind):
        """Whether a solve of ``kind`` uses the corrected gradient (L_i, the identity on the free surface and its
        band): every solve but the periodic box's drift half (correct_density)."""
        return kind != DRIFT

    def _source(self, kind):
        """The source kernel of a solve of ``kind``: the divergence's or the predicted density's, corrected where
        :meth:`_corrected`."""
        if kind == DIVERGENCE:
            return compute_corrected_divergence_source if self._corrected(kind) else compute_divergence_source
        return compute_corrected_density_source if self._corrected(kind) else compute_density_source

    def _factor(self, kind):
        """The DFSPH factor of a solve of ``kind``: the corrected one where :meth:`_corrected`, the density
        pass's elsewhere."""
        return self.corrected_factor if self._corrected(kind) else self.ctx.fluid.factor

    def _correction(self, kind):
        """L_i for a solve of ``kind`` where :meth:`_corrected`, else an empty array (the kernels do not read it)."""
        return self.gradient_correction if self._corrected(kind) else self.no_gradient_correction

    def _apply(self, kind, accumulate, velocity):
        ctx, c = self.ctx, self.ctx.constants
        corrected = self._corrected(kind)
        if accumulate and self._coupled(kind):  # the bodies' answer to this iteration's pressure (not the bulk's warm start)
            ctx.bodies.respond(self.stiffness, self._factor(kind), self.surface, self.free_surface,
                               self._correction(kind))
        ctx.launch(apply_corrected_pressure_acceleration if corrected else apply_pressure_acceleration, ctx.num_fluid,
                   [self.stiffness, ctx.fluid.x, ctx.neighbour_lists(), ctx.boundary.samples, c.fluid_volume,
                    c.support_radius, ctx.dt, accumulate, self.pressure_sum[kind], self._correction(kind), velocity])
        self._couple(kind)

    def _couple(self, kind):
        """Strong fluid-rigid coupling (Gissler et al. 2019): after each apply of the divergence and density solves
        (and at their start), the dynamic bodies' velocities take the pressure reactions the fluid has given them so
        far this step, and their samples' velocities, which the next source reads, follow
        (:meth:`~warpsph.bodies.MovingBodies.couple`). Without dynamic bodies nothing is launched; the periodic box's
        drift half (its velocity moves positions only) leaves the bodies as its rate half left them."""
        if self._coupled(kind):
            self.ctx.bodies.couple(gravity_weight=1.0 if kind == DENSITY else 0.0)

    def _coupled(self, kind):
        """Whether a solve of ``kind`` moves dynamic bodies in its iterations: there are some, and it is not the
        periodic box's drift half."""
        bodies = self.ctx.bodies
        return bodies is not None and bodies.coupling is not None and kind != DRIFT

    def _measure(self, kind, inputs, max_error, min_it, max_it, first, rate=(0.0, 0.0)):
        """Source, stiffness and error of the current velocities, and the loop's decision. The first
        measure of a solve replaces the stiffness by the warm start (when on; the bulk's of :meth:`_bulk_first`
        is applied before it): the loop's first apply uses it."""
        ctx = self.ctx
        ctx.launch(self._source(kind), ctx.num_fluid, inputs + [self.error, self.stiffness])
        if self._removes_mean():  # a step without free surface (on the device): the source less its mean
            ctx.launch(reduce_source_sum, REDUCE_THREADS,
                       [self.error, ctx.num_fluid, self.free_surface, self.error_stats])
            if self.free_surface_known != 1:  # (error_stats[2] stays 0 with a free surface)
                ctx.allreduce((self.error_stats, "--s"))
            ctx.launch(remove_mean_source, ctx.num_fluid,
                       [self.error_stats, ctx.global_count(), self.free_surface, self._factor(kind), ctx.dt,
                        int(kind == DIVERGENCE), self.error, self.stiffness])
        if first and ctx.parameters.warm_start:  # last step's pressure (kernels/pressure.py says where it is capped)
            ctx.launch(warm_start_pressure, ctx.num_fluid,
                       [self.error, self._factor(kind), ctx.dt, ctx.dt_previous, int(kind == DIVERGENCE),
                        self.surface, self.free_surface, self.pressure_sum[kind], int(self._bulk_first(kind)),
                        int(not self._removes_mean()), self.stiffness])
        ctx.launch(reduce_error, REDUCE_THREADS, [self.error, ctx.num_fluid, self.error_stats])
        ctx.allreduce((self.error_stats, "sm-"))
        ctx.launch(update_solver_status, 1,
                   [self.error_stats, ctx.global_count(), max_error, max_error * PEAK_ERROR_RATIO, int(kind == DIVERGENCE), *rate, ctx.dt, min_it, max_it,
                    int(first), 0 if kind == DRIFT else kind, self.average_error[kind], self.condition,
                    self.iterations, *((self.drift_totals, self.drift_streak) if kind == DRIFT
                                       else (self.totals, self.max_iteration_streak)),
                    self._residual(kind), max_error * ctx.constants.particle_diameter])

    def _residual(self, kind):
        """The coupled bodies' velocity residual the loop of a solve of ``kind`` reads (:meth:`_couple`), or an empty
        array (no dynamic bodies; the drift half)."""
        return self.ctx.bodies.coupling["residual"] if self._coupled(kind) else self.no_coupling

    def _solve(self, kind, inputs, max_error, min_it, max_it, velocity=None, rate=(0.0, 0.0)):
        """One pressure solve of ``kind`` (DIVERGENCE, DENSITY or DRIFT) that accumulates its stiffness in
        ``pressure_sum[kind]`` and applies it to ``velocity`` (default: the fluid's). ``rate`` = (per second, least):
        a tolerance per unit time, rate[0] x dt within [rate[1], max_error] (none when rate[0] is 0)."""
        ctx = self.ctx
        velocity = ctx.fluid.v if velocity is None else velocity
        self._couple(kind)  # the bodies' velocities as the fluid's now (the density solve: after the step's g dt)
        if not ctx.parameters.warm_start:
            self.pressure_sum[kind].zero_()
        elif self._bulk_first(kind):
            ctx.launch(warm_start_bulk, ctx.num_fluid,
                       [self.pressure_sum[kind], ctx.dt, ctx.dt_previous, self.surface, self.stiffness])
            ctx.exchange(self.stiffness)
            self._apply(kind, 0, velocity)
            ctx.exchange(velocity)
        self._measure(kind, inputs, max_error, min_it, max_it, True, rate)

        def iteration():
            ctx.exchange(self.stiffness)  # k_j of the apply
            self._apply(kind, 1, velocity)
            ctx.exchange(velocity)  # v_j of the next source
            self._measure(kind, inputs, max_error, min_it, max_it, False, rate)

        wp.capture_while(self.condition, iteration)

    def shift_particles(self):
        """After the position update: the density drift's correction (a periodic box, see
        :meth:`correct_density`), then particle shifting down the concentration gradient of the step's
        density pass (none when ``solver.shifting`` is 0; tangential beside walls and in the surface band, none on
        the free surface: :func:`compute_shift`)."""
        ctx, c = self.ctx, self.ctx.constants
        f = ctx.fluid
        if self.drift_by_positions:
            ctx.launch(advect_positions, ctx.num_fluid, [self.drift_velocity, ctx.dt, ctx.lower, ctx.period,
                                                         c.inside_lo, c.inside_hi, f.x])
        if self.shifting <= 0.0:
            return
        ctx.exchange(self.concentration_gradient, self.surface)  # read at the neighbours
        ctx.launch(compute_shift, ctx.num_fluid,
                   [self.concentration_gradient, f.x, ctx.neighbour_lists(), self.surface, self.free_surface,
                    c.support_radius, ctx.dt, ctx.max_speed_sq, self.shifting,
                    MAX_SHIFT * c.particle_diameter, int(not self.drift_by_positions), self.shift])
        ctx.launch(apply_shift, ctx.num_fluid, [self.shift, ctx.lower, ctx.period, c.inside_lo, c.inside_hi, f.x])

    # -- statistics (host reads, outside the step) -----------------------------------------
    def iteration_totals(self):
        """(divergence iterations, divergence solves, density iterations, density solves) so far."""
        return tuple(int(v) for v in self.totals.numpy())

    def drift_iteration_totals(self):
        """(drift iterations, drift solves) so far: the split density solve's drift half (a periodic box; (0, 0)
        elsewhere)."""
        return tuple(int(v) for v in self.drift_totals.numpy()) if self.drift_by_positions else (0, 0)

    def last_errors(self):
        return float(self.average_error[DIVERGENCE].numpy()[0]), float(self.average_error[DENSITY].numpy()[0])

    def pressure_field(self):
        """Pressure [Pa] per particle of the last step (host copy): p = k rho^2 / rho0 of the stiffness that the
        divergence and density solves applied (together, the pressure force), with the densities of that step."""
        ctx = self.ctx
        k = ctx.host(self.pressure_sum[DENSITY]) + ctx.host(self.pressure_sum[DIVERGENCE])
        return k * ctx.host(ctx.fluid.density) ** 2 / ctx.constants.rest_density

    def free_surface_count(self):
        """Fluid particles on the free surface at the last step (host read)."""
        return int(self.surface_count.numpy()[0])
