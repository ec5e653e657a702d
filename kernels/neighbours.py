"""Neighbour search on a counting-sorted cell grid and cell-order reordering of particle arrays.

Neighbours are stored as compressed rows (CSR): the neighbours of particle ``i`` are
``index[offset[i] : offset[i + 1]]``. The list is built once per step from the cell
grid and then read by every solver iteration, which is cheaper than repeating the
grid query in each pass.
"""

from typing import Any

import warp as wp

from .particles import SymmetricMatrix

wp.set_module_options({"enable_backward": False})


@wp.func
def image_shift(x: wp.vec3, lower: wp.vec3, period: wp.vec3, support_radius: float, image: int):
    """Shift of periodic image ``image`` (0..26; 13 is the particle itself) of a query point, or a
    vector with a NaN when that image cannot reach neighbours (non-periodic axis, or x farther
    than the support radius from the face the image crosses)."""
    shift = wp.vec3(0.0)
    code = image
    for k in range(3):
        s = code % 3 - 1
        code = code // 3
        if s != 0:
            p = period[k]
            if p <= 0.0:
                return wp.vec3(wp.nan)
            if s > 0 and x[k] - lower[k] >= support_radius:
                return wp.vec3(wp.nan)
            if s < 0 and lower[k] + p - x[k] >= support_radius:
                return wp.vec3(wp.nan)
            shift[k] = float(s) * p
    return shift


@wp.struct
class CellGrid:
    """Points counting-sorted into a dense grid of cubic cells over the domain (x fastest).

    ``ids`` lists the points cell by cell; the points of cell ``c`` are ``ids[start : cell_end[c]]``
    with ``start = cell_end[c - 1]`` (0 for the first cell). Points outside the domain go into its
    border cells (coordinates clamped), so every point is found by a query that clamps the same way;
    along x the cells of a query are one run of ``ids``."""

    lower: wp.vec3
    inverse_cell_size: float
    dims: wp.vec3i
    cell_end: wp.array(dtype=wp.int32)
    ids: wp.array(dtype=wp.int32)


@wp.func
def cell_coords(grid: CellGrid, p: wp.vec3):
    """Integer cell of point ``p``, clamped into the grid."""
    c = (p - grid.lower) * grid.inverse_cell_size
    return wp.vec3i(
        wp.clamp(int(wp.floor(c[0])), 0, grid.dims[0] - 1),
        wp.clamp(int(wp.floor(c[1])), 0, grid.dims[1] - 1),
        wp.clamp(int(wp.floor(c[2])), 0, grid.dims[2] - 1),
    )


@wp.func
def cell_index(grid: CellGrid, c: wp.vec3i):
    return (c[2] * grid.dims[1] + c[1]) * grid.dims[0] + c[0]


@wp.func
def cell_run_start(grid: CellGrid, cell: int):
    """First entry of ``cell`` in ``grid.ids`` (after the build, ``cell_end`` holds the ends)."""
    if cell == 0:
        return 0
    return grid.cell_end[cell - 1]


@wp.kernel
def count_points_in_cells(grid: CellGrid, points: wp.array(dtype=wp.vec3)):
    """First of the counting sort: the number of points per cell, into ``cell_end`` (zeroed)."""
    i = wp.tid()
    wp.atomic_add(grid.cell_end, cell_index(grid, cell_coords(grid, points[i])), 1)


@wp.kernel
def scatter_points_to_cells(grid: CellGrid, points: wp.array(dtype=wp.vec3)):
    """Last of the counting sort: with ``cell_end`` scanned to each cell's start, every point takes
    the next slot of its cell; the cursor then ends at the cell's end, which is what stays."""
    i = wp.tid()
    slot = wp.atomic_add(grid.cell_end, cell_index(grid, cell_coords(grid, points[i])), 1)
    grid.ids[slot] = i


@wp.kernel
def find_neighbours(
    grid: CellGrid,
    query_points: wp.array(dtype=wp.vec3),
    grid_points: wp.array(dtype=wp.vec3),
    support_radius: float,
    exclude_self: int,
    lower: wp.vec3,
    period: wp.vec3,
    fill: int,
    rows: wp.array(dtype=wp.int32),
    neighbours: wp.array(dtype=wp.int32),
):
    """The grid points strictly inside the support radius of each query point, through the periodic
    boundaries (the images of the query point) where the domain has them. Per image, each row of
    cells along x is one contiguous run of the grid's ids (9 runs for a cell size of the radius).

    Two launches build a CSR list: with ``fill == 0`` ``rows[i]`` receives the count (scan it into
    offsets), with ``fill != 0`` ``rows`` holds the offsets and the indices go into ``neighbours``."""
    i = wp.tid()
    x = query_points[i]
    k = int(0)
    end = int(0)
    if fill != 0:
        k = rows[i]
        end = rows[i + 1]
    n = int(0)
    reach = wp.vec3(support_radius)
    for image in range(27):
        shift = image_shift(x, lower, period, support_radius, image)
        if wp.isnan(shift[0]):
            continue
        xs = x + shift
        lo = cell_coords(grid, xs - reach)
        hi = cell_coords(grid, xs + reach)
        for cz in range(lo[2], hi[2] + 1):
            for cy in range(lo[1], hi[1] + 1):
                row = cell_index(grid, wp.vec3i(0, cy, cz))
                for s in range(cell_run_start(grid, row + lo[0]), grid.cell_end[row + hi[0]]):
                    j = grid.ids[s]
                    if exclude_self != 0 and j == i and image == 13:
                        continue
                    if wp.length(xs - grid_points[j]) < support_radius:
                        n += 1
                        if fill != 0 and k < end:
                            neighbours[k] = j
                            k += 1
    if fill == 0:
        rows[i] = n


@wp.func
def spread_bits(v: int):
    """Spreads the low 10 bits of v so that two zero bits separate each (Morton order)."""
    x = v & 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


@wp.kernel
def compute_morton_keys(
    x: wp.array(dtype=wp.vec3),
    origin: wp.vec3,
    cell_size: float,
    keys: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
):
    """Z-order key of each particle's grid cell, for sorting particles into cell order."""
    i = wp.tid()
    c = (x[i] - origin) / cell_size
    cx = wp.clamp(int(wp.floor(c[0])), 0, 1023)
    cy = wp.clamp(int(wp.floor(c[1])), 0, 1023)
    cz = wp.clamp(int(wp.floor(c[2])), 0, 1023)
    keys[i] = spread_bits(cx) | (spread_bits(cy) << 1) | (spread_bits(cz) << 2)
    order[i] = i


@wp.kernel
def gather(src: wp.array(dtype=Any), order: wp.array(dtype=wp.int32), dst: wp.array(dtype=Any)):
    """dst[i] = src[order[i]]: applies a permutation to a per-particle field of any type."""
    i = wp.tid()
    dst[i] = src[order[i]]


for _t in (float, wp.int32, wp.vec3, SymmetricMatrix):  # declared up front (subdomains permute from several threads)
    wp.overload(gather, [wp.array(dtype=_t), wp.array(dtype=wp.int32), wp.array(dtype=_t)])
