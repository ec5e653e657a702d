"""Particle shifting and the transport-velocity displacement of the confined pressure mode (Lind et al.
2012, Skillen et al. 2013; Adami, Hu & Adams 2013).

Under a signed pressure, SPH particles pair up (tensile instability) and a disordered distribution
has a higher summation density than the lattice at the same number density. The confined solver
removes the mean of its source (a constant pressure moves nothing in a closed or periodic box), so
nothing would stop that rise. Shifting moves each particle down the gradient of the particle
concentration C_i = sum_j V_j W_ij after the position update, which keeps the distribution close to
uniform. Measured on Taylor-Green (tools/results/CONFINED_NOTES.md), Lind et al.'s anti-pairing factor
(1 + 0.2 (W_ij / W(d))^4) and the first-order Taylor correction of the velocity to the shifted position
both injected energy, so the shift is the plain -D grad C and the velocity stays.
"""

import warp as wp

from .particles import Boundary, Neighbours, separation, wrap_into_domain
from .sph_kernel import cubic_kernel, cubic_kernel_gradient, cubic_kernel_zero

wp.set_module_options({"enable_backward": False})

# A particle whose concentration (fluid and boundary) is below this is at a free surface: no shift
# (the confined mode expects none; a shift there would pull the surface apart)
SURFACE_CONCENTRATION = wp.constant(0.9)


@wp.func
def limit_length(d: wp.vec3, max_length: float):
    """d, scaled down to ``max_length`` when it is longer."""
    length = wp.length(d)
    if length > max_length:
        return d * (max_length / length)
    return d


@wp.kernel
def compute_shift(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    fluid_volume: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    max_speed_sq: wp.array(dtype=float),
    coefficient: float,
    max_shift: float,
    shift: wp.array(dtype=wp.vec3),
):
    """shift_i = -D grad C_i, D = coefficient h max|v| dt (Skillen et al. 2013 with the step's largest
    speed, h = H / 2), |shift_i| <= max_shift; grad C_i = sum_f V_j grad W_ij + sum_b V_b grad W_ib.
    No shift where C_i < SURFACE_CONCENTRATION (a free surface)."""
    i = wp.tid()
    xi = x[i]
    concentration = fluid_volume * cubic_kernel_zero(support_radius)
    grad_c = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        x_ij = separation(nb, xi, x[nb.fluid[k]])
        concentration += fluid_volume * cubic_kernel(wp.length(x_ij), support_radius)
        grad_c += fluid_volume * cubic_kernel_gradient(x_ij, support_radius)
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        x_ib = separation(nb, xi, boundary.x[b])
        concentration += boundary.volume[b] * cubic_kernel(wp.length(x_ib), support_radius)
        grad_c += boundary.volume[b] * cubic_kernel_gradient(x_ib, support_radius)
    d = wp.vec3(0.0)
    if concentration >= SURFACE_CONCENTRATION:
        diffusion = coefficient * 0.5 * support_radius * wp.sqrt(max_speed_sq[0]) * dt[0]
        d = limit_length(-diffusion * grad_c, max_shift)
    shift[i] = d


@wp.kernel
def apply_shift(
    shift: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    period: wp.vec3,
    x: wp.array(dtype=wp.vec3),
):
    """x_i += shift_i, wrapped into the domain along periodic axes."""
    i = wp.tid()
    x[i] = wrap_into_domain(x[i] + shift[i], lower, period)


@wp.kernel
def compute_transport_shift(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    density: wp.array(dtype=float),
    fluid_volume: float,
    rest_density: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    max_speed_sq: wp.array(dtype=float),
    coefficient: float,
    max_shift: float,
    shift: wp.array(dtype=wp.vec3),
):
    """Transport-velocity displacement (Adami, Hu & Adams 2013): shift_i = dt^2 a_b,i with the
    acceleration of a uniform background pressure p_b = coefficient rho0 max|v|^2,
    a_b,i = -(p_b / m_i) sum_j (V_i^2 + V_j^2) grad W_ij, V = m / rho (rho of the step start);
    a boundary sample counts with V_b and (rho0 / rho_i)^2 V0 for i. |shift_i| <= max_shift."""
    i = wp.tid()
    xi = x[i]
    ri = rest_density / density[i]
    ri2 = ri * ri
    g = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        rj = rest_density / density[j]
        g += fluid_volume * (ri2 + rj * rj) * cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        g += (fluid_volume * ri2 + boundary.volume[b]) * cubic_kernel_gradient(separation(nb, xi, boundary.x[b]), support_radius)
    h = dt[0]
    shift[i] = limit_length(-coefficient * max_speed_sq[0] * h * h * g, max_shift)


@wp.kernel
def transport_velocity_correction(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    shift: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    fluid_volume: float,
    support_radius: float,
    v_out: wp.array(dtype=wp.vec3),
):
    """v_out_i = v_i + (shift_i . grad) v_i, grad v_i = sum_j V_j (v_j - v_i) grad W_ij^T."""
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    d = shift[i]
    dv = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        dv += fluid_volume * (v[j] - vi) * wp.dot(cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius), d)
    v_out[i] = vi + dv
