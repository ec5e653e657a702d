"""Constant-density solver of DFSPH: drives the predicted density rho* to rho0."""

import warp as wp

from .particles import Boundary, Neighbours
from .pressure import density_rate

wp.set_module_options({"enable_backward": False})


@wp.kernel
def compute_density_source(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    density: wp.array(dtype=float),
    factor: wp.array(dtype=float),
    fluid_volume: float,
    rest_density: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    clamp: int,
    density_weight: float,
    error: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
):
    """Predicted density rho*_i/rho0 = 1 + w (rho_i/rho0 - 1) + dt D(rho_i/rho0)/Dt (``density_weight``
    w: 1, or less with the confined mode's transport velocity); source
    s_i = max(rho*_i/rho0 - 1, 0) (pressure clamped at >= 0; ``clamp`` 0: the signed
    rho*_i/rho0 - 1, for confined flows) and k_i = s_i factor_i / dt^2."""
    i = wp.tid()
    h = dt[0]
    relative = density[i] / rest_density
    if density_weight != 1.0:  # (so that the default stays bit-identical)
        relative = 1.0 + density_weight * (relative - 1.0)
    predicted = relative + h * density_rate(i, x, v, nb, boundary, fluid_volume, support_radius)
    s = predicted - 1.0
    if clamp != 0:
        s = wp.max(s, 0.0)
    error[i] = s
    stiffness[i] = s * factor[i] / (h * h)
