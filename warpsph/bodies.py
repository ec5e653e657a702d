"""Rigid bodies as boundaries: static, kinematic (prescribed motion) and dynamic (two-way coupled).

Every body is a mesh sampled once at the particle spacing (Akinci et al. 2012). Static samples
never move. A moving body keeps its samples in body space, about a reference point (the spin
centre of a kinematic body, the centre of mass of a dynamic one); each step the samples are
placed at the body's pose with the rigid velocity v + omega x r, and the boundary cell grid is
rebuilt. Dynamic bodies receive the equal and opposite pressure impulses of the fluid (gathered
by the solvers' kernels), gravity, and contact with the domain walls, integrated on the host
(a handful of numbers per body and step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from warpsph import sampling
from warpsph.errors import SceneError
from warpsph.kernels.bodies import (
    correct_body_stiffness,
    measure_body_contacts,
    measure_body_response,
    place_body_samples,
    place_body_velocities,
    solve_body_response,
    sum_body_impulses,
    sum_coupling_impulses,
    update_body_velocities,
)
from warpsph.scene import Motion, Obstacle

BODY_INSET = 1.2  # particle radii between a closed mesh's surface and its samples (as the domain walls' offset)
# Explicit (partitioned) coupling is unstable for bodies lighter than the fluid they push around
# (the added-mass instability): a box of density 500 settling in water bounced out of it at 0.6 m/s
# after 0.4 s. Each step's acceleration is therefore relaxed towards the last one by the added mass
# m_a = ADDED_MASS rho0 V w (w: the share of the body's samples the fluid touched this step):
# (M + m_a) a = F_fluid + M g + m_a a_last. Gravity acts on the true mass, equilibria (a = 0) are
# unchanged, and a body in air (w = 0) falls at g. That lag drops momentum whenever the wetted share changes (a box
# of density 50 thrown into water rebounded and box + fluid gained 1.5 times its momentum): with a solver that
# couples the bodies inside its pressure iterations (``PressureSolver.couples_bodies``: DFSPH) the relaxation acts
# there instead, on the iterate of the body's velocity (:meth:`MovingBodies.couple`), and the step ends on Newton's
# law with the step's whole impulse (momentum exact); the lagged form stays for the others (IISPH).
ADDED_MASS = 1.0
STATE_COLUMNS = 24  # a dynamic body's state row: position 3, rotation 9, velocity 3, angular velocity 3,
# acceleration 3, angular acceleration 3 (float64: the bodies step in float64, and a resume must be bit-identical)
# The contacts' accumulated impulses a step hands to the next (:meth:`PointContact.remember`), one contact point a
# row: kind (0 wall, 1 body; -1 unused), two indices, the wall's side, the point and the tangential impulse in the
# body's frame, the normal impulse. Rows past the room are dropped (those points start cold).
CONTACT_MEMORY_ROWS = 4096
CONTACT_MEMORY_COLUMNS = 11
WALL_FRICTION = 0.5  # without a friction coefficient: the share of its tangential velocity and spin a dynamic body
# keeps per step in contact (dt-dependent, no Coulomb law: the behaviour before ``dynamics.friction``)
REST_SPEED = 2.0  # x |g| dt: a contact approaching slower than this comes to rest (no bounce): gravity's two steps
# Gauss-Seidel sweeps over all of a step's contact points (walls and bodies together, accumulated clamped impulses),
# until no sweep changes a velocity by CONTACT_TOLERANCE m/s. Solving each contact once, in turn, left a stack moving:
# the box on top pushed the one under it back into the floor, which nothing stopped again (at rest in position, the
# projections held them, but at g dt for two boxes and 3 g dt for three in velocity: the boundary velocity the fluid
# sees). Each contact starts from its last step's impulses (:meth:`PointContact.warm_start`): a resting stack then
# takes one to a few sweeps; cold, the chain converges slowly (two boxes with friction: ~55 sweeps to 1e-5 m/s).
CONTACT_SWEEPS = 30
CONTACT_TOLERANCE = 1.0e-7
CONTACT_DIRECTIONS = 8  # a body-body contact's points: its touching samples farthest along 8 directions in the plane
# [particle radii] a dynamic body's sample this close to touching a kinematic body counts as touching it: a box pushed
# along the floor by a kinematic paddle is left exactly at the paddle's surface, and moves on with it, so without a
# band the float32 depth (+-2e-8 m) found the contact every other step only (the floor's friction slowed the box by
# mu g dt in between, and a contact of 1 or 2 of its 4 points spun it). Far above the rounding, far below a radius.
KINEMATIC_CONTACT_BAND = 1.0e-3


def contact_coefficients(body, other, both):
    """(restitution, friction) of a contact of dynamic ``body`` with ``other`` (``both``: also dynamic): the body's
    own against walls and non-dynamic bodies; between two dynamic bodies sqrt(e_a e_b) and the mean of the given
    friction coefficients (None when neither has one: the per-step damping, WALL_FRICTION)."""
    d = body.obstacle.dynamics
    e, mu = float(d.restitution), d.friction
    if both:
        o = other.obstacle.dynamics
        e = float(np.sqrt(e * o.restitution))
        given = [m for m in (d.friction, o.friction) if m is not None]
        mu = float(np.mean(given)) if given else None
    return e, mu


def _cross_matrix(a):
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _cross(a, b):
    """a x b of two 3-vectors (np.cross's axis handling costs ten times the product in the contact sweeps)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


class PointContact:
    """A contact of dynamic ``body`` with ``other`` (dynamic when ``both``, else fixed: a wall or a static or
    kinematic body) at several contact ``points``, ``normal`` out of the other into the body: a face or an edge
    resting on a face needs its corners, as one point at their centre cannot hold a torque (a sliding box rocked on
    the floor; a box resting off-centre on another turned about the point and fell off). Sequential impulses with
    accumulated, clamped sums (:meth:`sweep`, Gauss-Seidel): each point that approaches faster than ``rest_speed``
    is to leave at -restitution times its normal speed, a slower one to rest; the accumulated normal impulse stays
    >= 0 and, with a ``friction`` coefficient, each point's tangential one within friction times it (Coulomb;
    None: normal impulses only); a point ``slack`` > 0 dt short of the other (a corner in the band, not yet down)
    may approach at up to that speed. The impulse J on the body is -J on a dynamic other (momentum-conserving). A
    kinematic other has infinite mass and moves: each point's relative velocity is taken against the other's rigid
    velocity there, v + omega x (x - c), from its prescribed motion at this step's pose (issue #39: it acted as if at
    rest, so a plate lifting a box or a paddle pushing one moved it by the position projections alone, at rest)."""

    def __init__(self, body, other, both, normal, points, restitution, friction, rest_speed, slack=None):
        self.body, self.other, self.both = body, other, both
        self.normal, self.friction = normal, friction
        self.inv = 1.0 / body.mass
        self.inv_i = np.linalg.inv(body.rotation @ body.inertia @ body.rotation.T)
        self.arms = np.asarray(points, np.float64) - body.position
        k = [self.inv * np.eye(3) - _cross_matrix(r) @ self.inv_i @ _cross_matrix(r) for r in self.arms]
        if both:
            self.inv_other = 1.0 / other.mass
            self.inv_i_other = np.linalg.inv(other.rotation @ other.inertia @ other.rotation.T)
            self.arms_other = np.asarray(points, np.float64) - other.position
            k = [m + self.inv_other * np.eye(3) - _cross_matrix(r) @ self.inv_i_other @ _cross_matrix(r)
                 for m, r in zip(k, self.arms_other)]
        else:
            self.inv_other = 0.0
        # a kinematic other's velocity at each point (None: a wall or a static body, at rest)
        self.other_velocity = None
        if other is not None and not both and other.kind == "kinematic":
            self.other_velocity = [rigid_velocity(other, x - other.position) for x in np.asarray(points, np.float64)]
        self.masses = k  # K: a point's relative velocity change per unit impulse (dv = inv J + (I^-1 (r x J)) x r)
        v_n = np.array([float(self.velocity(p) @ normal) for p in range(len(self.arms))])
        self.target = np.where(-v_n > rest_speed, -restitution * v_n, 0.0)
        if slack is not None:  # a point still ``slack`` dt away may approach at up to that speed (speculative)
            self.target = np.where(slack > 0.0, -slack, self.target)
        self.normal_sum = np.zeros(len(self.arms))
        self.tangent_sum = np.zeros((len(self.arms), 3))
        self.key = None  # which contact this is, from step to step (:meth:`MovingBodies.integrate`'s warm start)

    def warm_start(self, last, merge):
        """Starts from the accumulated impulses of the same contact's last step (``last``: :meth:`remember`) at each
        point within ``merge`` of one of its points (in the body's frame), applied now: a resting contact's are nearly
        this step's and the sweeps only correct them (cold, a stack of two with friction needed ~55 sweeps and kept
        turning at 1e-3 rad/s after 30). The clamps still hold: a sweep may take the started impulse back to 0."""
        if last is None:
            return
        local_last, normal_last, tangent_last = last
        rotation, normal = self.body.rotation, self.normal
        for p, x in enumerate(self.arms @ rotation):
            distance = np.linalg.norm(local_last - x, axis=1)
            q = int(np.argmin(distance))
            if distance[q] >= merge:
                continue
            self.normal_sum[p] = normal_last[q]
            if self.friction is not None:
                t = rotation @ tangent_last[q]
                t = t - float(t @ normal) * normal
                size, limit = float(np.linalg.norm(t)), self.friction * normal_last[q]
                self.tangent_sum[p] = t * (limit / size) if size > limit else t
            self._apply(p, self.normal_sum[p] * normal + self.tangent_sum[p])

    def remember(self):
        """(points in the body's frame, normal and tangential impulse sums) for the next step's :meth:`warm_start`."""
        rotation = self.body.rotation
        return self.arms @ rotation, self.normal_sum.copy(), self.tangent_sum @ rotation

    def velocity(self, p):
        """Point p's velocity on the body relative to the other."""
        b = self.body
        v = rigid_velocity(b, self.arms[p])
        if self.both:
            v = v - rigid_velocity(self.other, self.arms_other[p])
        elif self.other_velocity is not None:
            v = v - self.other_velocity[p]
        return v

    def _apply(self, p, j):
        b = self.body
        b.velocity = b.velocity + self.inv * j
        b.angular_velocity = b.angular_velocity + self.inv_i @ _cross(self.arms[p], j)
        if self.both:
            o = self.other
            o.velocity = o.velocity - self.inv_other * j
            o.angular_velocity = o.angular_velocity - self.inv_i_other @ _cross(self.arms_other[p], j)

    def sweep(self, backwards=False):
        """One Gauss-Seidel pass over the points (``backwards``: last first); returns the largest impulse's velocity
        change [m/s]."""
        normal, change, scale = self.normal, 0.0, self.inv + self.inv_other
        order = range(len(self.masses) - 1, -1, -1) if backwards else range(len(self.masses))
        for p in order:
            k = self.masses[p]
            v = self.velocity(p)
            new = max(self.normal_sum[p] + (self.target[p] - float(v @ normal)) / float(normal @ k @ normal), 0.0)
            self._apply(p, (new - self.normal_sum[p]) * normal)
            change = max(change, abs(new - self.normal_sum[p]) * scale)
            self.normal_sum[p] = new
            if self.friction is None:
                continue
            v = self.velocity(p)
            slip = v - float(v @ normal) * normal
            s = float(np.linalg.norm(slip))
            if s == 0.0:
                continue
            t = slip / s
            want = self.tangent_sum[p] - s / float(t @ k @ t) * t
            limit = self.friction * self.normal_sum[p]
            size = float(np.linalg.norm(want))
            if size > limit:
                want = want * (limit / size)
            self._apply(p, want - self.tangent_sum[p])
            change = max(change, float(np.linalg.norm(want - self.tangent_sum[p])) * scale)
            self.tangent_sum[p] = want
        return change


def rigid_velocity(body, arm):
    """The rigid velocity v + omega x arm of ``body`` at the point ``arm`` (x - c, world axes) from its centre; a
    kinematic body's at its current pose (its prescribed motion at this step, :meth:`MovingBodies.place`)."""
    return body.velocity + _cross(body.angular_velocity, arm)


def solve_contacts(contacts):
    """Sweeps every contact's points in turn (:meth:`PointContact.sweep`) up to CONTACT_SWEEPS times, until no
    impulse changes a velocity by CONTACT_TOLERANCE; returns the sweeps made."""
    for n in range(CONTACT_SWEEPS):
        backwards = n % 2 == 1  # alternately forwards and backwards (symmetric): a fixed order biased the residual
        change = max((c.sweep(backwards) for c in (contacts[::-1] if backwards else contacts)), default=0.0)
        if change < CONTACT_TOLERANCE:
            return n + 1
    return CONTACT_SWEEPS


def contact_points(points, normal, merge, directions=CONTACT_DIRECTIONS):
    """The few of ``points`` (a contact's touching samples) that span them in the plane normal to ``normal``:
    the farthest along ``directions`` directions (a face's corners; an edge's ends; ties broken towards the next
    direction), less those within ``merge`` of one already chosen in the plane (the same corner from both bodies'
    samples: a doubled point slowed the sweeps' convergence)."""
    points = np.asarray(points, np.float64)
    t1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    angles = 2.0 * np.pi * np.arange(directions) / directions
    u, w = points @ t1, points @ t2
    chosen = []
    for a in angles:
        p = int(np.argmax(u * np.cos(a) + w * np.sin(a) + 1.0e-3 * (w * np.cos(a) - u * np.sin(a))))
        if all(np.hypot(u[p] - u[q], w[p] - w[q]) >= merge for q in chosen):
            chosen.append(p)
    return points[chosen]


def orthonormalize(rotation):
    u, _, vt = np.linalg.svd(rotation)
    return u @ vt


@dataclass
class RigidBody:
    """One body: its mesh and samples in body space (about ``reference``, its world position at
    the placement) and, while it moves, its pose."""

    name: str
    obstacle: Obstacle
    vertices: np.ndarray  # mesh vertices in body space
    faces: np.ndarray
    samples: np.ndarray  # boundary samples in body space
    reference: np.ndarray  # world position of the body-space origin at the placement
    mass: float = 0.0
    added_mass: float = 0.0  # ADDED_MASS x the mass of fluid the body displaces when wholly wetted
    # the last step's linear and angular acceleration (the added-mass relaxation's lag)
    acceleration: np.ndarray = None
    angular_acceleration: np.ndarray = None
    inertia: np.ndarray = None  # body-space inertia tensor about the centre of mass
    # pose and rigid velocity (world)
    position: np.ndarray = None
    rotation: np.ndarray = None
    velocity: np.ndarray = None
    angular_velocity: np.ndarray = None

    closed: bool = False  # a watertight mesh: it has an inside (no fluid there, samples inset)
    inset: float = BODY_INSET  # the samples' distance inside the surface [particle radii]; negative: outside
    # a dynamic body that holds the fluid by a volume map (warpsph.volume_maps): the map's thickness [m]; None: by its
    # samples (then only for its contacts)
    volume_map: float = None

    @property
    def kind(self):
        o = self.obstacle
        return "dynamic" if o.dynamics is not None else "kinematic" if o.motion is not None else "static"

    def to_world(self, points):
        """Body-space points at the body's current pose."""
        return points @ self.rotation.T + self.position

    def world_samples(self):
        return self.to_world(self.samples).astype(np.float32)


def sample_offset_vertices(mesh, distance):
    """A closed mesh's vertices moved ``distance`` inwards (``sampling.inset_vertices``), or -distance
    outwards where it is negative (the least-squares offset is linear in the distance: v - (inset(v, d) - v))."""
    if distance >= 0.0:
        return sampling.inset_vertices(mesh, distance)
    return 2.0 * np.asarray(mesh.vertices, np.float64) - sampling.inset_vertices(mesh, -distance)


def load_body(obstacle: Obstacle, path, spacing, domain_size, default_name, fluid_density=1000.0,
              inset=BODY_INSET) -> RigidBody:
    """Samples an obstacle's mesh at its placement (scale, rotate, translate) and expresses it in
    body space; a dynamic body gets mass and inertia from its closed mesh and density. ``inset``: the
    samples' distance inside a closed mesh's surface [particle radii] (negative: outside), BODY_INSET
    unless an importer matches another code's boundary (``Conversion.body_insets``)."""
    mesh = sampling.place_mesh(obstacle, path, spacing, domain_size)
    kind = "dynamic" if obstacle.dynamics is not None else "kinematic" if obstacle.motion is not None else "static"
    reference = np.zeros(3)
    mass, added_mass, inertia = 0.0, 0.0, None
    if kind == "kinematic":
        m: Motion = obstacle.motion
        reference = np.asarray(m.center if m.center is not None else mesh.bounds.mean(axis=0), np.float64)
    elif kind == "dynamic":
        if not mesh.is_watertight or mesh.volume <= 0.0:
            raise SceneError(path, "dynamics", "a dynamic body needs a closed mesh (its volume gives mass and inertia)")
        density = obstacle.dynamics.density
        reference = np.asarray(mesh.center_mass, np.float64)
        mass = density * float(mesh.volume)
        added_mass = ADDED_MASS * fluid_density * float(mesh.volume)
        mesh.density = 1.0
        inertia = density * np.asarray(mesh.moment_inertia, np.float64)  # about the centre of mass
    offset = sample_offset_vertices(mesh, inset * 0.5 * spacing)
    samples = sampling.sample_triangles(offset, mesh.faces, spacing).astype(np.float64) - reference
    body = RigidBody(name=obstacle.name or default_name, obstacle=obstacle,
                     vertices=np.asarray(mesh.vertices, np.float64) - reference, faces=np.asarray(mesh.faces, np.int32),
                     samples=samples, reference=reference, closed=bool(mesh.is_watertight), mass=mass, added_mass=added_mass, inertia=inertia,
                     position=reference.copy(), rotation=np.eye(3), velocity=np.zeros(3), angular_velocity=np.zeros(3),
                     acceleration=np.zeros(3), angular_acceleration=np.zeros(3),
                     inset=float(inset) if mesh.is_watertight else 0.0)
    if kind == "dynamic":
        body.velocity = np.asarray(obstacle.dynamics.velocity, np.float64)
        body.angular_velocity = np.asarray(obstacle.dynamics.angular_velocity, np.float64)
    return body


def _spin(m: Motion, t):
    """Spin angle and rate at time t: zero before spin_start, ramped linearly up over spin_up and, from
    spin_end on, down to rest over spin_down; or following spin_rates."""
    if m.spin_rates:
        angle, rate = _spin_rates(m, t)
        return angle - _spin_rates(m, 0.0)[0], rate
    if m.spin_end is not None and t > m.spin_end:
        angle, rate = _spin_up(m, m.spin_end)
        tau = min(t - m.spin_end, m.spin_down)
        slowed = rate * (1.0 - tau / m.spin_down) if t - m.spin_end < m.spin_down else 0.0
        return angle + 0.5 * (rate + slowed) * tau, slowed
    return _spin_up(m, t)


def _spin_up(m: Motion, t):
    """Spin angle and rate at time t of a spin that never stops."""
    tau = t - m.spin_start
    if tau <= 0.0 or m.angular_velocity == 0.0:
        return 0.0, 0.0
    w = m.angular_velocity
    if tau < m.spin_up:
        return 0.5 * w * tau * tau / m.spin_up, w * tau / m.spin_up
    return w * (tau - 0.5 * m.spin_up), w


def _area(rates, times):
    """The trapezoid rule's integral of ``rates`` over ``times`` (numpy's trapezoid needs numpy 2)."""
    return float(np.sum(0.5 * (rates[1:] + rates[:-1]) * np.diff(times)))


def _spin_rates(m: Motion, t):
    """(integral of the rate from the first time to t, rate at t) of spin_rates: the rate linear between entries, held
    before the first and after the last; with spin_repeat, periodic from the first time on (period last - first)."""
    times = np.array([s.time for s in m.spin_rates], np.float64)
    rates = np.array([s.rate for s in m.spin_rates], np.float64)
    if t <= times[0]:
        return float(rates[0] * (t - times[0])), float(rates[0])
    turns = 0.0
    if m.spin_repeat:
        period = times[-1] - times[0]
        turns, rest = divmod(t - times[0], period)
        t = times[0] + rest
    elif t >= times[-1]:
        return _area(rates, times) + float(rates[-1] * (t - times[-1])), float(rates[-1])
    n = int(np.searchsorted(times, t, side="right")) - 1
    rate = rates[n] + (rates[n + 1] - rates[n]) * (t - times[n]) / (times[n + 1] - times[n])
    partial = _area(rates[:n + 1], times[:n + 1]) + 0.5 * (rates[n] + rate) * (t - times[n])
    return float(turns * _area(rates, times) + partial), float(rate)


def _keyframed(m: Motion, t):
    """Offset and velocity of the keyframed path at time t (linear between keyframes, held outside)."""
    keys = m.keyframes
    if not keys:
        return np.zeros(3), np.zeros(3)
    times = [k.time for k in keys]
    points = [np.asarray(k.translation, np.float64) for k in keys]
    if t <= times[0]:
        return points[0], np.zeros(3)
    if t >= times[-1]:
        return points[-1], np.zeros(3)
    n = int(np.searchsorted(times, t, side="right")) - 1
    slope = (points[n + 1] - points[n]) / (times[n + 1] - times[n])
    return points[n] + slope * (t - times[n]), slope


def kinematic_pose(m: Motion, reference, t):
    """(position, rotation, velocity, angular velocity) of a kinematic body at time t."""
    offset, velocity = _keyframed(m, t)
    stop = np.inf if m.end is None else m.end
    tau = min(t, stop) - m.start
    if tau > 0.0:
        offset = offset + np.asarray(m.velocity) * tau + 0.5 * np.asarray(m.acceleration) * tau**2
        if t < stop:
            velocity = velocity + np.asarray(m.velocity) + np.asarray(m.acceleration) * tau
    angle, rate = _spin(m, t)
    axis = np.asarray(m.axis, np.float64)
    axis = axis / np.linalg.norm(axis) if rate or angle else axis
    return reference + offset, sampling.rotation_matrix(axis, angle), velocity, axis * rate


@dataclass
class BodiesContext:
    """What the moving bodies see of the simulation, and nothing else (no solver, no models, no writers): the state
    (the fluid's arrays and count, dt, the allocation and ``carry`` calls), the constants, the boundary samples
    (which they place and whose impulses they read), the launch call, and two values read when used: the gravity
    (which may change between steps) and the neighbour lists (built after the bodies)."""

    state: object  # warpsph.state.State
    constants: object  # warpsph.state.Constants
    boundary: object  # warpsph.simulation.BoundaryParticles
    launch: object  # (kernel, dim, inputs): on the simulation's device, counted
    gravity: object  # () -> wp.vec3 [m/s^2]: the simulation's gravity now
    neighbour_lists: object  # () -> the kernels' Neighbours struct of this step


class MovingBodies:
    """The moving bodies' samples on the device and their poses; boundary samples from
    ``first_sample`` on are theirs, kinematic bodies first, then dynamic ones. ``ctx``: a :class:`BodiesContext`."""

    def __init__(self, ctx, bodies, first_sample, obstacles=()):
        self.ctx = ctx  # what the bodies see of the simulation (:class:`BodiesContext`)
        self.bodies = bodies
        self.first_sample = first_sample
        counts = [len(b.samples) for b in bodies]
        self.num_samples = sum(counts)
        kinds = [b.kind for b in bodies]
        self.num_kinematic = kinds.count("kinematic")
        self.dynamic = [b for b in bodies if b.kind == "dynamic"]
        dynamic_local = sum(counts[: self.num_kinematic])
        self.first_dynamic = first_sample + dynamic_local
        n = len(bodies)
        self.local = ctx.state.array("bodies", np.concatenate([b.samples for b in bodies]).astype(np.float32), wp.vec3)
        self.sample_body = ctx.state.array("bodies", np.repeat(np.arange(n, dtype=np.int32), counts), wp.int32)
        self._dynamic_sample_body = self.sample_body[dynamic_local:] if self.dynamic else None
        self.rotation = ctx.state.zeros("bodies", n, dtype=wp.mat33)
        self.position = ctx.state.zeros("bodies", n, dtype=wp.vec3)
        self.velocity = ctx.state.zeros("bodies", n, dtype=wp.vec3)
        self.angular_velocity = ctx.state.zeros("bodies", n, dtype=wp.vec3)
        self.totals = ctx.state.zeros("bodies", 3 * n, dtype=wp.vec3)
        self.rotation.assign(np.stack([b.rotation for b in bodies]).astype(np.float32))  # the initial pose (:meth:`place`
        self.position.assign(np.stack([b.position for b in bodies]).astype(np.float32))  # moves it each step)
        self.sample_counts = np.asarray(counts, np.float64)
        # dynamic state for checkpoints and retried frames: position, rotation, velocity, angular velocity,
        # and the last step's accelerations
        self.state = ctx.state.zeros("bodies", (max(len(self.dynamic), 1), STATE_COLUMNS), dtype=wp.float64)
        self.contact_memory = ctx.state.array("bodies", np.full((CONTACT_MEMORY_ROWS if self.dynamic else 1,
                                                           CONTACT_MEMORY_COLUMNS), -1.0), wp.float64)
        self._memory_rows = 0  # rows of contact_memory the last store wrote
        if self.dynamic:
            ctx.state.carry("bodies/state", self.state)
            ctx.state.carry("bodies/contacts", self.contact_memory, optional=True)
        # the last step's contacts' impulses, for the warm start (:meth:`PointContact.warm_start`); checkpointed
        # through ``contact_memory``
        self._warm = {}
        self._store_state()
        self.sweeps = 0  # the last step's contact sweeps (:func:`solve_contacts`)
        # each body's slice of the dynamic samples (the contact kernel's rows)
        starts = np.concatenate([[0], np.cumsum(counts)]) - dynamic_local
        self._dynamic_slices = [slice(int(starts[k]), int(starts[k + 1])) for k in range(n)]
        self._contacts = self._contact_arrays(list(obstacles)) if self.dynamic and n + len(obstacles) > 1 else None
        self.coupling = None  # the strong coupling's arrays (:meth:`start_coupling`), none unless a solver couples
        self.maps = None  # the mapped bodies' volume maps (:meth:`attach_volume_maps`), none unless a body has one
        self._coupled_sample_body = self._dynamic_sample_body  # the dynamic samples' bodies, then the maps' points'

    def attach_volume_maps(self, maps, capacity):
        """The mapped dynamic bodies' volume maps (warpsph.volume_maps.VolumeMaps): their points follow the dynamic
        samples in the boundary slots (their impulses summed with the samples', their velocities placed with them)."""
        self.maps = maps
        dynamic_local = self.first_dynamic - self.first_sample
        parts = [self.sample_body.numpy()[dynamic_local:], np.tile(np.asarray(maps.body_indices, np.int32), capacity)]
        self._coupled_sample_body = self.ctx.state.array("bodies", np.concatenate(parts).astype(np.int32), wp.int32)

    def _coupled_count(self):
        """The dynamic samples and the maps' points of the fluid particles there are now."""
        n = self.num_samples - (self.first_dynamic - self.first_sample)
        return n + (self.ctx.state.num_fluid * self.maps.count if self.maps is not None else 0)

    def start_coupling(self):
        """Allocates the arrays of the strong coupling (:meth:`respond`, :meth:`couple`): the dynamic bodies'
        velocities at the step's start, inverse mass, world inertia and its inverse, reach (the farthest sample), the
        iteration's trial impulse, the fluid's stiffness against each body's motion and the velocity change they give,
        the impulse's share of the velocity (``lag``) and the residual the solve's loop reads. Only for a scene with
        dynamic bodies, whose solver iterates its pressure (``PressureSolver.couples_bodies``)."""
        if not self.dynamic:
            return
        ctx, n = self.ctx, len(self.bodies)
        dynamic = [b.kind == "dynamic" for b in self.bodies]
        self.coupling = {
            "start_velocity": ctx.state.zeros("bodies", n, dtype=wp.vec3),
            "start_angular_velocity": ctx.state.zeros("bodies", n, dtype=wp.vec3),
            "inverse_mass": ctx.state.array("bodies", np.array([1.0 / b.mass if d else 0.0 for b, d in zip(self.bodies, dynamic)],
                                                         np.float32), float),
            "inertia": ctx.state.zeros("bodies", n, dtype=wp.mat33),
            "inverse_inertia": ctx.state.zeros("bodies", n, dtype=wp.mat33),
            "reach": ctx.state.array("bodies", np.array([np.linalg.norm(b.samples, axis=1).max() if d else 0.0
                                                   for b, d in zip(self.bodies, dynamic)], np.float32), float),
            "trial": ctx.state.zeros("bodies", 2 * n, dtype=wp.vec3),
            "response": ctx.state.zeros("bodies", 3 * n, dtype=wp.mat33),
            "delta": ctx.state.zeros("bodies", 2 * n, dtype=wp.vec3),
            "lag": ctx.state.zeros("bodies", 2 * n, dtype=wp.vec3),
            "residual": ctx.state.zeros("bodies", 1),  # the largest velocity change of the last update (the loop reads it)
        }
        self.lag_mismatch = 0.0  # the last step's largest |J / M - lag| [m/s] (:meth:`integrate`)

    def respond(self, stiffness, factor, surface, free_surface, correction):
        """Strong coupling, before a Jacobi iteration's pressure apply: each dynamic body's velocity change under the
        iteration's ``stiffness`` with the fluid's answer to that motion taken in (a block of the coupled system's
        diagonal, :func:`~warpsph.kernels.bodies.solve_body_response`), and the stiffness of the particles beside it
        corrected by it (:func:`~warpsph.kernels.bodies.correct_body_stiffness`). ``factor``, ``surface``,
        ``free_surface``, ``correction``: the solve's. All on the device."""
        c, ctx = self.coupling, self.ctx
        n = len(self.bodies)
        nb, boundary = ctx.neighbour_lists(), ctx.boundary.samples
        ctx.launch(measure_body_response, ctx.state.num_fluid,
                   [ctx.state.fluid.x, nb, boundary, correction, stiffness, factor, surface, free_surface,
                    self._coupled_sample_body, self.position, ctx.constants.support_radius, ctx.state.dt, n, c["trial"], c["response"]])
        ctx.launch(solve_body_response, n - self.num_kinematic,
                   [c["trial"], c["response"], c["inverse_mass"], c["inertia"], ctx.constants.particle_mass, self.num_kinematic, n,
                    c["delta"]])
        ctx.launch(correct_body_stiffness, ctx.state.num_fluid,
                   [ctx.state.fluid.x, nb, boundary, correction, factor, surface, free_surface, self._coupled_sample_body,
                    self.position, c["delta"], ctx.constants.support_radius, ctx.state.dt, n, stiffness])

    def couple(self, gravity_weight):
        """Strong coupling, after a pressure apply (and at a solve's start): the dynamic bodies' velocities under the
        fluid's reactions so far this step (:func:`~warpsph.kernels.bodies.update_body_velocities`; ``gravity_weight``
        1 in the density solve: the step's g dt is in) and their samples' velocities from those, for the next source.
        All on the device, no host read."""
        c, ctx = self.coupling, self.ctx
        n = len(self.bodies)
        dynamic_local = self.first_dynamic - self.first_sample
        count = self.num_samples - dynamic_local
        ctx.launch(sum_coupling_impulses, self._coupled_count(),
                   [ctx.boundary.impulse, ctx.boundary.x, self._coupled_sample_body, self.position, self.first_dynamic,
                    n, self.totals])
        ctx.launch(update_body_velocities, n - self.num_kinematic,
                   [self.totals, c["start_velocity"], c["start_angular_velocity"], c["inverse_mass"],
                    c["inverse_inertia"], c["reach"], ctx.constants.particle_mass, ctx.gravity(), float(gravity_weight), ctx.state.dt,
                    self.num_kinematic, n, c["lag"], self.velocity, self.angular_velocity, c["residual"]])
        ctx.launch(place_body_velocities, count,
                   [self.local[dynamic_local:], self._dynamic_sample_body, self.rotation, self.velocity,
                    self.angular_velocity, dynamic_local, ctx.boundary.v])
        if self.maps is not None:
            self.maps.place_velocities(ctx.launch, ctx.state.num_fluid, self, ctx.boundary)

    def _contact_arrays(self, obstacles):
        """Body-space meshes and poses of every body a dynamic one can touch: the moving bodies (their own
        order), then the static ``obstacles`` (placed once)."""
        ctx, bodies = self.ctx, self.bodies + obstacles
        meshes = [wp.Mesh(points=ctx.state.array("bodies", b.vertices.astype(np.float32), wp.vec3),
                          indices=ctx.state.array("bodies", b.faces.ravel().astype(np.int32), wp.int32)) for b in bodies]
        m = len(bodies)
        return {"bodies": bodies, "meshes": meshes, "count": m,
                "ids": ctx.state.array("bodies", np.array([mesh.id for mesh in meshes], np.uint64), wp.uint64),
                "closed": ctx.state.array("bodies", np.array([int(b.closed) for b in bodies], np.int32), wp.int32),
                "band": ctx.state.array("bodies", np.array([KINEMATIC_CONTACT_BAND * ctx.constants.particle_radius
                                                      if b.kind == "kinematic" else 0.0 for b in bodies], np.float32),
                                  wp.float32),
                "kinematic": np.array([b.kind == "kinematic" for b in bodies]),
                "rotation": ctx.state.array("bodies", np.stack([b.rotation for b in bodies]).astype(np.float32), wp.mat33),
                "position": ctx.state.array("bodies", np.stack([b.position for b in bodies]).astype(np.float32), wp.vec3),
                "depth": ctx.state.zeros("bodies", m * m), "push": ctx.state.zeros("bodies", m * m, dtype=wp.vec3),
                "touch": ctx.state.zeros("bodies", (self.num_samples - (self.first_dynamic - self.first_sample)) * m)}

    # -- poses -------------------------------------------------------------------------------------------
    def place(self, time):
        """Moves every sample to its body's pose at ``time`` (kinematic) or its current state (dynamic)."""
        for body in self.bodies:
            if body.kind == "kinematic":
                body.position, body.rotation, body.velocity, body.angular_velocity = kinematic_pose(
                    body.obstacle.motion, body.reference, time)
        ctx = self.ctx
        self.rotation.assign(np.stack([b.rotation for b in self.bodies]).astype(np.float32))
        self.position.assign(np.stack([b.position for b in self.bodies]).astype(np.float32))
        self.velocity.assign(np.stack([b.velocity for b in self.bodies]).astype(np.float32))
        self.angular_velocity.assign(np.stack([b.angular_velocity for b in self.bodies]).astype(np.float32))
        ctx.launch(place_body_samples, self.num_samples,
                   [self.local, self.sample_body, self.rotation, self.position, self.velocity, self.angular_velocity,
                    self.first_sample, ctx.boundary.x, ctx.boundary.v])
        c = self.coupling
        if c is not None:  # the step's start for the strong coupling (:meth:`couple`)
            c["start_velocity"].assign(self.velocity)
            c["start_angular_velocity"].assign(self.angular_velocity)
            world = [b.rotation @ b.inertia @ b.rotation.T if b.kind == "dynamic" else np.eye(3) for b in self.bodies]
            c["inertia"].assign(np.stack(world).astype(np.float32))
            c["inverse_inertia"].assign(np.stack([np.linalg.inv(i) for i in world]).astype(np.float32))
            c["lag"].zero_()
            self.totals.zero_()  # (the last step's sums, read by :meth:`integrate`)

    def poses(self):
        """{name: (position, rotation)} of every moving body, for the USD writer."""
        return {b.name: (b.position.copy(), b.rotation.copy()) for b in self.bodies}

    # -- two-way coupling -------------------------------------------------------------------------------------
    def integrate(self, dt, gravity, domain_lo, domain_hi, periodic, margin=0.0):
        """Advances every dynamic body by ``dt`` under the fluid's impulses of the step just taken
        (Akinci 2012: equal and opposite to the pressure impulses on the fluid), gravity and the
        domain walls (no penetration, friction). Symplectic Euler; explicit angular update. The step's contacts, walls
        and bodies, are solved together (:func:`solve_contacts`), each starting from its last step's impulses."""
        if not self.dynamic:
            return
        ctx = self.ctx
        n = len(self.bodies)
        rest_speed = REST_SPEED * float(np.linalg.norm(gravity)) * dt
        walls = []  # the touched walls' contacts, solved with the bodies' (:func:`solve_contacts`)
        self.totals.zero_()
        ctx.launch(sum_body_impulses, self._coupled_count(),
                   [ctx.boundary.impulse, ctx.boundary.x, self._coupled_sample_body, self.position, self.first_dynamic, n,
                    self.totals])
        totals = self.totals.numpy().astype(np.float64) * ctx.constants.particle_mass
        lag = self.coupling["lag"].numpy() if self.coupling is not None else None
        self.lag_mismatch = 0.0
        for k, body in enumerate(self.bodies):
            if body.kind != "dynamic":
                continue
            linear, angular = totals[k], totals[n + k]
            inertia_world = body.rotation @ body.inertia @ body.rotation.T
            if lag is not None:  # coupled in the solves (:meth:`couple`): Newton's law with the step's impulse
                body.acceleration = linear / (dt * body.mass) + np.asarray(gravity)
                body.angular_acceleration = np.linalg.solve(inertia_world, angular / dt)
                self.lag_mismatch = max(self.lag_mismatch, float(np.linalg.norm(linear / body.mass - lag[k])))
            else:
                wetted = totals[2 * n + k][0] / ctx.constants.particle_mass / self.sample_counts[k]
                relax = body.mass / (body.mass + wetted * body.added_mass)  # see ADDED_MASS
                body.acceleration = (relax * (linear / (dt * body.mass) + np.asarray(gravity))
                                     + (1.0 - relax) * body.acceleration)
                body.angular_acceleration = (relax * np.linalg.solve(inertia_world, angular / dt)
                                             + (1.0 - relax) * body.angular_acceleration)
            body.velocity = body.velocity + dt * body.acceleration
            body.angular_velocity = body.angular_velocity + dt * body.angular_acceleration
            body.position = body.position + dt * body.velocity
            w = body.angular_velocity
            angle = float(np.linalg.norm(w)) * dt
            if angle > 0.0:
                body.rotation = orthonormalize(sampling.rotation_matrix(w, angle) @ body.rotation)
            own = margin * body.inset / BODY_INSET  # the surface, not the samples, stops at the walls
            walls += self._wall_contact(body, np.add(domain_lo, own), np.subtract(domain_hi, own), periodic,
                                        rest_speed, own, dt)
        contacts = walls + self._body_contact(rest_speed)
        for c in contacts:
            c.warm_start(self._warm.get(c.key), ctx.constants.particle_radius)
        self.sweeps = solve_contacts(contacts)
        self._warm = {c.key: c.remember() for c in contacts}
        self._store_state()

    def _body_contact(self, rest_speed=0.0):
        """Keeps dynamic bodies out of each other and out of every other body (their samples BODY_INSET r
        inside their surface may come no closer than that to another body's surface): each touching pair is
        pushed apart along the depth-weighted direction (by inverse mass between two dynamic bodies) and gets a
        :class:`PointContact` at the touching samples that span the contact (:func:`contact_points`, moved BODY_INSET r
        onto the surfaces), with restitution and Coulomb friction from :func:`contact_coefficients`; without a friction
        coefficient the touching bodies' tangential and angular motion is damped as at a wall. Returns the contacts,
        solved with the walls' by :func:`solve_contacts`."""
        c = self._contacts
        if c is None:
            return []
        ctx, m = self.ctx, c["count"]
        n = len(self.bodies)
        c["rotation"][:n].assign(np.stack([b.rotation for b in self.bodies]).astype(np.float32))
        c["position"][:n].assign(np.stack([b.position for b in self.bodies]).astype(np.float32))
        c["depth"].zero_()
        c["push"].zero_()
        c["touch"].zero_()
        dynamic_local = self.first_dynamic - self.first_sample
        reach = BODY_INSET * ctx.constants.particle_radius
        ctx.launch(measure_body_contacts, (self.num_samples - dynamic_local, m),
                   [self.local[dynamic_local:], self._dynamic_sample_body, c["rotation"], c["position"], c["ids"],
                    c["closed"], c["band"], reach, m, c["depth"], c["push"], c["touch"]])
        depth = c["depth"].numpy().reshape(m, m).astype(np.float64)
        push = c["push"].numpy().reshape(m, m, 3).astype(np.float64)
        kinematic = c["kinematic"]
        # a sample within a kinematic body's band (KINEMATIC_CONTACT_BAND) touches it at depth 0
        banded = np.any(push[:, kinematic], axis=(1, 2))
        if not np.any(depth > 0.0) and not np.any(banded):
            return []
        bodies = c["bodies"]
        # body k's samples where they were measured (the separations below move the bodies) and its rows of touch,
        # read for the bodies whose samples touch another
        touching = {}
        for k, body in enumerate(self.bodies):
            if body.kind == "dynamic" and (np.any(depth[k] > 0.0) or banded[k]):
                rows = self._dynamic_slices[k]
                touching[k] = (body.to_world(body.samples),
                               c["touch"][rows.start * m:rows.stop * m].numpy().reshape(-1, m))

        def touched(k, o):
            """Body k's samples within reach of body o (world)."""
            if k not in touching:
                return np.zeros((0, 3))
            world, touch = touching[k]
            return world[touch[:, o] > 0.0]

        contacts = []
        for a, body in enumerate(self.bodies):
            if body.kind != "dynamic":
                continue
            for o in range(m):
                both = o < n and bodies[o].kind == "dynamic"
                if both and o < a:  # a pair of dynamic bodies once
                    continue
                d = max(depth[a, o], depth[o, a]) if both else depth[a, o]
                direction = push[a, o] - push[o, a] if both else push[a, o]
                if (d > 0.0 or kinematic[o]) and np.any(direction):
                    normal = direction / np.linalg.norm(direction)
                    # the touching samples of each, on its surface: b's towards o (against the normal), o's towards b
                    points = [touched(a, o) - reach * normal]
                    if both:
                        points.append(touched(o, a) + reach * normal)
                    points = contact_points(np.concatenate(points), normal, ctx.constants.particle_radius)
                    restitution, friction = contact_coefficients(body, bodies[o], both)
                    self._separate(body, bodies[o], normal, d, both, friction, points.mean(axis=0))
                    contacts.append(PointContact(body, bodies[o], both, normal, points, restitution, friction,
                                                 rest_speed))
                    contacts[-1].key = ("body", a, o)
        return contacts

    @staticmethod
    def _separate(body, other, normal, depth, both, friction, centre=None):
        """Moves ``body`` out of ``other`` along ``normal`` by ``depth`` (by inverse mass when ``both``: the other is
        dynamic) and, without a ``friction`` coefficient (None), damps their tangential slip and spin by WALL_FRICTION
        (see :meth:`_body_contact`; impulses between two dynamic bodies are equal and opposite). Against a kinematic
        other the slip is taken against its velocity at ``centre`` (the contact points' centre) and the spin is damped
        towards its own (a box on a moving or turning platform is carried along)."""
        inv, inv_other = 1.0 / body.mass, (1.0 / other.mass if both else 0.0)
        body.position = body.position + inv / (inv + inv_other) * depth * normal
        if both:
            other.position = other.position - inv_other / (inv + inv_other) * depth * normal
        if friction is not None:
            return
        if not both and other.kind == "kinematic":
            at = body.position if centre is None else centre
            slip = body.velocity - rigid_velocity(other, at - other.position)
            slip = slip - float(slip @ normal) * normal
            body.velocity = body.velocity - (1.0 - WALL_FRICTION) * slip
            body.angular_velocity = other.angular_velocity + WALL_FRICTION * (body.angular_velocity
                                                                              - other.angular_velocity)
            return
        slip = body.velocity - other.velocity if both else body.velocity
        slip = slip - float(slip @ normal) * normal
        impulse = -(1.0 - WALL_FRICTION) * slip / (inv + inv_other)
        body.velocity = body.velocity + inv * impulse
        body.angular_velocity = WALL_FRICTION * body.angular_velocity
        if both:
            other.velocity = other.velocity - inv_other * impulse
            other.angular_velocity = WALL_FRICTION * other.angular_velocity

    def _wall_contact(self, body, lo, hi, periodic, rest_speed, own, dt):
        """Keeps the body's samples inside [lo, hi] (the domain less the samples' inset, so the mesh surface stops at
        the walls): pushed back along each closed axis, and each touched wall's contact (:class:`PointContact`:
        restitution, Coulomb friction or, without a friction coefficient, normal impulses only and the tangential
        motion and spin damped by WALL_FRICTION) acts at the contact points on the wall: the mesh vertices within a
        particle radius of the one nearest the wall (the corners of a box's face; the vertices, as a face's samples
        are not placed symmetrically), each of those above it free to come down by its height in this step (a box
        at 4.7 degrees stopped on its lower edge with the upper corners 1.6 cm up, held there). Without a friction
        coefficient the contact acted at the centre of mass until session 21: a box dropped on its edge stayed on
        it. Returns the contacts, solved with the bodies' by :func:`solve_contacts`."""
        restitution, friction = contact_coefficients(body, None, False)
        band = self.ctx.constants.particle_radius
        contacts, touched = [], set()
        for k in range(3):
            if "xyz"[k] in periodic:
                continue
            for side in (-1.0, 1.0):
                world = body.to_world(body.samples)
                face = lo[k] if side < 0.0 else hi[k]
                height = side * (face - world[:, k])  # the samples' distance inside the wall's face
                depth = -float(height.min())
                if depth <= 0.0:
                    continue
                normal = np.zeros(3)
                normal[k] = -side
                body.position = body.position + depth * normal
                corners = body.to_world(body.vertices)  # the mesh's, evenly placed where the samples are not
                near = side * (face - corners[:, k])
                chosen = near - near.min() < band
                points = corners[chosen]
                points[:, k] = face + side * own
                contacts.append(PointContact(body, None, False, normal, points, restitution, friction, rest_speed,
                                             slack=(near[chosen] - near.min()) / dt))
                contacts[-1].key = ("wall", self.bodies.index(body), k, side)
                touched.add(k)
        if touched and friction is None:
            for k in set(range(3)) - touched:
                body.velocity[k] *= WALL_FRICTION
            body.angular_velocity = WALL_FRICTION * body.angular_velocity
        return contacts

    # -- state ------------------------------------------------------------------------------------------------
    def _store_state(self):
        if not self.dynamic:
            return
        rows = [np.concatenate([b.position, b.rotation.ravel(), b.velocity, b.angular_velocity, b.acceleration,
                                b.angular_acceleration]) for b in self.dynamic]
        self.state.assign(np.asarray(rows, np.float64))
        rows = []
        for key, (points, normal_sum, tangent_sum) in self._warm.items():
            head = [0.0 if key[0] == "wall" else 1.0, key[1], key[2], key[3] if key[0] == "wall" else 0.0]
            rows += [head + list(points[p]) + list(tangent_sum[p]) + [normal_sum[p]] for p in range(len(points))]
        rows = rows[:CONTACT_MEMORY_ROWS]
        # the rows in use, and those the last step used marked unused: the rest of the room is unused already
        written = max(len(rows), self._memory_rows)
        if written:
            memory = np.full((written, CONTACT_MEMORY_COLUMNS), -1.0)
            memory[:len(rows)] = np.asarray(rows, np.float64).reshape(-1, CONTACT_MEMORY_COLUMNS)
            self.contact_memory[:written].assign(memory)
        self._memory_rows = len(rows)

    def load_state(self):
        """Reads the dynamic bodies' pose and velocity and the contacts' impulses back from ``state`` and
        ``contact_memory`` (after a restore: a checkpoint or a retried frame)."""
        if not self.dynamic:
            return
        self._warm = {}
        memory = self.contact_memory.numpy()
        self._memory_rows = int((memory[:, 0] >= 0.0).sum())  # the rows in use come first
        for r in memory[:self._memory_rows]:
            key = ("wall", int(r[1]), int(r[2]), r[3]) if r[0] == 0.0 else ("body", int(r[1]), int(r[2]))
            points, normal_sum, tangent_sum = self._warm.get(key, (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))))
            self._warm[key] = (np.vstack([points, r[4:7]]), np.append(normal_sum, r[10]), np.vstack([tangent_sum, r[7:10]]))
        for row, body in zip(self.state.numpy(), self.dynamic):
            body.position, body.rotation = row[0:3].copy(), row[3:12].reshape(3, 3).copy()
            body.velocity, body.angular_velocity = row[12:15].copy(), row[15:18].copy()
            body.acceleration, body.angular_acceleration = row[18:21].copy(), row[21:24].copy()
