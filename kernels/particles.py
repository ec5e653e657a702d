"""Structs that group the arrays every neighbour pass reads."""

import warp as wp


@wp.struct
class Neighbours:
    """CSR neighbour lists of the fluid particles: the fluid neighbours of particle i are
    ``fluid[fluid_offsets[i] : fluid_offsets[i + 1]]``, its boundary neighbours likewise."""

    fluid_offsets: wp.array(dtype=wp.int32)
    fluid: wp.array(dtype=wp.int32)
    boundary_offsets: wp.array(dtype=wp.int32)
    boundary: wp.array(dtype=wp.int32)


@wp.struct
class Boundary:
    """Akinci boundary samples: position, velocity (of their body) and volume V_b."""

    x: wp.array(dtype=wp.vec3)
    v: wp.array(dtype=wp.vec3)
    volume: wp.array(dtype=float)
