"""Constant-density solver of DFSPH: drives the predicted density rho* to rho0."""

import warp as wp

from .particles import Boundary, Neighbours, SymmetricMatrix
from .pressure import clamped, corrected_density_rate, density_rate, pressure_source, relaxed_stiffness

wp.set_module_options({"enable_backward": False})


def _density_source_kernel(corrected: bool):
    @wp.kernel
    def compute_density_source(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        nb: Neighbours,
        boundary: Boundary,
        density: wp.array(dtype=float),
        factor: wp.array(dtype=float),
        surface: wp.array(dtype=wp.int32),
        free_surface: wp.array(dtype=wp.int32),
        fluid_volume: float,
        rest_density: float,
        support_radius: float,
        dt: wp.array(dtype=float),
        drift_weight: float,
        correction: wp.array(dtype=SymmetricMatrix),
        error: wp.array(dtype=float),
        stiffness: wp.array(dtype=float),
    ):
        """Predicted density rho*_i/rho0 = rho_i/rho0 + dt D(rho_i/rho0)/Dt (Bender & Koschier 2017, eq 11), with the
        step's starting error rho_i/rho0 - 1 weighted by ``drift_weight`` (1; 0 and 1 in the two halves of the
        split solve of a periodic box, warpsph/solvers/dfsph.py). Every solve but the periodic box's drift half uses
        :data:`compute_corrected_density_source`, which takes the rate with the corrected gradient ``correction``
        (the identity outside the bulk), L_i of :func:`compute_gradient_correction` (the plain kernel does not
        read it). Source s_i = rho*_i/rho0 - 1, clamped at >= 0 at the free surface and signed in the bulk
        (:func:`pressure_source`), and k_i from :func:`relaxed_stiffness`."""
        i = wp.tid()
        h = dt[0]
        is_clamped = clamped(surface[i], free_surface)
        rate = float(0.0)
        if wp.static(corrected):
            rate = corrected_density_rate(i, x, v, nb, boundary, correction, fluid_volume, support_radius)
        else:
            rate = density_rate(i, x, v, nb, boundary, fluid_volume, support_radius)
        predicted = density[i] / rest_density + h * rate
        if drift_weight != 1.0:
            predicted -= (1.0 - drift_weight) * (density[i] / rest_density - 1.0)
        s = pressure_source(predicted - 1.0, is_clamped)
        error[i] = s
        stiffness[i] = relaxed_stiffness(s, is_clamped, factor[i], h * h)

    return compute_density_source


compute_density_source = _density_source_kernel(False)
compute_corrected_density_source = _density_source_kernel(True)
