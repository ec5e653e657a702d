"""Moving boundaries: kinematic and dynamic rigid bodies carrying Akinci boundary samples."""

import warp as wp

from .particles import Boundary, Neighbours, SymmetricMatrix, separation, symmetric_times
from .pressure import BULK_RELAXATION, clamped
from .sph_kernel import cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})


@wp.func
def rigid_velocity(velocity: wp.vec3, angular_velocity: wp.vec3, arm: wp.vec3):
    """The rigid velocity v + omega x arm at the point ``arm`` (x - c) from a body's centre c."""
    return velocity + wp.cross(angular_velocity, arm)


@wp.func
def add_sample_impulse(j: wp.vec3, arm: wp.vec3, b: int, body_count: int, totals: wp.array(dtype=wp.vec3)):
    """Adds a sample's impulse ``j`` (at ``arm`` = x - c from its body b's centre) to the body's sums: the linear
    impulse totals[b], the angular one about the centre totals[body_count + b], and one wetted sample (a nonzero
    impulse) in the x of totals[2 body_count + b]."""
    wp.atomic_add(totals, b, j)
    wp.atomic_add(totals, body_count + b, wp.cross(arm, j))
    if wp.length_sq(j) > 0.0:
        wp.atomic_add(totals, 2 * body_count + b, wp.vec3(1.0, 0.0, 0.0))


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
    v[s] = rigid_velocity(velocity[b], angular_velocity[b], r)


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
    add_sample_impulse(j, x[first + s] - position[b], b, body_count, totals)
    impulse[first + s] = wp.vec3(0.0)


@wp.kernel
def sum_coupling_impulses(
    impulse: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    sample_body: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    first: int,
    body_count: int,
    totals: wp.array(dtype=wp.vec3),
):
    """Inside the pressure solves (strong coupling, :func:`update_body_velocities`): the impulses the fluid has given
    each dynamic body's samples so far this step, summed as :func:`sum_body_impulses` sums them (into ``totals``,
    zero before: :func:`update_body_velocities` clears it), the samples' impulses kept for the step's end."""
    s = wp.tid()
    b = sample_body[s]
    add_sample_impulse(impulse[first + s], x[first + s] - position[b], b, body_count, totals)


# most dynamic bodies one fluid particle's support takes into the strong coupling's stiffness (a fourth one pushes
# and is pushed, but its response to the others' motion is left out of :func:`measure_body_response`)
MAX_BODIES_PER_PARTICLE = wp.constant(3)


@wp.func
def responds(stiffness: float, is_clamped: bool):
    """Whether a fluid particle's Jacobi stiffness follows a body's velocity (:func:`measure_body_response`):
    where it is signed, or clamped (p >= 0) and pushing."""
    return (not is_clamped) or stiffness > 0.0


@wp.func
def response_coefficient(is_clamped: bool, factor: float, dt: float):
    """-dk_i / d(g_i . delta): how much a Jacobi stiffness k_i = omega s_i factor_i / scale drops as the bodies'
    velocities change by delta (the source changes by -dt g_i . delta in the density solve, scale dt^2, and by
    -g_i . delta in the divergence solve, scale dt: omega factor_i / dt in both)."""
    omega = BULK_RELAXATION
    if is_clamped:
        omega = 1.0
    return omega * factor / dt


@wp.func
def body_sample_gradient(i: int, b: int, xi: wp.vec3, nb: Neighbours, boundary: Boundary,
                         correction: wp.array(dtype=SymmetricMatrix), support_radius: float):
    """V_b L_i grad W_ib: the pressure apply's boundary term of sample b for fluid particle i, and minus its
    source's derivative by the sample's velocity (kernels/pressure.py apply_pressure_acceleration,
    corrected_density_rate; L_i the identity outside the bulk)."""
    return boundary.volume[b] * symmetric_times(correction[i], cubic_kernel_gradient(separation(nb, xi, boundary.x[b]),
                                                                                    support_radius))


