"""Vorticity refinement (VR paper, Algorithm 2): the vorticity lost to numerical
dissipation is turned back into velocity through a stream function."""

import warp as wp

from .particles import Neighbours, separation
from .sph_kernel import PI, cubic_kernel_gradient
from .viscosity import artificial_laplacian
from .vorticity import curl_of_gradient, sph_curl

wp.set_module_options({"enable_backward": False})

# eq 15 divides by |x_ij|; like SPlisHSPlasH we add 0.1 H so that two particles that come
# very close cannot produce an unbounded stream function.
STREAM_FUNCTION_GUARD = wp.constant(0.1)


@wp.kernel
def compute_vorticity_loss(
    vorticity: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    particle_mass: float,
    has_target: int,
    target_then_loss: wp.array(dtype=wp.vec3),
):
    """V_i d zeta_i with the dissipated vorticity d zeta = zeta^{n+1} - curl v~ (eq 12), written over
    the target zeta^{n+1} (read here only; the target pass writes the next one), so the stream-function
    pass reads one vector per neighbour; zero before the first target exists, for everyone on the first step
    and for a particle that an emitter just added (target NaN, ``models.NO_HISTORY``)."""
    i = wp.tid()
    if has_target != 0 and not wp.isnan(target_then_loss[i][0]):
        target_then_loss[i] = (particle_mass / density[i]) * (target_then_loss[i] - vorticity[i])
    else:
        target_then_loss[i] = wp.vec3(0.0)


@wp.kernel
def compute_stream_function(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    weighted_loss: wp.array(dtype=wp.vec3),
    support_radius: float,
    stream_function: wp.array(dtype=wp.vec3),
):
    """psi_i = 1/(4 pi) sum_j d zeta_j V_j / (|x_ij| + 0.1 H) over kernel neighbours (eq 15), from
    V_j d zeta_j (``weighted_loss``)."""
    i = wp.tid()
    xi = x[i]
    guard = STREAM_FUNCTION_GUARD * support_radius
    psi = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        psi += weighted_loss[j] * (1.0 / (wp.length(separation(nb, xi, x[j])) + guard))
    stream_function[i] = psi / (4.0 * PI)


@wp.kernel
def compute_target_vorticity(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    vorticity: wp.array(dtype=wp.vec3),
    particle_mass: float,
    viscosity: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    target: wp.array(dtype=wp.vec3),
):
    """The next step's ideal vorticity zeta^{n+1} = zeta^n + dt (zeta^n . grad v + nu lap zeta)
    (eqs 9-11). One neighbour loop over the refined velocity v^n gives its gradient
    G_i = sum_j (m_j/rho_j) (v_j - v_i) (x) grad W_ij (row a: grad v^a, eq 8), so the stretching
    G_i zeta^n_i, and zeta^n_i = curl v^n (Algorithm 2's first line) as G's antisymmetric part: the
    same sum as eq 6. The artificial Laplacian (eq 10) is taken of the shared field curl v~, the
    vorticity before this step's refinement, because the refined one at the neighbours would cost a
    pass of its own; the two differ by alpha d zeta, whose diffusion over one step is
    O(nu dt / h^2) smaller (<= 1/8 under the viscous time-step limit).

    zeta^n is what the refinement realised, not what it asked for (curl v~ + alpha d zeta): the
    stream function summed within h realises only part of d zeta, and the unrealised part would
    come back in the next d zeta multiplied by alpha; with alpha > 1 that grew 1.2x a step until
    a dam break blew up (alpha 1.2, 1.3, 2)."""
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    zi = vorticity[i]
    lap = wp.vec3(0.0)
    grad = wp.mat33(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        x_ij = separation(nb, xi, x[j])
        volume = particle_mass / density[j]
        gw = cubic_kernel_gradient(x_ij, support_radius)
        lap += artificial_laplacian(zi - vorticity[j], x_ij, gw, volume, support_radius)
        grad -= volume * wp.outer(vi - v[j], gw)
    refined = curl_of_gradient(grad)
    target[i] = refined + dt[0] * (grad * refined + viscosity * lap)


@wp.kernel
def apply_vorticity_refinement(
    x: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    stream_function: wp.array(dtype=wp.vec3),
    particle_mass: float,
    alpha: float,
    support_radius: float,
    v: wp.array(dtype=wp.vec3),
):
    """dv_i = sum_j (m_j / rho_j) (psi_i - psi_j) x grad W_ij (eq 16), the SPH curl of psi;
    v_i <- v~_i + alpha dv_i (eq 17)."""
    i = wp.tid()
    v[i] = v[i] + alpha * sph_curl(i, x, stream_function, density, nb, particle_mass, support_radius)
