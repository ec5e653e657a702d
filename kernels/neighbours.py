"""Neighbour search on ``wp.HashGrid`` and cell-order reordering of particle arrays.

Neighbours are stored as compressed rows (CSR): the neighbours of particle ``i`` are
``index[offset[i] : offset[i + 1]]``. The list is built once per step from the hash
grid and then read by every solver iteration, which is cheaper than repeating the
27-cell grid query in each pass.
"""

from typing import Any

import warp as wp

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


@wp.kernel
def find_neighbours(
    grid: wp.uint64,
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
    boundaries (the images of the query point) where the domain has them.

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
    for image in range(27):
        shift = image_shift(x, lower, period, support_radius, image)
        if wp.isnan(shift[0]):
            continue
        xs = x + shift
        query = wp.hash_grid_query(grid, xs, support_radius)
        j = int(0)
        while wp.hash_grid_query_next(query, j):
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
