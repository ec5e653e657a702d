"""Neighbour lists for the fluid: fluid-fluid and fluid-boundary, rebuilt once per step."""

from __future__ import annotations

import numpy as np
import warp as wp

from warpsph.kernels import neighbours as nk
from warpsph.kernels.particles import Neighbours

GRID_DIM = 128  # hash grid buckets per axis (cells hash into a 128^3 table)
GROWTH = 1.05  # spare capacity when a neighbour list is sized (first update) or must grow


class NeighbourSearch:
    """Hash grids and CSR neighbour lists.

    The boundary grid is built once, or each step when bodies move (:meth:`rebuild_boundary_grid`,
    about a tenth of a grid pass); the fluid grid and both
    lists are rebuilt by :meth:`update`, which costs two neighbour-grid passes and one
    host read of the list sizes per step. The lists are sized by the first update to what it
    found plus 5 % (a fixed 32 + 8 slots a particle overestimated the boundary list 3x in a dam
    break), and grow by the same margin when needed, so their arrays (and any CUDA graph that
    captured them) rarely change.
    """

    def __init__(self, sim, boundary_x: wp.array):
        self.sim = sim
        n = sim.capacity
        self.support_radius = sim.support_radius
        self.fluid_grid = wp.HashGrid(GRID_DIM, GRID_DIM, GRID_DIM, device=sim.device)
        self.boundary_x = boundary_x
        self.boundary_grid = None
        if boundary_x.shape[0] > 0:
            self.boundary_grid = wp.HashGrid(GRID_DIM, GRID_DIM, GRID_DIM, device=sim.device)
            self.boundary_grid.build(boundary_x, self.support_radius)
        # counts are written into the offsets arrays and scanned in place (no count arrays)
        self.fluid_offsets = sim.zeros("neighbours", n + 1, dtype=wp.int32)
        self.boundary_offsets = sim.zeros("neighbours", n + 1, dtype=wp.int32)
        self.fluid_neighbours = sim.zeros("neighbours", 1, dtype=wp.int32)  # sized by the first update
        self.boundary_neighbours = sim.zeros("neighbours", 1, dtype=wp.int32)
        self.generation = 0  # bumped when a list array is reallocated
        self._no_list = wp.empty(0, dtype=wp.int32, device=sim.device)
        self.lower = wp.vec3(*np.asarray(sim.scene.domain.min, dtype=np.float32))
        self.period = wp.vec3(*sim.scene.domain.period)

    def rebuild_boundary_grid(self):
        """After boundary samples moved: the boundary hash grid at their new positions."""
        self.boundary_grid.build(self.boundary_x, self.support_radius)

    def update(self, x: wp.array):
        """Rebuilds the fluid grid and both neighbour lists for positions ``x``."""
        sim = self.sim
        n = sim.num_fluid
        self.fluid_grid.build(sim.active(x), self.support_radius)
        self.fluid_neighbours = self._build_list(self.fluid_grid, x, x, 1, self.fluid_offsets, self.fluid_neighbours)
        if self.boundary_grid is not None:
            self.boundary_neighbours = self._build_list(self.boundary_grid, x, self.boundary_x, 0,
                                                        self.boundary_offsets, self.boundary_neighbours)

    def _build_list(self, grid, x, grid_points, exclude_self, offsets, neighbours):
        """One CSR list: counts into ``offsets``, an exclusive scan in place (row n: the total), then
        the indices; returns the index array (reallocated when the total outgrew it)."""
        sim, n = self.sim, self.sim.num_fluid
        args = [grid.id, x, grid_points, self.support_radius, exclude_self, self.lower, self.period]
        rows = offsets[: n + 1]
        rows[n:].zero_()
        sim.launch(nk.find_neighbours, n, args + [0, rows, self._no_list])
        wp.utils.array_scan(rows, rows, inclusive=False)
        neighbours = self._ensure_capacity(neighbours, int(rows[n:].numpy()[0]))
        sim.launch(nk.find_neighbours, n, args + [1, rows, neighbours])
        return neighbours

    @property
    def lists(self) -> Neighbours:
        """The current lists as the struct the kernels take."""
        s = Neighbours()
        s.fluid_offsets = self.fluid_offsets
        s.fluid = self.fluid_neighbours
        s.boundary_offsets = self.boundary_offsets
        s.boundary = self.boundary_neighbours
        s.period = self.period
        return s

    def _ensure_capacity(self, array, needed):
        if needed <= array.shape[0]:
            return array
        self.generation += 1
        self.sim.allocations["neighbours"] -= array.capacity  # the old array goes
        return self.sim.zeros("neighbours", int(needed * GROWTH) + 1, dtype=wp.int32)

    def counts(self):
        """Per-particle (fluid, boundary) neighbour counts as numpy arrays (for tests and stats)."""
        n = self.sim.num_fluid
        return np.diff(self.fluid_offsets.numpy()[: n + 1]), np.diff(self.boundary_offsets.numpy()[: n + 1])


def sort_order(sim, x: wp.array, keys: wp.array, order: wp.array):
    """Fills ``order`` with the permutation that sorts particles by Z-order cell (on the device)."""
    n = sim.num_fluid
    origin = wp.vec3(*np.asarray(sim.scene.domain.min, dtype=np.float32))
    sim.launch(nk.compute_morton_keys, n, [x, origin, sim.support_radius, keys, order])
    wp.utils.radix_sort_pairs(keys, order, n)
