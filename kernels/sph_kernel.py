"""Cubic spline smoothing kernel W and its gradient (VR paper, the kernel after eq 2).

The paper writes the kernel with smoothing length h and support 2h; we use the
equivalent normalised form with *support radius* ``H = 2h = 4 r`` (``r`` the particle
radius), as SPlisHSPlasH does. All kernels in this package take ``H``.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

PI = wp.constant(3.14159265358979)


@wp.func
def cubic_kernel(r: float, H: float):
    """W(r) of the cubic spline with support radius H, normalised to integrate to 1 in 3D."""
    q = r / H
    k = 8.0 / (PI * H * H * H)
    if q <= 0.5:
        return k * (6.0 * q * q * q - 6.0 * q * q + 1.0)
    if q <= 1.0:
        s = 1.0 - q
        return k * 2.0 * s * s * s
    return 0.0


@wp.func
def cubic_kernel_gradient(x_ij: wp.vec3, H: float):
    """Gradient of W with respect to x_i for the offset x_ij = x_i - x_j (one division: it runs
    once per neighbour in almost every pass)."""
    r = wp.length(x_ij)
    if r < 1.0e-9 * H or r > H:
        return wp.vec3(0.0)
    inverse_h = 1.0 / H  # loop-invariant in the callers' neighbour loops
    q = r * inverse_h
    l = 48.0 / PI * inverse_h * inverse_h * inverse_h
    grad_q = x_ij * (inverse_h / r)
    if q <= 0.5:
        return l * q * (3.0 * q - 2.0) * grad_q
    s = 1.0 - q
    return -l * s * s * grad_q


@wp.func
def cubic_kernel_zero(H: float):
    """W(0), the self contribution of a particle to its own density."""
    return 8.0 / (PI * H * H * H)
