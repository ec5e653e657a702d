"""Cheap per-step health checks on the device: NaN/inf, escaped particles, runaway density."""

import warp as wp

wp.set_module_options({"enable_backward": False})

NOT_FINITE = wp.constant(1)
OUTSIDE_DOMAIN = wp.constant(2)
DENSITY_LIMIT = wp.constant(3)


@wp.func
def finite3(a: wp.vec3):
    return wp.isfinite(a[0]) and wp.isfinite(a[1]) and wp.isfinite(a[2])


@wp.kernel
def check_particles(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    lower: wp.vec3,
    upper: wp.vec3,
    density_limit: float,
    counts: wp.array(dtype=wp.int32),
    first: wp.array(dtype=wp.int32),
):
    """counts[c] = particles failing check c, first[c] = the lowest such index (reset both first)."""
    i = wp.tid()
    xi = x[i]
    check = int(0)
    if not (finite3(xi) and finite3(v[i]) and wp.isfinite(density[i])):
        check = NOT_FINITE
    elif xi[0] < lower[0] or xi[1] < lower[1] or xi[2] < lower[2] or xi[0] > upper[0] or xi[1] > upper[1] or xi[2] > upper[2]:
        check = OUTSIDE_DOMAIN
    elif density[i] > density_limit:
        check = DENSITY_LIMIT
    if check != 0:
        wp.atomic_add(counts, check, 1)
        wp.atomic_min(first, check, i)
