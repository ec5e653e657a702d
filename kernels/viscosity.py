"""The viscous Laplacian: the artificial viscosity of the VR paper (eq 4, after Koschier et al. 2019), and away from the
free surface the divergence of the corrected strain rate, div (2 S), with eq 4 on its gradient-corrected residual.
"""

import warp as wp

from .free_surface import SURFACE, off_surface
from .particles import Boundary, Neighbours, SymmetricMatrix, boundary_velocity, pack_symmetric, separation, symmetric_quadratic, symmetric_times
from .sph_kernel import cubic_kernel_gradient
from .vorticity import curl_term

wp.set_module_options({"enable_backward": False})



@wp.func
def residual_laplacian(a_dot_x: float, x_ij: wp.vec3, grad_w: wp.vec3, volume_j: float, support_radius: float):
    """:func:`artificial_laplacian` given A_ij . x_ij."""
    h2 = support_radius * support_radius
    return (10.0 * volume_j * a_dot_x / (wp.dot(x_ij, x_ij) + 0.01 * h2)) * grad_w


@wp.func
def artificial_laplacian(a_ij: wp.vec3, x_ij: wp.vec3, grad_w: wp.vec3, volume_j: float, support_radius: float):
    """One neighbour's term of eq 4: 2(d+2) V_j (A_ij . x_ij) / (|x_ij|^2 + 0.01 H^2) grad W_ij, d = 3.

    Shared by the viscosity of v (eq 4) and the vorticity Laplacian (eq 10); ``grad_w`` is grad W_ij,
    which the callers' loops also use for other sums."""
    return residual_laplacian(wp.dot(a_ij, x_ij), x_ij, grad_w, volume_j, support_radius)


