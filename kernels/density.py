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


@wp.func
def pair_viscous_stiffness(x_ij: wp.vec3, volume_grad_w: wp.vec3, support_radius: float):
    """K_ij = 2(d+2) V_j |grad W_ij| x_ij x_ij^T / (|x_ij| (|x_ij|^2 + 0.01 H^2)), d = 3: the positive semi-definite
    matrix of eq 4's pair term, -K_ij (v_i - v_j) (:func:`~kernels.viscosity.artificial_laplacian`), given
    V_j grad W_ij (``volume_grad_w``)."""
    return (10.0 / (wp.dot(x_ij, x_ij) + 0.01 * support_radius * support_radius)) * wp.outer(x_ij, -volume_grad_w)


@wp.func
def largest_eigenvalue(a: wp.mat33):
    """The largest eigenvalue of a symmetric 3x3 matrix."""
    q, d = wp.eig3(a)
    return wp.max(d[0], wp.max(d[1], d[2]))


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
    viscosity: float,
    boundary_viscosity: float,
    viscous_rate: wp.array(dtype=float),
):
    """rho_i = rho0 (V_i W(0) + sum_f V_j W_ij + sum_b V_b W_ib) and the DFSPH factor
    factor_i = 1 / (|sum_f V_j grad W_ij + sum_b V_b grad W_ib|^2 + sum_f |V_j grad W_ij|^2)
    (Bender & Koschier 2017; no squared boundary term, 0 when the denominator is tiny), and the divergence
    of position div r_i = -sum_f V_j x_ij . grad W_ij - sum_b V_b x_ib . grad W_ib (Lind et al. 2012; 3 in
    the bulk, about 2.2 on a flat free surface), which :func:`classify_free_surface` reads. The gradient
    sum is also the gradient of the particle concentration that shifting reads. ``factor``, ``position_divergence``
    and ``concentration_gradient`` may be empty: the solver (IISPH) or shifting (off) does not read them.

    ``viscous_rate`` (empty without viscosity): lambda_i = the largest eigenvalue of 2 nu sum_f K_ij + nu_b sum_b K_ib
    (:func:`pair_viscous_stiffness` at the rest volume V_j = m / rho0), which bounds the explicit viscosity's largest
    rate: eq 4 with symmetric pair volumes gives u . (L u) = -1/2 sum_ij (u_i - u_j) . K_ij (u_i - u_j) and
    (a - b) . K (a - b) <= 2 (a . K a + b . K b), so |L| <= max_i lambda_i, and explicit Euler is stable for
    dt <= 2 / max_i lambda_i (on a lattice the bound is that of the checkerboard mode, 1.14x Morris et al.'s
    0.125 (H/2)^2 / nu)."""

    i = wp.tid()
    xi = x[i]
    rho = fluid_volume * cubic_kernel_zero(support_radius)
    grad_sum = wp.vec3(0.0)
    grad_sq = float(0.0)
    div_r = float(0.0)
    with_rate = viscous_rate.shape[0] > 0
    stiffness = wp.mat33(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        x_ij = separation(nb, xi, x[nb.fluid[k]])
        rho += fluid_volume * cubic_kernel(wp.length(x_ij), support_radius)
        g = fluid_volume * cubic_kernel_gradient(x_ij, support_radius)
        grad_sum += g
        div_r -= wp.dot(x_ij, g)
        grad_sq += wp.dot(g, g)
        if with_rate:
            stiffness += (2.0 * viscosity) * pair_viscous_stiffness(x_ij, g, support_radius)
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        x_ib = separation(nb, xi, boundary.x[b])
        rho += boundary.volume[b] * cubic_kernel(wp.length(x_ib), support_radius)
        gb = boundary.volume[b] * cubic_kernel_gradient(x_ib, support_radius)
        grad_sum += gb
        div_r -= wp.dot(x_ib, gb)
        if with_rate:
            stiffness += boundary_viscosity * pair_viscous_stiffness(x_ib, gb, support_radius)
    density[i] = rest_density * rho
    if with_rate:
        viscous_rate[i] = largest_eigenvalue(stiffness)
    if position_divergence.shape[0] > 0:
        position_divergence[i] = div_r
    if concentration_gradient.shape[0] > 0:
        concentration_gradient[i] = grad_sum
    if factor.shape[0] > 0:
        factor[i] = dfsph_factor(grad_sum, grad_sq, support_radius)