@wp.kernel
def measure_body_response(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    correction: wp.array(dtype=SymmetricMatrix),
    stiffness: wp.array(dtype=float),
    factor: wp.array(dtype=float),
    surface: wp.array(dtype=wp.int32),
    free_surface: wp.array(dtype=wp.int32),
    sample_body: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    support_radius: float,
    dt: wp.array(dtype=float),
    body_count: int,
    trial: wp.array(dtype=wp.vec3),
    response: wp.array(dtype=wp.mat33),
):
    """Strong coupling, before a Jacobi iteration's pressure apply (Gissler et al. 2019: the rigid bodies inside the
    fluid's pressure solve; the reaction is Akinci et al. 2012's). Per fluid particle i and dynamic body B its
    support reaches: g_i = (G_i, R_i), G_i = sum_b V_b L_i grad W_ib over B's samples and R_i = sum_b (x_b - c_B) x
    V_b L_i grad W_ib. The iteration's stiffness k_i would give B the impulse dt k_i g_i (``trial``, per unit fluid
    mass: linear rows, then angular), and k_i drops by c_i g_i . delta as B's velocity (linear and angular) changes
    by delta (:func:`response_coefficient`): the fluid's stiffness against B's motion, K_B = sum_i dt c_i g_i g_i^T
    (``response``: the blocks GG, GR and RR of each body, 3 a body), over the particles that :func:`responds`.
    Each particle takes one body at a time, lowest index first (up to MAX_BODIES_PER_PARTICLE)."""
    i = wp.tid()
    xi = x[i]
    ki = stiffness[i]
    is_clamped = clamped(surface[i], free_surface)
    c = response_coefficient(is_clamped, factor[i], dt[0])
    previous = int(-1)
    for _p in range(MAX_BODIES_PER_PARTICLE):
        body = int(body_count)
        for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
            b = nb.boundary[k]
            if b >= boundary.first_dynamic:
                o = sample_body[b - boundary.first_dynamic]
                if o > previous and o < body:
                    body = o
        if body == body_count:
            return
        g = wp.vec3(0.0)
        r = wp.vec3(0.0)
        for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
            b = nb.boundary[k]
            if b >= boundary.first_dynamic:
                if sample_body[b - boundary.first_dynamic] == body:
                    gb = body_sample_gradient(i, b, xi, nb, boundary, correction, support_radius)
                    g += gb
                    r += wp.cross(boundary.x[b] - position[body], gb)
        wp.atomic_add(trial, body, dt[0] * ki * g)
        wp.atomic_add(trial, body_count + body, dt[0] * ki * r)
        if responds(ki, is_clamped):  # the impulse dt dk_i g_i = -dt c_i g_i (g_i . delta)
            wp.atomic_add(response, 3 * body, dt[0] * c * wp.outer(g, g))
            wp.atomic_add(response, 3 * body + 1, dt[0] * c * wp.outer(g, r))
            wp.atomic_add(response, 3 * body + 2, dt[0] * c * wp.outer(r, r))
        previous = body


@wp.kernel
def solve_body_response(
    trial: wp.array(dtype=wp.vec3),
    response: wp.array(dtype=wp.mat33),
    inverse_mass: wp.array(dtype=float),
    inertia: wp.array(dtype=wp.mat33),
    particle_mass: float,
    first_body: int,
    body_count: int,
    delta: wp.array(dtype=wp.vec3),
):
    """One thread per dynamic body (from ``first_body``): the velocity change delta = (dv, dw) the iteration gives
    it, with the fluid's stiffness against its motion (:func:`measure_body_response`) taken in: Newton's law for the
    iteration's impulse as the fluid's pressures answer it, [[M + K_GG, K_GR], [K_GR^T, I + K_RR]] (dv, dw) = (J, L)
    (J, L: the trial impulse and its moment; K in units of the fluid particle's mass; I the world inertia tensor),
    by elimination of dv. A Jacobi iteration that left the body out of each particle's diagonal had every wetted
    particle push it as if alone: a body lighter than the fluid it touches (the added-mass instability) overshot,
    and the clamped pressure (p >= 0) could not take it back (a box of density 20 thrown at 1 m/s into still water
    left it at 2.4 m/s). ``trial`` and ``response`` are cleared for the next iteration."""
    k = first_body + wp.tid()
    m = particle_mass
    a = (1.0 / inverse_mass[k]) * wp.identity(3, dtype=float) + m * response[3 * k]
    bgr = m * response[3 * k + 1]
    d = inertia[k] + m * response[3 * k + 2]
    j = m * trial[k]
    l = m * trial[body_count + k]
    a_inv = wp.inverse(a)
    schur = d - wp.transpose(bgr) * a_inv * bgr
    dw = wp.inverse(schur) * (l - wp.transpose(bgr) * (a_inv * j))
    dv = a_inv * (j - bgr * dw)
    delta[k] = dv
    delta[body_count + k] = dw
    trial[k] = wp.vec3(0.0)
    trial[body_count + k] = wp.vec3(0.0)
    response[3 * k] = wp.mat33(0.0)
    response[3 * k + 1] = wp.mat33(0.0)
    response[3 * k + 2] = wp.mat33(0.0)


