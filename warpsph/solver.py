"""The DFSPH pressure solver (Bender & Koschier 2015/2017): divergence and density.

Both solvers share one loop: warm start, then iterate {apply pressure, recompute the
source and stiffness, average the error, decide} until the average error is below the
tolerance and the minimum iterations are done, or the maximum is reached. The decision
is made on the device (:func:`update_solver_status`) and the loop is a
``wp.capture_while``: on CUDA inside a captured graph no iteration waits on the host.
"""

from __future__ import annotations

import warp as wp

from warpsph.kernels.density_solver import compute_density_source
from warpsph.kernels.divergence_solver import compute_divergence_source
from warpsph.kernels.pressure import apply_pressure_acceleration, scale_warm_start, update_solver_status

DIVERGENCE, DENSITY = 0, 1
# share of the last step's pressure that warm-starts each solver
# Share of the last step's pressure that warm-starts each solver. 1.0 for the density
# solver made the pressure ping-pong between steps in a resting tank (mid-depth pressure
# 4 % .. 180 % of rho g h); 0.5 settles (within 10 %, 15 iterations a step instead of 34 cold).
WARM_START_FACTOR = {DIVERGENCE: 0.5, DENSITY: 0.5}


class DFSPHSolver:
    def __init__(self, sim):
        self.sim = sim
        n = sim.num_fluid
        z = sim.zeros
        self.stiffness = z("pressure", n)
        self.error = z("pressure", n)
        # accumulated stiffness of the last solve of each kind, for the warm start
        self.pressure_sum = [z("pressure", n), z("pressure", n)]
        self.error_sum = z("pressure", 1)
        self.average_error = [z("pressure", 1), z("pressure", 1)]
        self.status = z("pressure", 2, dtype=wp.int32)
        # per solver: [iterations summed over steps, solves]
        self.totals = z("pressure", 4, dtype=wp.int64)

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
        sim, f, nb = self.sim, self.sim.fluid, self.sim.neighbours
        b = sim.boundary
        return [f.x, f.v, nb.fluid_offsets, nb.fluid_neighbours, b.x, b.v, b.volume,
                nb.boundary_offsets, nb.boundary_neighbours]

    def _divergence_inputs(self):
        sim = self.sim
        return self._common() + [sim.fluid.factor, sim.fluid_volume, sim.support_radius, sim.dt]

    def _density_inputs(self):
        sim = self.sim
        return self._common() + [sim.fluid.density, sim.fluid.factor, sim.fluid_volume, sim.rest_density,
                                 sim.support_radius, sim.dt]

    def _apply(self, kind, accumulate):
        sim, nb, b = self.sim, self.sim.neighbours, self.sim.boundary
        sim.launch(apply_pressure_acceleration, sim.num_fluid,
                   [self.stiffness, sim.fluid.x, nb.fluid_offsets, nb.fluid_neighbours, b.x, b.volume,
                    nb.boundary_offsets, nb.boundary_neighbours, sim.fluid_volume, sim.support_radius,
                    sim.dt, accumulate, self.pressure_sum[kind], sim.fluid.v])

    def _measure(self, kind, source_kernel, inputs, max_error, min_it, max_it, first):
        sim = self.sim
        sim.launch(source_kernel, sim.num_fluid, inputs + [self.error, self.stiffness])
        wp.utils.array_sum(self.error, out=self.error_sum)
        sim.launch(update_solver_status, 1,
                   [self.error_sum, sim.num_fluid, max_error, int(kind == DIVERGENCE), sim.dt, min_it, max_it,
                    int(first), kind, self.average_error[kind], self.status, self.totals])

    def _solve(self, kind, source_kernel, inputs, max_error, min_it, max_it):
        sim = self.sim
        if sim.scene.solver.warm_start:
            # the last step's pressure where particles are compressed now
            sim.launch(source_kernel, sim.num_fluid, inputs + [self.error, self.stiffness])
            sim.launch(scale_warm_start, sim.num_fluid,
                       [self.pressure_sum[kind], self.error, sim.dt, sim.dt_previous, int(kind == DIVERGENCE),
                        WARM_START_FACTOR[kind], self.stiffness])
            self._apply(kind, 0)
        else:
            self.pressure_sum[kind].zero_()
        self._measure(kind, source_kernel, inputs, max_error, min_it, max_it, True)

        def iteration():
            self._apply(kind, 1)
            self._measure(kind, source_kernel, inputs, max_error, min_it, max_it, False)

        wp.capture_while(self.status, iteration)

    # -- statistics (host reads, outside the step) -----------------------------------------
    def iteration_totals(self):
        """(divergence iterations, divergence solves, density iterations, density solves) so far."""
        return tuple(int(v) for v in self.totals.numpy())

    def last_errors(self):
        return float(self.average_error[DIVERGENCE].numpy()[0]), float(self.average_error[DENSITY].numpy()[0])
