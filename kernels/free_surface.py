"""Free-surface detection for the pressure solver (Lind, Xu, Stansby & Rogers 2012; DualSPHysics'
shifting thresholds): a particle whose divergence of position is below its threshold and whose density
is below its own is on the free surface, one with such a particle within its support lies in the surface
band. Divergence of position alone does not separate the two at the cubic spline's ~33 neighbours: a
compressed bulk particle of a disordered distribution reaches 2.2 (Taylor-Green, 16 across), as low as a
flat surface (2.24 on the lattice), but its density is above rho0, where a surface particle's is 0.85 rho0
(lattice; 0.91 with its layer 10 % compressed) and the bulk's stays above 0.96 rho0. Both keep p >= 0 and
are not shifted across the surface; the rest of the fluid (the bulk) has signed pressure."""

import warp as wp

from .particles import Neighbours

wp.set_module_options({"enable_backward": False})

BULK = wp.constant(0)
BAND = wp.constant(1)
SURFACE = wp.constant(2)
WALL = wp.constant(3)  # bulk particle with boundary samples in its support: signed pressure, tangential shift


@wp.func
def off_surface(flag: wp.int32):
    """Whether a particle flagged ``flag`` lies away from the free surface and its band (BULK or WALL): where
    the corrected operators act."""
    return flag != SURFACE and flag != BAND


@wp.func
def on_free_surface(i: int, position_divergence: wp.array(dtype=float), density: wp.array(dtype=float),
                    concentration_gradient: wp.array(dtype=wp.vec3), down: wp.vec3, threshold: float,
                    density_threshold: float, gradient_threshold: float):
    """div r_i < threshold, and rho_i < density_threshold or grad C_i . down > gradient_threshold (``down``: the
    unit vector of gravity, zero without it). Under gravity the solver presses a resting surface down to rho0 (a
    standing wave's top layer: 0.9987 rho0 at the median), where the density test alone lost every surface
    particle and the bulk's signed pressure then pulled at the surface until the solve stalled; its one-sided
    support still shows in grad C, which points down into the fluid there (|grad C| 0.44 / d at the median, at
    most 0.07 / d in the bulk below). Stretched particles of a vortex core reach 0.2 / d in any direction: along
    gravity only, they do not pass for a surface (a full tank switched to p >= 0 for a step and blew up)."""
    if position_divergence[i] >= threshold:
        return False
    return density[i] < density_threshold or wp.dot(concentration_gradient[i], down) > gradient_threshold


@wp.kernel
def classify_free_surface(
    position_divergence: wp.array(dtype=float),
    density: wp.array(dtype=float),
    concentration_gradient: wp.array(dtype=wp.vec3),
    down: wp.vec3,
    nb: Neighbours,
    threshold: float,
    density_threshold: float,
    gradient_threshold: float,
    surface: wp.array(dtype=wp.int32),
    surface_count: wp.array(dtype=wp.int32),
    free_surface: wp.array(dtype=wp.int32),
):
    """surface_i = SURFACE where :func:`on_free_surface` (counted in ``surface_count[0]``), BAND where a fluid
    neighbour is, WALL where boundary samples are in the support, else BULK. A surface particle also sets
    ``free_surface[0]`` (which the solver sets beforehand: 1 under gravity, else 0)."""
    i = wp.tid()
    flag = int(BULK)
    if on_free_surface(i, position_divergence, density, concentration_gradient, down, threshold, density_threshold,
                       gradient_threshold):
        flag = SURFACE
        wp.atomic_add(surface_count, 0, 1)
        free_surface[0] = 1
    else:
        for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
            if on_free_surface(nb.fluid[k], position_divergence, density, concentration_gradient, down, threshold,
                               density_threshold, gradient_threshold):
                flag = BAND
                break
    if flag == BULK and nb.boundary_offsets[i + 1] > nb.boundary_offsets[i]:
        flag = WALL
    surface[i] = flag