@wp.kernel
def compute_strain_rate(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    nb: Neighbours,
    particle_mass: float,
    rest_density: float,
    support_radius: float,
    surface: wp.array(dtype=wp.int32),
    strain_rate: wp.array(dtype=SymmetricMatrix),
    stress_correction: wp.array(dtype=SymmetricMatrix),
):
    """The strain rate S_i = (grad v_i + grad v_i^T) / 2 of grad v_i = (sum_f V_j (v_j - v_i) (x) grad W_ij) M_i^-1,
    M_i = sum_f V_j (x_j - x_i) (x) grad W_ij (Bonet & Lok 1999: exact for a linear field), V_j = m / rho_j; the
    plain sum where M_i is too thin to invert (|det M_i| <= 0.1). Fluid neighbours only: the walls enter through M_i's
    renormalisation. ``stress_correction``: L_i = M0_i^-T of the same pairs at the rest volume V0 = m / rho0 (the
    identity where M0_i is too thin), which the divergence of 2 S in :data:`add_corrected_viscosity_acceleration`
    takes. Zero strain rate (and the identity) on the free surface (``surface``): only bulk particles take the
    corrected operator, and their neighbours are bulk or band; a splash's thin M_i, near the threshold, turned
    rounding into jumps of the operator. The viscosity reads only S, the symmetric part of grad v."""
    i = wp.tid()
    if surface[i] == SURFACE:
        strain_rate[i] = SymmetricMatrix()
        stress_correction[i] = pack_symmetric(wp.identity(3, dtype=float))
        return
    xi = x[i]
    vi = v[i]
    g = wp.mat33(0.0)
    m = wp.mat33(0.0)
    m0 = wp.mat33(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        x_ij = separation(nb, xi, x[j])
        gw = cubic_kernel_gradient(x_ij, support_radius)
        volume = particle_mass / density[j]
        g += volume * wp.outer(v[j] - vi, gw)
        m -= volume * wp.outer(x_ij, gw)
        m0 -= wp.outer(x_ij, gw)
    if wp.abs(wp.determinant(m)) > 0.1:
        g = g * wp.inverse(m)
    strain_rate[i] = pack_symmetric(g)
    m0 = m0 * (particle_mass / rest_density)
    li = wp.identity(3, dtype=float)
    if wp.abs(wp.determinant(m0)) > 0.1:
        li = wp.transpose(wp.inverse(m0))
    stress_correction[i] = pack_symmetric(li)


# weight of eq 4 on the residual v_ij - (grad v_i + grad v_j)/2 x_ij in the corrected operator: 0.25 left
# Lamb-Oseen's core 7 % high at 32 across, 1 blew up at the viscous step from 128 across (docs/notes/solver.md)
CORRECTED_STABILISER = wp.constant(0.5)


def _viscosity_acceleration_kernel(corrected: bool):
    @wp.kernel(name="add_corrected_viscosity_acceleration" if corrected else "add_viscosity_acceleration")
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
        surface: wp.array(dtype=wp.int32),
        strain_rate: wp.array(dtype=SymmetricMatrix),
        stress_correction: wp.array(dtype=SymmetricMatrix),
        rest_density: float,
        acceleration: wp.array(dtype=wp.vec3),
        vorticity: wp.array(dtype=wp.vec3),
    ):
        """a_i += nu * laplacian(v)_i (eq 4) with the pair's mean volume (m / rho_i + m / rho_j) / 2 as the neighbour's
        (Morris et al. 1997 with mu = rho nu): the pair's forces are then equal and opposite along x_ij, so they exert
        no torque and no net force (with m / rho_j, pairs across the free surface's density drop to 0.8 rho0 took 0.4 %
        of a vortex's angular momentum by T below a surface); plus, with
        ``boundary_viscosity``, the same term against the boundary samples' velocities (V_b as volume):
        walls and moving bodies drag the fluid; a dynamic body's sample gets the opposite impulse.

        When a turbulence model needs it, the same neighbour loop also yields the vorticity
        zeta_i = sum_j (m_j/rho_j)(v_i - v_j) x grad W_ij (eq 6): one pass instead of two.

        :data:`add_corrected_viscosity_acceleration` takes, between two particles both away from the free surface and
        its band (``surface``; a pair that has one there takes eq 4 from both sides, so that the pair's forces are
        equal and opposite: with the choice made per particle, a walled channel gained 6 % of its momentum in 0.45 s),
        the divergence of the viscous stress 2 S, sum_j V0 (2 S_i L_i + 2 S_j L_j) grad W_ij (``strain_rate`` and
        ``stress_correction`` from :func:`compute_strain_rate`), which is the Laplacian where div v = 0, and adds eq 4
        of the residual v_ij - (grad v_i + grad v_j) x_ij / 2, weighted CORRECTED_STABILISER (eq 4 reads a_ij only
        through a_ij . x_ij, so of grad v only its symmetric part). Eq 4 acts as nu on an isotropic neighbourhood, but
        as 0.7 nu on a shear along particle rows and 1.4 nu at 45 degrees to them; a vortex lines its particles up
        along the streamlines, and Lamb-Oseen's core then decays as if nu were 0.83 nu. The stress's divergence is
        right in every orientation, and it keeps angular momentum: S is symmetric and L_i = M0_i^-T, so a particle's
        pair torques sum to ε : (S_i L_i M0_i^T) = ε : S_i = 0 (the componentwise Laplacian before it, along v_ij, took
        3.1-3.6 % of a vortex's angular momentum by T). Alone it lets particle noise grow (a velocity that alternates
        from particle to particle has no strain rate): eq 4 on the residual, zero on a linear field, damps that noise."""
        i = wp.tid()
        xi = x[i]
        vi = v[i]
        lap = wp.vec3(0.0)
        curl = wp.vec3(0.0)
        si = SymmetricMatrix()
        volume0 = particle_mass / rest_density
        own_volume = particle_mass / density[i]
        bulk = False  # the corrected operator away from the free surface and its band, eq 4 there
        if wp.static(corrected):
            si = strain_rate[i]
            bulk = off_surface(surface[i])
        for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
            j = nb.fluid[k]
            x_ij = separation(nb, xi, x[j])
            volume = particle_mass / density[j]
            pair_volume = 0.5 * (volume + own_volume)  # eq 4's (the vorticity keeps m / rho_j)
            v_ij = vi - v[j]
            gw = cubic_kernel_gradient(x_ij, support_radius)
            # a pair weighs the two operators by its particles' share of the bulk, the same from both sides (equal
            # and opposite forces: momentum is conserved)
            share = float(0.0)
            if wp.static(corrected):
                share = 0.5 * (wp.where(bulk, 1.0, 0.0) + wp.where(off_surface(surface[j]), 1.0, 0.0))
            if share > 0.0:
                # (v_ij - (grad v_i + grad v_j) x_ij / 2) . x_ij
                residual = wp.dot(v_ij, x_ij) - 0.5 * (symmetric_quadratic(si, x_ij) + symmetric_quadratic(strain_rate[j], x_ij))
                # div (2 S) = sum_j V0 (2 S_i L_i + 2 S_j L_j) grad W_ij
                stress = symmetric_times(si, symmetric_times(stress_correction[i], gw))
                stress += symmetric_times(strain_rate[j], symmetric_times(stress_correction[j], gw))
                lap += (2.0 * share * volume0) * stress
                lap += (share * CORRECTED_STABILISER) * residual_laplacian(residual, x_ij, gw, pair_volume, support_radius)
            if share < 1.0:
                lap += (1.0 - share) * artificial_laplacian(v_ij, x_ij, gw, pair_volume, support_radius)
            if with_vorticity != 0:
                curl += curl_term(v_ij, gw, volume)
        friction = wp.vec3(0.0)
        if boundary_viscosity > 0.0:
            for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
                b = nb.boundary[k]
                x_ib = separation(nb, xi, boundary.x[b])
                gw = cubic_kernel_gradient(x_ib, support_radius)
                term = boundary_viscosity * artificial_laplacian(vi - boundary_velocity(boundary, b), x_ib, gw,
                                                                 boundary.volume[b], support_radius)
                if b >= boundary.first_dynamic:
                    wp.atomic_add(boundary.impulse, b, -dt[0] * term)
                friction += term
        acceleration[i] = acceleration[i] + viscosity * lap + friction
        if with_vorticity != 0:
            vorticity[i] = curl

    return add_viscosity_acceleration


add_viscosity_acceleration = _viscosity_acceleration_kernel(False)
add_corrected_viscosity_acceleration = _viscosity_acceleration_kernel(True)