@wp.kernel
def correct_body_stiffness(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    correction: wp.array(dtype=SymmetricMatrix),
    factor: wp.array(dtype=float),
    surface: wp.array(dtype=wp.int32),
    free_surface: wp.array(dtype=wp.int32),
    sample_body: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3),
    support_radius: float,
    dt: wp.array(dtype=float),
    body_count: int,
    stiffness: wp.array(dtype=float),
):
    """Each fluid particle's Jacobi stiffness as the bodies' velocities change by :func:`solve_body_response`'s
    delta: k_i -= c_i sum_b V_b L_i grad W_ib . (dv + dw x (x_b - c)) over its dynamic samples, where it
    :func:`responds` (kept >= 0 where clamped), so that the apply hands the bodies the impulse their delta took in."""
    i = wp.tid()
    ki = stiffness[i]
    is_clamped = clamped(surface[i], free_surface)
    if not responds(ki, is_clamped):
        return
    xi = x[i]
    change = float(0.0)
    touched = int(0)
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        if b >= boundary.first_dynamic:
            o = sample_body[b - boundary.first_dynamic]
            gb = body_sample_gradient(i, b, xi, nb, boundary, correction, support_radius)
            change += wp.dot(gb, delta[o] + wp.cross(delta[body_count + o], boundary.x[b] - position[o]))
            touched = 1
    if touched == 0:
        return
    k_new = ki - response_coefficient(is_clamped, factor[i], dt[0]) * change
    if is_clamped:
        k_new = wp.max(k_new, 0.0)
    stiffness[i] = k_new


@wp.kernel
def update_body_velocities(
    totals: wp.array(dtype=wp.vec3),
    start_velocity: wp.array(dtype=wp.vec3),
    start_angular_velocity: wp.array(dtype=wp.vec3),
    inverse_mass: wp.array(dtype=float),
    inverse_inertia: wp.array(dtype=wp.mat33),
    reach: wp.array(dtype=float),
    particle_mass: float,
    gravity: wp.vec3,
    gravity_weight: float,
    dt: wp.array(dtype=float),
    first_body: int,
    body_count: int,
    lag: wp.array(dtype=wp.vec3),
    velocity: wp.array(dtype=wp.vec3),
    angular_velocity: wp.array(dtype=wp.vec3),
    residual: wp.array(dtype=float),
):
    """One thread per dynamic body (from ``first_body``), after each pressure apply of the solves (and at their
    start): the body's velocity under the fluid's reactions so far this step, Newton's law M (v - v_n) = J + M g dt,
    I (omega - omega_n) = L (J, L: the impulse and its moment about the centre, :func:`sum_coupling_impulses`, per
    unit fluid mass), for the next iteration's source (strong coupling, Gissler et al. 2019; Akinci et al. 2012,
    eq. 9-10, the reaction). Gravity enters whole (``gravity_weight`` 1 in the density solve, after the fluid's own
    g dt; 0 in the divergence solve), so a body in air (J = 0) falls at g. ``lag`` keeps the impulse's share
    (J / M, I^-1 L); its change, the spin's times the body's ``reach`` (its farthest sample), goes to
    ``residual[0]`` (the largest over the bodies), which keeps the solve iterating while a body still moves
    (kernels/pressure.py update_solver_status). ``totals`` is cleared for the next sum."""
    k = first_body + wp.tid()
    u = particle_mass * inverse_mass[k] * totals[k]
    w = particle_mass * (inverse_inertia[k] * totals[body_count + k])
    wp.atomic_max(residual, 0, wp.max(wp.length(u - lag[k]), reach[k] * wp.length(w - lag[body_count + k])))
    lag[k] = u
    lag[body_count + k] = w
    velocity[k] = start_velocity[k] + gravity_weight * dt[0] * gravity + u
    angular_velocity[k] = start_angular_velocity[k] + w
    totals[k] = wp.vec3(0.0)
    totals[body_count + k] = wp.vec3(0.0)
    totals[2 * body_count + k] = wp.vec3(0.0)


@wp.kernel
def place_body_velocities(
    local: wp.array(dtype=wp.vec3),
    sample_body: wp.array(dtype=wp.int32),
    rotation: wp.array(dtype=wp.mat33),
    velocity: wp.array(dtype=wp.vec3),
    angular_velocity: wp.array(dtype=wp.vec3),
    first: int,
    v: wp.array(dtype=wp.vec3),
):
    """The rigid velocity v_c + omega x R p of each dynamic body's sample s (``v[first + s]``, the moving samples'
    velocities) from the body velocities of :func:`update_body_velocities`: the velocity the next Jacobi
    iteration's source sees at the boundary (the samples stay where :func:`place_body_samples` put them)."""
    s = wp.tid()
    b = sample_body[s]
    v[first + s] = rigid_velocity(velocity[b], angular_velocity[b], rotation[b] * local[s])


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
