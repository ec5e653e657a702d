"""Density (eq 2 with A = rho) and the DFSPH factor, fused in one neighbour pass."""

import warp as wp

from .particles import Boundary, Neighbours, separation
from .sph_kernel import cubic_kernel, cubic_kernel_gradient, cubic_kernel_zero

wp.set_module_options({"enable_backward": False})


@wp.func
def dfsph_factor(grad_sum: wp.vec3, grad_sq: float, support_radius: float):
    """1 / (|sum_j V_j grad W_ij|^2 + sum_j |V_j grad W_ij|^2) from those two sums (Bender & Koschier 2017), 0 when
    the denominator is tiny (a particle with almost no neighbours)."""
    denominator = wp.dot(grad_sum, grad_sum) + grad_sq
    if denominator > 1.0e-6 / (support_radius * support_radius):
        return 1.0 / denominator
    return 0.0


@wp.kernel
def compute_density_and_factor(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    fluid_volume: float,
    rest_density: float,
    support_radius: float,
    density: wp.array(dtype=float),
    factor: wp.array(dtype=float),
    position_divergence: wp.array(dtype=float),
    concentration_gradient: wp.array(dtype=wp.vec3),
):
    """rho_i = rho0 (V_i W(0) + sum_f V_j W_ij + sum_b V_b W_ib) and the DFSPH factor
    factor_i = 1 / (|sum_f V_j grad W_ij + sum_b V_b grad W_ib|^2 + sum_f |V_j grad W_ij|^2)
    (Bender & Koschier 2017; no squared boundary term, 0 when the denominator is tiny), and the divergence
    of position div r_i = -sum_f V_j x_ij . grad W_ij - sum_b V_b x_ib . grad W_ib (Lind et al. 2012; 3 in
    the bulk, about 2.2 on a flat free surface), which :func:`classify_free_surface` reads. The gradient
    sum is also the gradient of the particle concentration that shifting reads. ``factor``, ``position_divergence``
    and ``concentration_gradient`` may be empty: the solver (IISPH) or shifting (off) does not read them."""
    i = wp.tid()
    xi = x[i]
    rho = fluid_volume * cubic_kernel_zero(support_radius)
    grad_sum = wp.vec3(0.0)
    grad_sq = float(0.0)
    div_r = float(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        x_ij = separation(nb, xi, x[nb.fluid[k]])
        rho += fluid_volume * cubic_kernel(wp.length(x_ij), support_radius)
        g = fluid_volume * cubic_kernel_gradient(x_ij, support_radius)
        grad_sum += g
        div_r -= wp.dot(x_ij, g)
        grad_sq += wp.dot(g, g)
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        x_ib = separation(nb, xi, boundary.x[b])
        rho += boundary.volume[b] * cubic_kernel(wp.length(x_ib), support_radius)
        gb = boundary.volume[b] * cubic_kernel_gradient(x_ib, support_radius)
        grad_sum += gb
        div_r -= wp.dot(x_ib, gb)
    density[i] = rest_density * rho
    if position_divergence.shape[0] > 0:
        position_divergence[i] = div_r
    if concentration_gradient.shape[0] > 0:
        concentration_gradient[i] = grad_sum
    if factor.shape[0] > 0:
        factor[i] = dfsph_factor(grad_sum, grad_sq, support_radius)
