"""Divergence-free solver of DFSPH: drives D rho/Dt to zero by velocity-based pressure."""

import warp as wp

from .particles import Boundary, Neighbours
from .pressure import density_rate

wp.set_module_options({"enable_backward": False})

# SPlisHSPlasH skips particles with fewer neighbours than this in 3D: near the free
# surface their density rate is not a reliable divergence estimate.
MIN_NEIGHBOURS = wp.constant(20)


@wp.kernel
def compute_divergence_source(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    factor: wp.array(dtype=float),
    fluid_volume: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    clamp: int,
    error: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
):
    """Source s_i = max(D(rho_i/rho0)/Dt, 0) (compression only; ``clamp`` 0: the signed
    D(rho_i/rho0)/Dt, for confined flows) and k_i = s_i factor_i / dt."""
    i = wp.tid()
    count = nb.fluid_offsets[i + 1] - nb.fluid_offsets[i] + nb.boundary_offsets[i + 1] - nb.boundary_offsets[i]
    s = float(0.0)
    if count >= MIN_NEIGHBOURS:
        s = density_rate(i, x, v, nb, boundary, fluid_volume, support_radius)
        if clamp != 0:
            s = wp.max(s, 0.0)
    error[i] = s
    stiffness[i] = s * factor[i] / dt[0]
