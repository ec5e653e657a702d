"""Particle shifting of the pressure solver (Lind, Xu, Stansby & Rogers 2012; Skillen et al. 2013).

Under a signed pressure SPH particles pair up (tensile instability), and a disordered distribution has a higher
summation density than the lattice at the same number density. Shifting moves each bulk particle down the
gradient of the particle concentration C_i = sum_j V_j W_ij after the position update, which keeps the
distribution close to uniform. Outside the periodic box only the particle-scale part of grad C moves a bulk
particle: grad C less its kernel-weighted mean over the bulk neighbours. The smooth part is not a
disorder but the curvature of the particle rows (a vortex's core reads grad C inwards on every particle);
shifted out along it, the core was pulled back in by the density solve, which corrects the drift through the
velocity there, and each cycle added angular momentum. Lamb-Oseen on the CPU at 16 / 24 / 32 across:
2.62 / 1.44 / 1.32 % with it, 4.59 / 2.25 / 1.52 % with the whole grad C (docs/notes/solver.md). The periodic
box corrects its drift through the positions and keeps the whole grad C. Near the free surface the shift is tangential (its
component along grad C, the surface normal, removed) and on the surface it is off, so the surface is not pulled
apart (Lind et al. 2012, section 3.3). Lind et al.'s anti-pairing factor and the first-order Taylor correction
of the velocity to the shifted position both injected energy on Taylor-Green (docs/notes/solver.md), so the
shift is the plain -D grad C and the velocity stays.
"""

import warp as wp

from .free_surface import BAND, BULK, SURFACE, WALL
from .particles import Neighbours, keep_in_domain, separation
from .sph_kernel import cubic_kernel, cubic_kernel_zero

wp.set_module_options({"enable_backward": False})


@wp.func
def limit_length(d: wp.vec3, max_length: float):
    """d, scaled down to ``max_length`` when it is longer."""
    length = wp.length(d)
    if length > max_length:
        return d * (max_length / length)
    return d


@wp.kernel
def compute_shift(
    concentration_gradient: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    surface: wp.array(dtype=wp.int32),
    free_surface: wp.array(dtype=wp.int32),
    support_radius: float,
    dt: wp.array(dtype=float),
    max_speed_sq: wp.array(dtype=float),
    coefficient: float,
    max_shift: float,
    high_pass: int,
    shift: wp.array(dtype=wp.vec3),
):
    """shift_i = -D grad C_i, D = coefficient h max|v| dt (Skillen et al. 2013 with the step's largest speed,
    h = H / 2), |shift_i| <= max_shift; grad C_i = sum_f V_j grad W_ij + sum_b V_b grad W_ib from the density
    pass at the step's start. With ``high_pass`` (every box but the periodic one) a bulk particle takes
    grad C_i - <grad C>_i, <grad C>_i = sum_j W_ij grad C_j / sum_j W_ij over i and its bulk fluid neighbours (the
    whole grad C in a free-surface scene compressed a 16K dam break to 1.15 rho0, docs/notes/solver.md). In the
    surface band and beside walls only its part normal to grad C_i (which is the surface's or the wall's normal
    there), none on the free surface. ``free_surface`` is not read."""
    i = wp.tid()
    d = wp.vec3(0.0)
    flag = surface[i]
    if flag != SURFACE:
        grad_c = concentration_gradient[i]
        if flag == BULK and high_pass != 0:
            xi = x[i]
            weight = cubic_kernel_zero(support_radius)
            mean = weight * grad_c
            for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
                j = nb.fluid[k]
                if surface[j] == BULK:
                    w = cubic_kernel(wp.length(separation(nb, xi, x[j])), support_radius)
                    mean += w * concentration_gradient[j]
                    weight += w
            grad_c = grad_c - mean / weight
        d = -coefficient * 0.5 * support_radius * wp.sqrt(max_speed_sq[0]) * dt[0] * grad_c
        if flag == BAND or flag == WALL:
            n = wp.normalize(grad_c)
            d = d - wp.dot(d, n) * n
        d = limit_length(d, max_shift)
    shift[i] = d


@wp.kernel
def apply_shift(
    shift: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    period: wp.vec3,
    inside_lo: wp.vec3,
    inside_hi: wp.vec3,
    x: wp.array(dtype=wp.vec3),
):
    """x_i += shift_i, wrapped into the domain along periodic axes and held inside its walled faces."""
    i = wp.tid()
    x[i] = keep_in_domain(x[i] + shift[i], lower, period, inside_lo, inside_hi)
