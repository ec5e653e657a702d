"""Structs that group the arrays every neighbour pass reads."""

import warp as wp


@wp.struct
class Neighbours:
    """CSR neighbour lists of the fluid particles: the fluid neighbours of particle i are
    ``fluid[fluid_offsets[i] : fluid_offsets[i + 1]]``, its boundary neighbours likewise.
    ``period`` is the domain's extent along its periodic axes (0 along the others)."""

    fluid_offsets: wp.array(dtype=wp.int32)
    fluid: wp.array(dtype=wp.int32)
    boundary_offsets: wp.array(dtype=wp.int32)
    boundary: wp.array(dtype=wp.int32)
    period: wp.vec3


@wp.func
def periodic_offset(d: wp.vec3, period: wp.vec3):
    """The minimum image of the offset d along the periodic axes (period > 0)."""
    out = d
    for k in range(3):
        p = period[k]
        if p > 0.0:
            out[k] = d[k] - p * wp.floor(d[k] / p + 0.5)
    return out


@wp.func
def wrap_into_domain(p: wp.vec3, lower: wp.vec3, period: wp.vec3):
    """Point p mapped into [lower, lower + period) along the periodic axes (period > 0)."""
    out = p
    for k in range(3):
        if period[k] > 0.0:
            out[k] = lower[k] + (p[k] - lower[k]) - period[k] * wp.floor((p[k] - lower[k]) / period[k])
    return out


@wp.func
def keep_in_domain(p: wp.vec3, lower: wp.vec3, period: wp.vec3, inside_lo: wp.vec3, inside_hi: wp.vec3):
    """Point p wrapped along the periodic axes and held within [inside_lo, inside_hi] along the walled
    ones (the domain's faces: a particle never crosses a wall, whatever its speed). NaN stays NaN, for the
    health check to find."""
    out = wrap_into_domain(p, lower, period)
    for k in range(3):
        if out[k] < inside_lo[k]:
            out[k] = inside_lo[k]
        elif out[k] > inside_hi[k]:
            out[k] = inside_hi[k]
    return out


@wp.func
def separation(nb: Neighbours, a: wp.vec3, b: wp.vec3):
    """x_ab = a - b, through the periodic boundaries where the domain has them."""
    return periodic_offset(a - b, nb.period)


@wp.struct
class Boundary:
    """Akinci boundary samples: position, volume V_b and velocity (of their body). Static samples
    come first and stand still: ``v`` holds the moving ones' only, ``v[b - first_moving]`` (read it
    through :func:`boundary_velocity`). Samples from ``first_dynamic`` on belong to dynamic bodies:
    the pressure solvers add the reaction of each fluid-sample pair to ``impulse`` (per unit fluid
    particle mass) for two-way coupling."""

    x: wp.array(dtype=wp.vec3)
    v: wp.array(dtype=wp.vec3)
    volume: wp.array(dtype=float)
    impulse: wp.array(dtype=wp.vec3)
    first_moving: int
    first_dynamic: int


@wp.func
def boundary_velocity(boundary: Boundary, b: int):
    """Velocity of boundary sample b: zero for a static one."""
    if b < boundary.first_moving:
        return wp.vec3(0.0)
    return boundary.v[b - boundary.first_moving]
