"""Kernels of the slab decomposition (warpsph/decomposition.py): which particles leave for another subdomain,
which ones another subdomain needs as ghosts, and the row moves. Lists are filled through atomic counters
(no sort, no scan): on a GPU their order varies from run to run, as the order of atomic sums does."""

from typing import Any

import warp as wp

from .particles import SymmetricMatrix

wp.set_module_options({"enable_backward": False})


@wp.func
def slab_of(c: float, cuts: wp.array(dtype=float)):
    """The slab holding coordinate ``c``: the number of interior cuts at or below it."""
    s = int(0)
    for k in range(cuts.shape[0]):
        if c >= cuts[k]:
            s += 1
    return s


@wp.func
def append(lists: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), which: int, room: int, value: int):
    """Appends ``value`` to list ``which`` (entries which * room ..; ``counts[which]`` counts past ``room``,
    so that the caller sees the overflow and lists again with more room)."""
    slot = wp.atomic_add(counts, which, 1)
    if slot < room:
        lists[which * room + slot] = value


@wp.kernel
def list_leavers(
    x: wp.array(dtype=wp.vec3),
    axis: int,
    cuts: wp.array(dtype=float),
    own: int,
    room: int,
    counts: wp.array(dtype=wp.int32),
    leavers: wp.array(dtype=wp.int32),
):
    """Rows whose slab is no longer ``own``, listed by the subdomain they go to."""
    i = wp.tid()
    s = slab_of(x[i][axis], cuts)
    if s != own:
        append(leavers, counts, s, room, i)


@wp.kernel
def list_holes(leavers: wp.array(dtype=wp.int32), room: int, counts: wp.array(dtype=wp.int32), stay: int,
               found: wp.array(dtype=wp.int32), holes: wp.array(dtype=wp.int32)):
    """The leavers' rows below ``stay`` (the rows that stayers will fill), counted in ``found[0]``."""
    t = wp.tid()
    if t % room < counts[t // room]:
        r = leavers[t]
        if r < stay:
            holes[wp.atomic_add(found, 0, 1)] = r


@wp.kernel
def list_movers(x: wp.array(dtype=wp.vec3), axis: int, cuts: wp.array(dtype=float), own: int, stay: int,
                found: wp.array(dtype=wp.int32), movers: wp.array(dtype=wp.int32)):
    """The stayers among rows ``stay ..`` (as many as the holes), counted in ``found[1]``."""
    r = stay + wp.tid()
    if slab_of(x[r][axis], cuts) == own:
        movers[wp.atomic_add(found, 1, 1)] = r


@wp.kernel
def move_rows(holes: wp.array(dtype=wp.int32), movers: wp.array(dtype=wp.int32), found: wp.array(dtype=wp.int32),
              a: wp.array(dtype=Any)):
    """a[holes[i]] = a[movers[i]]: every hole lies below every mover, so no row is read after it is written."""
    i = wp.tid()
    if i < found[0]:
        a[holes[i]] = a[movers[i]]


@wp.func
def interval_distance(c: float, lower: float, upper: float, period: float):
    """Distance from ``c`` to [lower, upper), through the periodic images when ``period`` > 0."""
    d = wp.max(wp.max(lower - c, c - upper), 0.0)
    if period > 0.0:
        d = wp.min(d, wp.max(wp.max(lower - (c + period), (c + period) - upper), 0.0))
        d = wp.min(d, wp.max(wp.max(lower - (c - period), (c - period) - upper), 0.0))
    return d


@wp.kernel
def list_ghosts(
    x: wp.array(dtype=wp.vec3),
    axis: int,
    lower: float,
    upper: float,
    period: float,
    width: float,
    peer: int,
    room: int,
    counts: wp.array(dtype=wp.int32),
    lists: wp.array(dtype=wp.int32),
):
    """Rows within ``width`` (the support radius) of slab [lower, upper) of subdomain ``peer`` along ``axis``:
    neighbours of that slab's particles, so its ghosts; listed as list ``peer``."""
    i = wp.tid()
    if interval_distance(x[i][axis], lower, upper, period) < width:
        append(lists, counts, peer, room, i)


@wp.kernel
def gather_rows(src: wp.array(dtype=Any), index: wp.array(dtype=wp.int32), first: int, dst: wp.array(dtype=Any)):
    """dst[first + i] = src[index[i]]: the rows of one field that another subdomain holds as ghosts."""
    i = wp.tid()
    dst[first + i] = src[index[i]]


@wp.kernel
def combine_values(other: wp.array(dtype=Any), ops: wp.array(dtype=wp.int32), values: wp.array(dtype=Any)):
    """values[k] += other[k] (ops[k] 1) or max(values[k], other[k]) (ops[k] 2); 0 leaves it: one subdomain's
    part of an all-reduction, combined in the same order on every subdomain."""
    k = wp.tid()
    if ops[k] == 1:
        values[k] = values[k] + other[k]
    elif ops[k] == 2:
        values[k] = wp.max(values[k], other[k])


# the row types a step carries or exchanges, declared up front: the subdomains' threads must not create
# overloads of a generic kernel at the same time (Warp's registry of them is not thread-safe)
# (SymmetricMatrix: the corrected kernel gradient and the strain rate: their rows move and are exchanged, never combined)
ROW_TYPES = (float, wp.int32, wp.vec3, SymmetricMatrix)
for _t in ROW_TYPES:
    wp.overload(gather_rows, [wp.array(dtype=_t), wp.array(dtype=wp.int32), int, wp.array(dtype=_t)])
    wp.overload(move_rows, [wp.array(dtype=wp.int32), wp.array(dtype=wp.int32), wp.array(dtype=wp.int32),
                            wp.array(dtype=_t)])
    if _t is not SymmetricMatrix:
        wp.overload(combine_values, [wp.array(dtype=_t), wp.array(dtype=wp.int32), wp.array(dtype=_t)])
