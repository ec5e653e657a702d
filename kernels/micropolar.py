"""Micropolar model (Bender et al. 2017/2018): per-particle angular velocity omega coupled
to the linear velocity through the transfer coefficient nu_t."""

import warp as wp

from .particles import Neighbours, separation
from .sph_kernel import cubic_kernel, cubic_kernel_gradient
from .vorticity import curl_term

wp.set_module_options({"enable_backward": False})


@wp.kernel
def micropolar_step(
    x: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    vorticity: wp.array(dtype=wp.vec3),
    omega: wp.array(dtype=wp.vec3),
    particle_mass: float,
    transfer_coefficient: float,
    inverse_inertia: float,
    viscosity_omega: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    acceleration: wp.array(dtype=wp.vec3),
    omega_next: wp.array(dtype=wp.vec3),
):
    """a_i += (nu_t / rho_i) sum_j m_j (omega_i - omega_j) x grad W_ij and
    d omega_i/dt = Theta^-1 nu_t (curl v_i - 2 omega_i) - (Theta^-1 zeta / dt) sum_j (m_j/rho_j)(omega_i - omega_j) W_ij,
    with curl v the shared vorticity (eq 6); explicit Euler into ``omega_next``."""
    i = wp.tid()
    xi = x[i]
    wi = omega[i]
    curl_omega = wp.vec3(0.0)
    smooth = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        x_ij = separation(nb, xi, x[j])
        w_ij = wi - omega[j]
        curl_omega += curl_term(w_ij, cubic_kernel_gradient(x_ij, support_radius), particle_mass)
        smooth += (particle_mass / density[j]) * cubic_kernel(wp.length(x_ij), support_radius) * w_ij
    h = dt[0]
    acceleration[i] = acceleration[i] + (transfer_coefficient / density[i]) * curl_omega
    rate = inverse_inertia * transfer_coefficient * (vorticity[i] - 2.0 * wi) - (inverse_inertia * viscosity_omega / h) * smooth
    omega_next[i] = wi + h * rate
