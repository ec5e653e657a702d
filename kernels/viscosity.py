"""Artificial-viscosity Laplacian (VR paper eq 4, after Koschier et al. 2019)."""

import warp as wp

from .particles import Boundary, Neighbours, boundary_velocity, separation
from .sph_kernel import cubic_kernel_gradient
from .vorticity import curl_term

wp.set_module_options({"enable_backward": False})


@wp.func
def artificial_laplacian(a_ij: wp.vec3, x_ij: wp.vec3, grad_w: wp.vec3, volume_j: float, support_radius: float):
    """One neighbour's term of eq 4: 2(d+2) V_j (A_ij . x_ij) / (|x_ij|^2 + 0.01 H^2) grad W_ij, d = 3.

    Shared by the viscosity of v (eq 4) and the vorticity Laplacian (eq 10); ``grad_w`` is grad W_ij,
    which the callers' loops also use for other sums."""
    h2 = support_radius * support_radius
    return (10.0 * volume_j * wp.dot(a_ij, x_ij) / (wp.dot(x_ij, x_ij) + 0.01 * h2)) * grad_w


@wp.kernel
def add_viscosity_acceleration(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    particle_mass: float,
    viscosity: float,
    support_radius: float,
    boundary: Boundary,
    boundary_viscosity: float,
    dt: wp.array(dtype=float),
    with_vorticity: int,
    acceleration: wp.array(dtype=wp.vec3),
    vorticity: wp.array(dtype=wp.vec3),
):
    """a_i += nu * laplacian(v)_i with m_j / rho_j as the neighbour volume (eq 4), plus, with
    ``boundary_viscosity``, the same term against the boundary samples' velocities (V_b as volume):
    walls and moving bodies drag the fluid; a dynamic body's sample gets the opposite impulse.

    When a turbulence model needs it, the same neighbour loop also yields the vorticity
    zeta_i = sum_j (m_j/rho_j)(v_i - v_j) x grad W_ij (eq 6): one pass instead of two."""
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    lap = wp.vec3(0.0)
    curl = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        x_ij = separation(nb, xi, x[j])
        volume = particle_mass / density[j]
        v_ij = vi - v[j]
        gw = cubic_kernel_gradient(x_ij, support_radius)
        lap += artificial_laplacian(v_ij, x_ij, gw, volume, support_radius)
        if with_vorticity != 0:
            curl += curl_term(v_ij, gw, volume)
    friction = wp.vec3(0.0)
    if boundary_viscosity > 0.0:
        for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
            b = nb.boundary[k]
            x_ib = separation(nb, xi, boundary.x[b])
            gw = cubic_kernel_gradient(x_ib, support_radius)
            term = boundary_viscosity * artificial_laplacian(vi - boundary_velocity(boundary, b), x_ib, gw, boundary.volume[b], support_radius)
            if b >= boundary.first_dynamic:
                wp.atomic_add(boundary.impulse, b, -dt[0] * term)
            friction += term
    acceleration[i] = acceleration[i] + viscosity * lap + friction
    if with_vorticity != 0:
        vorticity[i] = curl
