"""Rankine vortex feedback (Rankine paper, Algorithm 1)."""

import warp as wp

from .particles import Neighbours, separation

wp.set_module_options({"enable_backward": False})

OSEEN = wp.constant(1.25643)  # Lamb-Oseen parameter of eq 10
# The paper keeps the viscous core inside a particle (r_c < r). The feedback's restoring gain grows as
# r_c^2 (-0.85 of d omega at r_c = r for 8-spacing structures on a lattice), and with r_c above about
# 0.9 r the loop ran away in a Lamb-Oseen vortex (kinetic energy x3 to x40 at 64-192 particles across,
# beta 0.6 and 1 alike); 0.7 r keeps the gain near half of that.
# The cap bounds the largest core r_c^max of eq 11, before beta scales it (``core_radius``), so that beta
# stays the paper's intensity knob over [0, 1].
MAX_CORE = wp.constant(0.7)


@wp.func
def core_radius(beta: float, viscosity: float, particle_radius: float, dt: float):
    """r_c = beta r_c^max (eq 11, Algorithm 1 line 4) with r_c^max = min(sqrt(4 1.25643 nu dt), 0.7 r).

    Eq 11 makes beta the share of the largest core, r_c^max = sqrt(4 alpha nu dt) (eq 10 over one step), and
    the outer feedback scales as r_c^2 (eq 15), so as beta^2: the paper's Fig 7 sweeps beta = 0 .. 0.6 as its
    intensity knob. Our cap (MAX_CORE) is a bound on that largest core, so it applies before beta. Capping
    beta r_c^max instead, as earlier versions did, made every beta above 0.7 r / r_c^max the same model:
    at the viscous time-step limit r_c^max is about 1.6 r, so beta = 0.44 .. 1 all gave r_c = 0.7 r (the
    Lamb-Oseen study showed beta = 0.6 and 1 equal to the digit from 96 across up)."""
    return beta * wp.min(wp.sqrt(4.0 * OSEEN * viscosity * dt), MAX_CORE * particle_radius)


@wp.kernel
def compute_vorticity_change(
    vorticity: wp.array(dtype=wp.vec3),
    has_previous: int,
    previous: wp.array(dtype=wp.vec3),
    change: wp.array(dtype=wp.vec3),
):
    """d omega = omega^n - omega^{n-1} (line 3), zero on the first step and on a particle's first step after
    an emitter added it (omega^{n-1} NaN, ``models.NO_HISTORY``); omega^n is kept for the next."""
    i = wp.tid()
    w = vorticity[i]
    if has_previous != 0 and not wp.isnan(previous[i][0]):
        change[i] = w - previous[i]
    else:
        change[i] = wp.vec3(0.0)
    previous[i] = w


@wp.func
def rankine_velocity(change_j: wp.vec3, x_ij: wp.vec3, core_radius: float):
    """Velocity that vortex j induces at x_i = x_j + x_ij: r_c^2 / (2 r) d omega_j x e_theta (eq 15),
    e_theta pointing from the vortex to the receiver; inside the core the rigid rotation
    d omega_j / 2 x x_ij (eq 14) that it matches at r = r_c."""
    r2 = wp.dot(x_ij, x_ij)
    if r2 <= 0.0:
        return wp.vec3(0.0)
    c = wp.cross(change_j, x_ij)  # r (d omega_j x e_theta)
    rc2 = core_radius * core_radius
    if r2 < rc2:
        return 0.5 * c
    return (0.5 * rc2 / r2) * c


@wp.kernel
def apply_rankine_feedback(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    change: wp.array(dtype=wp.vec3),
    beta: float,
    viscosity: float,
    particle_radius: float,
    dt: wp.array(dtype=float),
    v: wp.array(dtype=wp.vec3),
):
    """v_i += sum_j r_c^2 / (2 r) (-d omega_j) x e_theta with r_c = beta min(sqrt(4 1.25643 nu dt), 0.7 r)
    (lines 4-6, ``core_radius``): the largest core is at most 0.7 of the particle radius (MAX_CORE), since the
    paper requires the viscous core to stay inside a particle (at r = 6.3 mm, dt = 1.3 ms and nu = 0.05 the
    formula gives 18 mm and a 1M dam break ran away) and close to r the feedback loop itself ran away; beta
    scales the capped core, so the feedback grows as beta^2 over the whole range [0, 1].

    Each pair's refinement goes to the receiver i from the vortex at its neighbour j (eq 13:
    d v_{j->i}, e_theta from x_j to x_i): a vortex moves the fluid around it, not its own core.

    The vortex fed back is -d omega_j: section 4.1 says the angular velocity that refines the linear
    velocity "should be negative wrt. the dissipated angular velocity" (a negative factor towards the
    vortex centre), so the feedback restores the vorticity lost since step n-1 (Fig 8: "refine the
    dissipated vorticity"). Fed back with the plain sign it would reinforce the change, i.e. hasten the
    decay of a freely decaying vortex (measured: 0.173 of the initial kinetic energy against 0.191 for
    plain DFSPH). Gathered per receiver, so no atomics."""
    i = wp.tid()
    core = core_radius(beta, viscosity, particle_radius, dt[0])
    xi = x[i]
    dv = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        dv -= rankine_velocity(change[j], separation(nb, xi, x[j]), core)
    v[i] = v[i] + dv
