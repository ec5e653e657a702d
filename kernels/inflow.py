"""Inflow and outflow: particles driven in an emitter's box, particles inside a sink box or outside an open domain."""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def inside_box(p: wp.vec3, lo: wp.vec3, hi: wp.vec3):
    """Whether p lies in the axis-aligned box [lo, hi] (faces included)."""
    return p[0] >= lo[0] and p[0] <= hi[0] and p[1] >= lo[1] and p[1] <= hi[1] and p[2] >= lo[2] and p[2] <= hi[2]


@wp.func
def outside_box(p: wp.vec3, lo: wp.vec3, hi: wp.vec3):
    """Whether p lies beyond a face of [lo, hi] (a NaN position is not: the health check reports it)."""
    return p[0] < lo[0] or p[1] < lo[1] or p[2] < lo[2] or p[0] > hi[0] or p[1] > hi[1] or p[2] > hi[2]


@wp.kernel
def mark_particles_in_sinks(
    x: wp.array(dtype=wp.vec3),
    sink_min: wp.array(dtype=wp.vec3),
    sink_max: wp.array(dtype=wp.vec3),
    open_domain: int,
    domain_min: wp.vec3,
    domain_max: wp.vec3,
    keys: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    removed: wp.array(dtype=wp.int32),
):
    """keys[i] = 1 for a particle inside any sink box or, in an open domain, outside the domain
    box, else 0, and order[i] = i: sorting the pairs by key moves the survivors to the front in
    their current order; ``removed`` counts the rest: [0] in sinks, [1] outside the domain."""
    i = wp.tid()
    p = x[i]
    inside = int(0)
    for s in range(sink_min.shape[0]):
        if inside_box(p, sink_min[s], sink_max[s]):
            inside = 1
    if inside != 0:
        wp.atomic_add(removed, 0, 1)
    elif open_domain != 0 and outside_box(p, domain_min, domain_max):
        inside = 1
        wp.atomic_add(removed, 1, 1)
    keys[i] = inside
    order[i] = i


@wp.kernel
def drive_inflow_particles(
    x: wp.array(dtype=wp.vec3),
    lo: wp.vec3,
    hi: wp.vec3,
    velocity: wp.vec3,
    v: wp.array(dtype=wp.vec3),
):
    """Particles inside an emitter's driving box move at the emitter's velocity (as SPlisHSPlasH's
    emitters do): the layers leave at the speed they were spaced for, so a new layer never lands
    on one that the fluid ahead slowed down."""
    i = wp.tid()
    if inside_box(x[i], lo, hi):
        v[i] = velocity
