"""Divergence-free solver of DFSPH: drives D rho/Dt to zero by velocity-based pressure."""

import warp as wp

from .pressure import density_rate

wp.set_module_options({"enable_backward": False})

# SPlisHSPlasH skips particles with fewer neighbours than this in 3D: near the free
# surface their density rate is not a reliable divergence estimate.
MIN_NEIGHBOURS = wp.constant(20)


@wp.kernel
def compute_divergence_source(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    fluid_offsets: wp.array(dtype=wp.int32),
    fluid_neighbours: wp.array(dtype=wp.int32),
    boundary_x: wp.array(dtype=wp.vec3),
    boundary_v: wp.array(dtype=wp.vec3),
    boundary_volume: wp.array(dtype=float),
    boundary_offsets: wp.array(dtype=wp.int32),
    boundary_neighbours: wp.array(dtype=wp.int32),
    factor: wp.array(dtype=float),
    fluid_volume: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    error: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
):
    """Source s_i = max(D(rho_i/rho0)/Dt, 0) (compression only) and k_i = s_i factor_i / dt."""
    i = wp.tid()
    count = fluid_offsets[i + 1] - fluid_offsets[i] + boundary_offsets[i + 1] - boundary_offsets[i]
    s = float(0.0)
    if count >= MIN_NEIGHBOURS:
        s = wp.max(
            density_rate(i, x, v, fluid_offsets, fluid_neighbours, boundary_x, boundary_v, boundary_volume,
                         boundary_offsets, boundary_neighbours, fluid_volume, support_radius),
            0.0,
        )
    error[i] = s
    stiffness[i] = s * factor[i] / dt[0]
