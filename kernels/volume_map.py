"""Volume maps (Bender et al. 2019, "Volume Maps: An Implicit Boundary Representation for SPH") for dynamic bodies.

A mapped body holds the fluid as SPlisHSPlasH's boundaryHandlingMethod 2 does: each fluid particle i within the
support of the body's surface sees one boundary point of its own, x_b = x_i - max(d + r/2, 2r) n (d the distance from
the surface, less the map's thickness, n the outward normal at the closest surface point), with the volume
Psi(x_i) = integral over the ball |y| < H of chi(d(x_i + y)), chi = 1 behind the surface and W(s)/W(0) at s in front
(tabulated once on a grid in the body's frame, :func:`map_volume`). The point is a boundary sample like any other
(``Boundary``: its position, volume, the body's rigid velocity there and the reaction impulse), in slot
``first + i * maps + m`` of the boundary arrays, listed among particle i's boundary neighbours only
(:func:`add_map_neighbours`); the body's own samples keep volume 0 and serve its contacts only."""

import warp as wp

from .bodies import rigid_velocity

wp.set_module_options({"enable_backward": False})


@wp.kernel
def signed_distance_at_points(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), max_distance: float,
                              distance: wp.array(dtype=float)):
    """Signed distance of each point from a closed mesh (negative inside; the generalised winding number decides),
    ``max_distance`` where the surface is farther (set-up of :func:`map_volume`'s grid)."""
    k = wp.tid()
    p = points[k]
    q = wp.mesh_query_point_sign_winding_number(mesh, p, max_distance)
    if q.result:
        c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        distance[k] = q.sign * wp.length(p - c)
    else:
        distance[k] = max_distance


@wp.func
def map_volume(values: wp.array(dtype=float), first: int, dims: wp.vec3i, lower: wp.vec3, inverse_spacing: float,
               p: wp.vec3):
    """Psi at the body-space point p: trilinear in the map's grid (x fastest, from ``first`` in ``values``); 0 outside."""
    c = (p - lower) * inverse_spacing
    i0 = int(wp.floor(c[0]))
    j0 = int(wp.floor(c[1]))
    k0 = int(wp.floor(c[2]))
    if i0 < 0 or j0 < 0 or k0 < 0 or i0 >= dims[0] - 1 or j0 >= dims[1] - 1 or k0 >= dims[2] - 1:
        return 0.0
    fx = c[0] - float(i0)
    fy = c[1] - float(j0)
    fz = c[2] - float(k0)
    out = float(0.0)
    for corner in range(8):
        a = corner & 1
        b = (corner >> 1) & 1
        e = (corner >> 2) & 1
        w = wp.where(a == 1, fx, 1.0 - fx) * wp.where(b == 1, fy, 1.0 - fy) * wp.where(e == 1, fz, 1.0 - fz)
        out += w * values[first + ((k0 + e) * dims[1] + (j0 + b)) * dims[0] + (i0 + a)]
    return out


@wp.kernel
def place_map_samples(
    x: wp.array(dtype=wp.vec3),
    mesh: wp.array(dtype=wp.uint64),
    map_body: wp.array(dtype=wp.int32),
    thickness: wp.array(dtype=float),
    values: wp.array(dtype=float),
    value_first: wp.array(dtype=wp.int32),
    dims: wp.array(dtype=wp.vec3i),
    lower: wp.array(dtype=wp.vec3),
    inverse_spacing: wp.array(dtype=float),
    rotation: wp.array(dtype=wp.mat33),
    position: wp.array(dtype=wp.vec3),
    velocity: wp.array(dtype=wp.vec3),
    angular_velocity: wp.array(dtype=wp.vec3),
    maps: int,
    first: int,
    first_moving: int,
    particle_radius: float,
    support_radius: float,
    boundary_x: wp.array(dtype=wp.vec3),
    boundary_v: wp.array(dtype=wp.vec3),
    boundary_volume: wp.array(dtype=float),
):
    """One thread per fluid particle i and map m: particle i's boundary point of map m's body (slot first + i maps + m),
    SPlisHSPlasH's TimeStep::computeVolumeAndBoundaryX: where 0 < d < H, the point max(d + r/2, 2r) behind x_i along
    the outward normal, the map's volume Psi(x_i) and the body's rigid velocity there; elsewhere (outside the support,
    or inside the body) volume 0 and the point out of reach."""
    t = wp.tid()
    i = t / maps
    m = t - i * maps
    slot = first + t
    body = map_body[m]
    xi = x[i]
    r = rotation[body]
    local = wp.transpose(r) * (xi - position[body])
    volume = float(0.0)
    xb = xi + wp.vec3(2.0 * support_radius, 0.0, 0.0)
    vb = wp.vec3(0.0)
    q = wp.mesh_query_point_sign_winding_number(mesh[m], local, support_radius + thickness[m])
    if q.result:
        c = wp.mesh_eval_position(mesh[m], q.face, q.u, q.v)
        offset = local - c
        length = wp.length(offset)
        d = q.sign * length - thickness[m]
        if d > 0.0 and d < support_radius and length > 1.0e-9 * support_radius:
            psi = map_volume(values, value_first[m], dims[m], lower[m], inverse_spacing[m], local)
            if psi > 0.0:
                normal = r * (offset * (q.sign / length))  # outward, world
                xb = xi - wp.max(d + 0.5 * particle_radius, 2.0 * particle_radius) * normal
                volume = psi
                vb = rigid_velocity(velocity[body], angular_velocity[body], xb - position[body])
    boundary_x[slot] = xb
    boundary_volume[slot] = volume
    boundary_v[slot - first_moving] = vb


@wp.kernel
def place_map_velocities(
    map_body: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    velocity: wp.array(dtype=wp.vec3),
    angular_velocity: wp.array(dtype=wp.vec3),
    maps: int,
    first: int,
    first_moving: int,
    boundary_x: wp.array(dtype=wp.vec3),
    boundary_volume: wp.array(dtype=float),
    boundary_v: wp.array(dtype=wp.vec3),
):
    """Strong coupling, after a body's velocity changed inside a solve: the rigid velocity at each fluid particle's
    boundary point of the body (as ``place_body_velocities`` for its samples)."""
    t = wp.tid()
    slot = first + t
    if boundary_volume[slot] > 0.0:
        body = map_body[t - (t / maps) * maps]
        boundary_v[slot - first_moving] = rigid_velocity(velocity[body], angular_velocity[body],
                                                         boundary_x[slot] - position[body])


@wp.kernel
def add_map_neighbours(
    boundary_volume: wp.array(dtype=float),
    maps: int,
    first: int,
    fill: int,
    rows: wp.array(dtype=wp.int32),
    neighbours: wp.array(dtype=wp.int32),
):
    """Each fluid particle's own boundary points (volume > 0) in its boundary neighbour list (slots first + i maps + m):
    with ``fill == 0`` added to the count ``rows[i]`` (before the scan), with ``fill != 0`` written at the end of its
    row (after ``find_neighbours`` filled the samples)."""
    i = wp.tid()
    n = int(0)
    for m in range(maps):
        if boundary_volume[first + i * maps + m] > 0.0:
            n += 1
    if fill == 0:
        rows[i] = rows[i] + n
        return
    k = rows[i + 1] - n
    for m in range(maps):
        slot = first + i * maps + m
        if boundary_volume[slot] > 0.0:
            neighbours[k] = slot
            k += 1

