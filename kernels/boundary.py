"""Akinci et al. 2012 boundary particles: their volumes and the fluid-boundary neighbour sums."""

import warp as wp

from .neighbours import CellGrid, cell_coords, cell_index, cell_run_start, image_shift
from .sph_kernel import cubic_kernel, cubic_kernel_zero

wp.set_module_options({"enable_backward": False})


@wp.kernel
def compute_boundary_volume(
    grid: CellGrid,
    boundary_x: wp.array(dtype=wp.vec3),
    sample_body: wp.array(dtype=wp.int32),
    first_moving_body: int,
    support_radius: float,
    lower: wp.vec3,
    period: wp.vec3,
    boundary_volume: wp.array(dtype=float),
):
    """Boundary volume V_b = 1 / (W(0) + sum_k W(x_b - x_k)) over boundary neighbours k (Akinci 2012).

    Computed once, never per step: the static samples weigh each other (walls and fixed obstacles
    meet in corners); a moving body's samples weigh only their own body's, so V_b is a body-space
    quantity that holds wherever the body goes. Across periodic faces the samples' images count.
    """
    b = wp.tid()
    x = boundary_x[b]
    body = sample_body[b]
    s = cubic_kernel_zero(support_radius)
    for image in range(27):
        shift = image_shift(x, lower, period, support_radius, image)
        if wp.isnan(shift[0]):
            continue
        xs = x + shift
        lo = cell_coords(grid, xs - wp.vec3(support_radius))
        hi = cell_coords(grid, xs + wp.vec3(support_radius))
        for cz in range(lo[2], hi[2] + 1):
            for cy in range(lo[1], hi[1] + 1):
                row = cell_index(grid, wp.vec3i(0, cy, cz))
                for r in range(cell_run_start(grid, row + lo[0]), grid.cell_end[row + hi[0]]):
                    k = grid.ids[r]
                    other = sample_body[k]
                    same_group = other == body or (other < first_moving_body and body < first_moving_body)
                    if (k != b or image != 13) and same_group:
                        s += cubic_kernel(wp.length(xs - boundary_x[k]), support_radius)
    boundary_volume[b] = 1.0 / s
