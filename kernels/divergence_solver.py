"""Divergence-free solver of DFSPH: drives D rho/Dt to zero by velocity-based pressure."""

import warp as wp

from .particles import Boundary, Neighbours, SymmetricMatrix
from .pressure import clamped, corrected_density_rate, density_rate, pressure_source, relaxed_stiffness

wp.set_module_options({"enable_backward": False})

# SPlisHSPlasH skips particles with fewer neighbours than this in 3D: near the free
# surface their density rate is not a reliable divergence estimate.
MIN_NEIGHBOURS = wp.constant(20)


def _divergence_source_kernel(corrected: bool):
    @wp.kernel
    def compute_divergence_source(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        nb: Neighbours,
        boundary: Boundary,
        factor: wp.array(dtype=float),
        surface: wp.array(dtype=wp.int32),
        free_surface: wp.array(dtype=wp.int32),
        fluid_volume: float,
        support_radius: float,
        dt: wp.array(dtype=float),
        correction: wp.array(dtype=SymmetricMatrix),
        error: wp.array(dtype=float),
        stiffness: wp.array(dtype=float),
    ):
        """Source s_i = D(rho_i/rho0)/Dt (Bender & Koschier 2017, eq 9), clamped at >= 0 at the free
        surface and signed in the bulk (:func:`pressure_source`), and k_i from :func:`relaxed_stiffness`. The solver
        launches :data:`compute_corrected_divergence_source`, which takes the rate with the corrected gradient
        ``correction`` (:func:`compute_gradient_correction`); the plain kernel does not read it."""
        i = wp.tid()
        count = nb.fluid_offsets[i + 1] - nb.fluid_offsets[i] + nb.boundary_offsets[i + 1] - nb.boundary_offsets[i]
        s = float(0.0)
        is_clamped = clamped(surface[i], free_surface)
        if count >= MIN_NEIGHBOURS:
            rate = float(0.0)
            if wp.static(corrected):
                rate = corrected_density_rate(i, x, v, nb, boundary, correction, fluid_volume, support_radius)
            else:
                rate = density_rate(i, x, v, nb, boundary, fluid_volume, support_radius)
            s = pressure_source(rate, is_clamped)
        error[i] = s
        stiffness[i] = relaxed_stiffness(s, is_clamped, factor[i], dt[0])

    return compute_divergence_source


compute_divergence_source = _divergence_source_kernel(False)
compute_corrected_divergence_source = _divergence_source_kernel(True)
