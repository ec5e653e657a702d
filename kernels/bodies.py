"""Moving boundaries: kinematic and dynamic rigid bodies carrying Akinci boundary samples."""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def place_body_samples(
    local: wp.array(dtype=wp.vec3),
    sample_body: wp.array(dtype=wp.int32),
    rotation: wp.array(dtype=wp.mat33),
    position: wp.array(dtype=wp.vec3),
    velocity: wp.array(dtype=wp.vec3),
    angular_velocity: wp.array(dtype=wp.vec3),
    first: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
):
    """Sample s of the moving bodies (boundary sample first + s) at its body's pose: x = c + R p
    (p in body space, about the body's reference point c) and the rigid velocity
    v = v_c + omega x (x - c) that the divergence and density solvers see at the boundary."""
    s = wp.tid()
    b = sample_body[s]
    r = rotation[b] * local[s]
    x[first + s] = position[b] + r
    v[s] = velocity[b] + wp.cross(angular_velocity[b], r)


@wp.kernel
def sum_body_impulses(
    impulse: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    sample_body: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    first: int,
    body_count: int,
    totals: wp.array(dtype=wp.vec3),
):
    """Per dynamic body: the linear impulse the fluid gave its samples this step (totals[b]), its
    angular impulse about the centre of mass (totals[body_count + b]) and, in the x of
    totals[2 body_count + b], how many of its samples the fluid touched (a nonzero impulse: the wetted
    samples); the samples' impulses are cleared for the next step."""
    s = wp.tid()
    j = impulse[first + s]
    b = sample_body[s]
    wp.atomic_add(totals, b, j)
    wp.atomic_add(totals, body_count + b, wp.cross(x[first + s] - position[b], j))
    if wp.length_sq(j) > 0.0:
        wp.atomic_add(totals, 2 * body_count + b, wp.vec3(1.0, 0.0, 0.0))
    impulse[first + s] = wp.vec3(0.0)


@wp.kernel
def mark_fluid_clear_of_mesh(
    mesh: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    clearance: float,
    keep: wp.array(dtype=wp.int32),
):
    """keep[i] = 0 where fluid particle i lies inside a closed mesh or within ``clearance`` of it
    (the initial fill must not put fluid inside a body)."""
    i = wp.tid()
    query = wp.mesh_query_point_sign_winding_number(mesh, x[i], 1.0e6)
    if query.result:
        closest = wp.mesh_eval_position(mesh, query.face, query.u, query.v)
        if query.sign < 0.0 or wp.length(x[i] - closest) < clearance:
            keep[i] = 0


@wp.kernel
def measure_body_contacts(
    local: wp.array(dtype=wp.vec3),
    sample_body: wp.array(dtype=wp.int32),
    rotation: wp.array(dtype=wp.mat33),
    position: wp.array(dtype=wp.vec3),
    meshes: wp.array(dtype=wp.uint64),
    closed: wp.array(dtype=wp.int32),
    band: wp.array(dtype=float),
    reach: float,
    body_count: int,
    depth: wp.array(dtype=float),
    push: wp.array(dtype=wp.vec3),
    touch: wp.array(dtype=float),
):
    """Launched over (dynamic body samples, bodies): how deep sample s of body b lies within ``reach`` of body o's
    mesh surface (inside a closed mesh counts from the surface inward). depth[b body_count + o] takes the largest
    such depth, push[b body_count + o] the depth-weighted sum of the world directions that move b out of o, and
    touch[s body_count + o] the sample's own depth (0: not touching), from which the contact's points are chosen.
    A sample up to band[o] short of touching counts as touching, with its depth + band[o] as weight and touch
    (depth takes the true depths only: 0 for a pair that touches in the band alone): a kinematic body's band, so
    that a contact held exactly at the surface (a box pushed along, at the pusher's speed) is not lost to rounding
    every other step; 0 for every other body."""
    s, o = wp.tid()
    b = sample_body[s]
    if b == o:
        return
    x = rotation[b] * local[s] + position[b]
    p = wp.transpose(rotation[o]) * (x - position[o])
    query = wp.mesh_query_point_sign_winding_number(meshes[o], p, 1.0e6)
    if not query.result:
        return
    offset = p - wp.mesh_eval_position(meshes[o], query.face, query.u, query.v)
    distance = wp.length(offset)
    direction = offset / wp.max(distance, 1.0e-9)
    d = reach - distance
    if closed[o] != 0 and query.sign < 0.0:
        d = reach + distance
        direction = -direction
    if d > -band[o]:
        w = d + band[o]
        wp.atomic_max(depth, b * body_count + o, d)
        wp.atomic_add(push, b * body_count + o, w * (rotation[o] * direction))
        touch[s * body_count + o] = w
