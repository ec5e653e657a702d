"""Kernels of the slab decomposition (warpsph/decomposition.py): which subdomain a particle belongs to, which
particles another subdomain needs as ghosts, and the row copies between subdomains."""

from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def slab_of(c: float, cuts: wp.array(dtype=float)):
    """The slab holding coordinate ``c``: the number of interior cuts at or below it."""
    s = int(0)
    for k in range(cuts.shape[0]):
        if c >= cuts[k]:
            s += 1
    return s


@wp.kernel
def assign_subdomains(
    x: wp.array(dtype=wp.vec3),
    axis: int,
    cuts: wp.array(dtype=float),
    own: int,
    keys: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    leaving: wp.array(dtype=wp.int32),
):
    """keys_i = 0 for a particle that stays in subdomain ``own``, 1 + its new subdomain for one that left
    (a stable sort by key puts the stayers first, the leavers grouped by destination); ``leaving[s]``
    counts the particles bound for subdomain s."""
    i = wp.tid()
    s = slab_of(x[i][axis], cuts)
    key = int(0)
    if s != own:
        key = 1 + s
        wp.atomic_add(leaving, s, 1)
    keys[i] = key
    order[i] = i


@wp.func
def interval_distance(c: float, lower: float, upper: float, period: float):
    """Distance from ``c`` to [lower, upper), through the periodic images when ``period`` > 0."""
    d = wp.max(wp.max(lower - c, c - upper), 0.0)
    if period > 0.0:
        d = wp.min(d, wp.max(wp.max(lower - (c + period), (c + period) - upper), 0.0))
        d = wp.min(d, wp.max(wp.max(lower - (c - period), (c - period) - upper), 0.0))
    return d


@wp.kernel
def mark_ghosts(
    x: wp.array(dtype=wp.vec3),
    axis: int,
    lower: float,
    upper: float,
    period: float,
    width: float,
    flags: wp.array(dtype=wp.int32),
):
    """flags_i = 1 where particle i lies within ``width`` (the support radius) of the slab [lower, upper)
    along ``axis``: a neighbour of one of that slab's particles, so a ghost there."""
    i = wp.tid()
    flags[i] = int(interval_distance(x[i][axis], lower, upper, period) < width)


@wp.kernel
def gather_rows(src: wp.array(dtype=Any), index: wp.array(dtype=wp.int32), first: int, dst: wp.array(dtype=Any)):
    """dst[first + i] = src[index[i]]: the rows of one field that another subdomain holds as ghosts."""
    i = wp.tid()
    dst[first + i] = src[index[i]]


# the row types a step carries or exchanges, declared up front: the subdomains' threads must not create
# overloads of a generic kernel at the same time (Warp's registry of them is not thread-safe)
ROW_TYPES = (float, wp.int32, wp.vec3)
for _t in ROW_TYPES:
    wp.overload(gather_rows, [wp.array(dtype=_t), wp.array(dtype=wp.int32), int, wp.array(dtype=_t)])
