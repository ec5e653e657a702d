"""Neighbour lists for the fluid: fluid-fluid and fluid-boundary, rebuilt once per step."""

from __future__ import annotations

import numpy as np
import warp as wp

from warpsph.kernels import neighbours as nk
from warpsph.kernels.particles import Neighbours

GROWTH = 1.05  # spare capacity when a neighbour list is sized (first update) or must grow
MIN_CELLS = 2**18  # a cell table may always have this many cells (1 MiB) ...
CELLS_PER_POINT = 2  # ... or this many per fluid particle and boundary sample; coarser cells beyond


def grid_geometry(domain, support_radius, num_points):
    """Cell size and cells per axis of a dense grid over ``domain``: cells of the support radius
    (a query spans 3 per axis), enlarged only where the table would exceed its cap."""
    extent = np.maximum(np.asarray(domain.max, np.float64) - np.asarray(domain.min, np.float64), support_radius)
    cap = max(MIN_CELLS, CELLS_PER_POINT * num_points)
    cell = support_radius * max(1.0, (float(np.prod(extent / support_radius)) / cap) ** (1.0 / 3.0))
    return cell, [max(1, int(np.ceil(e / cell - 1e-6))) for e in extent]


class PointGrid:
    """One point set (the fluid, or the boundary samples) counting-sorted into the cells of a
    :class:`~warpsph.kernels.neighbours.CellGrid`: a count, a scan and a scatter, no sort. It holds
    one int32 per cell; the ids (one per point) are given, so the fluid's can be scratch."""

    def __init__(self, sim, lower, cell_size, dims, ids):
        self.sim = sim
        g = self.grid = nk.CellGrid()
        g.lower = lower
        g.inverse_cell_size = 1.0 / cell_size
        g.dims = wp.vec3i(*dims)
        g.cell_end = sim.zeros("neighbours", int(np.prod(dims)), dtype=wp.int32)
        g.ids = ids

    def build(self, points, count):
        """Sorts the first ``count`` of ``points`` into the cells."""
        self.grid.cell_end.zero_()
        self.sim.launch(nk.count_points_in_cells, count, [self.grid, points])
        wp.utils.array_scan(self.grid.cell_end, self.grid.cell_end, inclusive=False)
        self.sim.launch(nk.scatter_points_to_cells, count, [self.grid, points])


class NeighbourSearch:
    """Cell grids and CSR neighbour lists.

    The boundary grid is built once, or each step when bodies move (:meth:`rebuild_boundary_grid`);
    the fluid grid (its ids in the scratch pool, free while the lists are built) and both
    lists are rebuilt by :meth:`update`, which costs two neighbour-grid passes and one
    host read of the list sizes per step. The lists are sized by the first update to what it
    found plus 5 % (a fixed 32 + 8 slots a particle overestimated the boundary list 3x in a dam
    break), and grow by the same margin when needed, so their arrays (and any CUDA graph that
    captured them) rarely change.
    """

    def __init__(self, sim, boundary_x: wp.array, samples=None):
        """``samples``: how many of ``boundary_x`` are samples (in the grid; default all): the rest are the volume
        maps' points (warpsph.volume_maps), each in its own fluid particle's list only (:attr:`volume_maps`)."""
        self.sim = sim
        self.samples = boundary_x.shape[0] if samples is None else int(samples)
        # (VolumeMaps, a callable that places their points before the boundary list); None: no maps
        self.volume_maps = None
        n = sim.capacity
        self.support_radius = sim.support_radius
        self.lower = wp.vec3(*np.asarray(sim.scene.domain.min, dtype=np.float32))
        self.period = wp.vec3(*sim.scene.domain.period)
        points = n if sim.halo is None else sim.halo.grid_points  # a subdomain: the whole simulation's grid
        self.cell_size, dims = grid_geometry(sim.scene.domain, self.support_radius, points + self.samples)
        self.fluid_grid = PointGrid(sim, self.lower, self.cell_size, dims, sim.scratch(wp.int32, 0))
        self.boundary_x = boundary_x
        self.boundary_grid = None
        if self.samples > 0:
            ids = sim.zeros("neighbours", self.samples, dtype=wp.int32)
            self.boundary_grid = PointGrid(sim, self.lower, self.cell_size, dims, ids)
            self.rebuild_boundary_grid()
        # counts are written into the offsets arrays and scanned in place (no count arrays)
        self.fluid_offsets = sim.zeros("neighbours", n + 1, dtype=wp.int32)
        self.boundary_offsets = sim.zeros("neighbours", n + 1, dtype=wp.int32)
        self.fluid_neighbours = sim.zeros("neighbours", 1, dtype=wp.int32)  # sized by the first update
        self.boundary_neighbours = sim.zeros("neighbours", 1, dtype=wp.int32)
        self.generation = 0  # bumped when a list array is reallocated
        self._no_list = wp.empty(0, dtype=wp.int32, device=sim.device)

    def rebuild_boundary_grid(self):
        """After boundary samples moved: the boundary cell grid at their new positions."""
        self.boundary_grid.build(self.boundary_x, self.samples)

    def update(self, x: wp.array):
        """Rebuilds the fluid grid and both neighbour lists for positions ``x``."""
        sim = self.sim
        n = sim.num_fluid
        self.fluid_grid.build(x, n + (sim.halo.ghosts if sim.halo is not None else 0))  # ghost rows: found, not queried
        self.fluid_neighbours = self._build_list(self.fluid_grid, x, x, 1, self.fluid_offsets, self.fluid_neighbours)
        if self.boundary_grid is not None:
            maps = None
            if self.volume_maps is not None:
                maps, place = self.volume_maps
                place()  # each particle's own points, which its list then takes
            self.boundary_neighbours = self._build_list(self.boundary_grid, x, self.boundary_x, 0,
                                                        self.boundary_offsets, self.boundary_neighbours, maps)

    def _build_list(self, grid, x, grid_points, exclude_self, offsets, neighbours, maps=None):
        """One CSR list: counts into ``offsets``, an exclusive scan in place (row n: the total), then
        the indices; returns the index array (reallocated when the total outgrew it)."""
        sim, n = self.sim, self.sim.num_fluid
        args = [grid.grid, x, grid_points, self.support_radius, exclude_self, self.lower, self.period]
        rows = offsets[: n + 1]
        rows[n:].zero_()
        sim.launch(nk.find_neighbours, n, args + [0, rows, self._no_list])
        if maps is not None:
            maps.add_neighbours(sim.launch, n, self.sim.boundary.volume, 0, rows, self._no_list)
        wp.utils.array_scan(rows, rows, inclusive=False)
        neighbours = self._ensure_capacity(neighbours, int(rows[n:].numpy()[0]))
        sim.launch(nk.find_neighbours, n, args + [1, rows, neighbours])
        if maps is not None:
            maps.add_neighbours(sim.launch, n, self.sim.boundary.volume, 1, rows, neighbours)
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
