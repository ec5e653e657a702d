"""Vorticity zeta = curl v (VR paper eq 6), difference form.

Computed once per step over fluid neighbours only (boundary particles carry no
vorticity, as in the Rankine paper) and shared by every model that needs it. When the
fluid has viscosity, the viscosity pass computes them instead (one pass fewer); this
kernel serves inviscid scenes and the diagnostics.
"""

import warp as wp

from .particles import Neighbours, separation
from .sph_kernel import cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})


@wp.func
def curl_term(a_ij: wp.vec3, grad_w: wp.vec3, volume_j: float):
    """One neighbour's term of the difference-form curl (eq 3 with a cross product): V_j a_ij x grad W_ij."""
    return volume_j * wp.cross(a_ij, grad_w)


@wp.func
def curl_of_gradient(grad: wp.mat33):
    """curl v from the velocity gradient G[a][b] = d v^a / d x^b: (G21 - G12, G02 - G20, G10 - G01).
    With G summed as sum_j V_j (v_j - v_i) (x) grad W_ij this is exactly the eq-6 sum."""
    return wp.vec3(grad[2, 1] - grad[1, 2], grad[0, 2] - grad[2, 0], grad[1, 0] - grad[0, 1])


@wp.func
def sph_curl(
    i: int,
    x: wp.array(dtype=wp.vec3),
    field: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    particle_mass: float,
    support_radius: float,
):
    """Difference-form curl of a per-particle vector field at particle i (eq 6 form, fluid
    neighbours): sum_j (m_j / rho_j) (a_i - a_j) x grad W_ij."""
    xi = x[i]
    ai = field[i]
    curl = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        gw = cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
        curl += curl_term(ai - field[j], gw, particle_mass / density[j])
    return curl


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
    vorticity[i] = sph_curl(i, x, v, density, nb, particle_mass, support_radius)
