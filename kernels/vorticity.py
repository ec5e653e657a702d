"""Vorticity zeta = curl v (VR paper eq 6) and the velocity gradient (eq 8), difference form.

Computed once per step over fluid neighbours only (boundary particles carry no
vorticity, as in the Rankine paper) and shared by every model that needs it.
"""

import warp as wp

from .particles import Neighbours
from .sph_kernel import cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})


@wp.kernel
def compute_vorticity(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    particle_mass: float,
    support_radius: float,
    vorticity: wp.array(dtype=wp.vec3),
):
    """zeta_i = sum_j (m_j / rho_j) (v_i - v_j) x grad W_ij (eq 6)."""
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    curl = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        curl += (particle_mass / density[j]) * wp.cross(vi - v[j], cubic_kernel_gradient(xi - x[j], support_radius))
    vorticity[i] = curl


@wp.kernel
def compute_vorticity_and_gradient(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    particle_mass: float,
    support_radius: float,
    vorticity: wp.array(dtype=wp.vec3),
    velocity_gradient: wp.array(dtype=wp.mat33),
):
    """zeta_i (eq 6) and G_i = sum_j (m_j / rho_j) (v_j - v_i) (x) grad W_ij, whose row a is
    grad v^a (eq 8), so that the stretching term zeta . grad v (eq 9) is G_i zeta_i."""
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    curl = wp.vec3(0.0)
    grad = wp.mat33(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        volume = particle_mass / density[j]
        gw = cubic_kernel_gradient(xi - x[j], support_radius)
        curl += volume * wp.cross(vi - v[j], gw)
        grad += volume * wp.outer(v[j] - vi, gw)
    vorticity[i] = curl
    velocity_gradient[i] = grad
