"""Structs that group the arrays every neighbour pass reads, and the stored form of a symmetric 3x3 matrix."""

import warp as wp

# A symmetric 3x3 matrix as its six entries (xx, yy, zz, xy, xz, yz): the corrected kernel gradient L_i
# (kernels/pressure.py) and the strain rate (kernels/viscosity.py), read for every neighbour by the corrected
# pressure force and viscosity. Six values instead of nine: the pressure force reads 40 bytes a neighbour instead
# of 52 (1M dam break, H100: the density solve 0.25 ms a step cheaper).
SymmetricMatrix = wp.types.vector(length=6, dtype=float)


@wp.func
def pack_symmetric(m: wp.mat33):
    """The symmetric part of m, (m + m^T) / 2, as a :data:`SymmetricMatrix`."""
    return SymmetricMatrix(m[0, 0], m[1, 1], m[2, 2], 0.5 * (m[0, 1] + m[1, 0]), 0.5 * (m[0, 2] + m[2, 0]),
                           0.5 * (m[1, 2] + m[2, 1]))


@wp.func
def symmetric_times(s: SymmetricMatrix, v: wp.vec3):
    """S v for the matrix S a :data:`SymmetricMatrix` stores."""
    return wp.vec3(s[0] * v[0] + s[3] * v[1] + s[4] * v[2], s[3] * v[0] + s[1] * v[1] + s[5] * v[2],
                   s[4] * v[0] + s[5] * v[1] + s[2] * v[2])


@wp.func
def symmetric_quadratic(s: SymmetricMatrix, v: wp.vec3):
    """v . S v for the matrix S a :data:`SymmetricMatrix` stores."""
    return (s[0] * v[0] * v[0] + s[1] * v[1] * v[1] + s[2] * v[2] * v[2]
            + 2.0 * (s[3] * v[0] * v[1] + s[4] * v[0] * v[2] + s[5] * v[1] * v[2]))


def symmetric_matrices(rows):
    """The (n, 3, 3) matrices of a host copy of a :data:`SymmetricMatrix` array, (n, 6)."""
    import numpy as np

    rows = np.asarray(rows, dtype=np.float64)
    out = np.empty((len(rows), 3, 3))
    for k, (a, b) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
        out[:, a, b] = out[:, b, a] = rows[:, k]
    return out


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
