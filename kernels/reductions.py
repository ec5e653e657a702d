"""Sums and maxima over all particles: the solvers' error, the signed source's sum, the CFL speed.

Each kernel is launched on exactly ``REDUCE_THREADS`` threads, each summing a grid stride of the values; it allocates
nothing, so it can sit inside a captured ``wp.capture_while`` body (``wp.utils.array_sum`` cannot). There are two
builds of the same kernels (:func:`reduction_kernels`), one a Warp module each:

- this module's: one atomic per thread, for the CPU, whose threads run one after the other;
- :mod:`block_reductions`'s: one atomic per block through Warp's tile sums, for CUDA (16384 atomics on one address
  took 0.055 ms a launch at 1M particles on an H100; 0.36 ms a step in the error sums).

Tile code makes a module slow to compile (a one-kernel module: 1.3 s against 0.4 s through NVRTC, 2.9 s against
0.15 s through Warp's CPU compiler), so only the CUDA build has it, and a CPU run never compiles it.
:func:`for_device` gives a device's build.
"""

from types import SimpleNamespace

import warp as wp

wp.set_module_options({"enable_backward": False})

DEVICES = ("cpu",)  # the build compiled for these devices (warpsph.warmup)

# threads of the grid-stride reductions; each strides over n / REDUCE_THREADS values. They are launched on exactly
# this many threads (a whole number of blocks: the block sums are cooperative). 4096 left most of an H100 idle
# (0.09 ms for 1M values, five times a step).
REDUCE_THREADS = wp.constant(16384)


@wp.func
def block_sum(value: float):
    """The sum of ``value`` over the threads of the block, in its first thread (:func:`first_in_block`); every
    thread of the block must call it."""
    return wp.tile_sum(wp.tile(value))[0]


@wp.func
def block_max(value: float):
    """The largest ``value`` over the threads of the block, in its first thread; as :func:`block_sum`."""
    return wp.tile_max(wp.tile(value))[0]


@wp.func
def first_in_block(t: int):
    """Whether thread ``t`` holds its block's :func:`block_sum` and :func:`block_max`."""
    return t % wp.block_dim() == 0


def reduction_kernels(per_block: bool, module: str) -> SimpleNamespace:
    """The reduction kernels, registered in the Warp module named ``module``: with ``per_block`` one atomic per
    block of the threads' partial results (tile sums), else one per thread."""

    @wp.func(module=module)
    def total(value: float, t: int):
        """(what thread ``t`` adds, whether it adds): the block's sum in its first thread, or its own value."""
        if wp.static(per_block):
            return block_sum(value), first_in_block(t)
        return value, True

    @wp.func(module=module)
    def largest(value: float, t: int):
        """As ``total``, for a maximum."""
        if wp.static(per_block):
            return block_max(value), first_in_block(t)
        return value, True

    @wp.kernel(module=module, enable_backward=False)
    def reduce_error(error: wp.array(dtype=float), count: int, error_stats: wp.array(dtype=float)):
        """error_stats[0] += sum |e|, error_stats[1] = max(error_stats[1], max |e|) (update_solver_status resets
        both after reading)."""
        t = wp.tid()
        s = float(0.0)
        m = float(0.0)
        for i in range(t, count, REDUCE_THREADS):
            e = wp.abs(error[i])
            s += e
            m = wp.max(m, e)
        s, adds = total(s, t)
        m, adds = largest(m, t)
        if adds:
            wp.atomic_add(error_stats, 0, s)
            wp.atomic_max(error_stats, 1, m)

    @wp.kernel(module=module, enable_backward=False)
    def reduce_source_sum(source: wp.array(dtype=float), count: int, free_surface: wp.array(dtype=wp.int32),
                          error_stats: wp.array(dtype=float)):
        """error_stats[2] += sum of the signed source, in a box without free surface (``free_surface[0]`` 0;
        update_solver_status resets it)."""
        t = wp.tid()
        s = float(0.0)
        if free_surface[0] == 0:
            for i in range(t, count, REDUCE_THREADS):
                s += source[i]
        s, adds = total(s, t)
        if adds and free_surface[0] == 0:
            wp.atomic_add(error_stats, 2, s)

    @wp.kernel(module=module, enable_backward=False)
    def compute_max_speed(v: wp.array(dtype=wp.vec3), count: int, gravity: wp.vec3, dt: wp.array(dtype=float),
                          max_speed_sq: wp.array(dtype=float)):
        """max_speed_sq[0] = max_i |v_i|^2 and max_speed_sq[1] = max_i |v_i + g dt|^2 with ``dt`` the last step's
        (reset both to 0 first; the second is SPlisHSPlasH's CFL speed |v + a h|, its a the gravity here)."""
        t = wp.tid()
        shift = gravity * dt[0]
        m = float(0.0)
        m_cfl = float(0.0)
        for i in range(t, count, REDUCE_THREADS):
            m = wp.max(m, wp.length_sq(v[i]))
            m_cfl = wp.max(m_cfl, wp.length_sq(v[i] + shift))
        m, adds = largest(m, t)
        m_cfl, adds = largest(m_cfl, t)
        if adds:
            wp.atomic_max(max_speed_sq, 0, m)
            wp.atomic_max(max_speed_sq, 1, m_cfl)

    @wp.kernel(module=module, enable_backward=False)
    def compute_max_body_speed(v: wp.array(dtype=wp.vec3), count: int, max_speed_sq: wp.array(dtype=float)):
        """max_speed_sq[1] = max(max_speed_sq[1], max_i |v_i|^2) over moving bodies' boundary samples (SPlisHSPlasH's
        CFL speed takes the moving bodies' too)."""
        t = wp.tid()
        m = float(0.0)
        for i in range(t, count, REDUCE_THREADS):
            m = wp.max(m, wp.length_sq(v[i]))
        m, adds = largest(m, t)
        if adds:
            wp.atomic_max(max_speed_sq, 1, m)

    return SimpleNamespace(reduce_error=reduce_error, reduce_source_sum=reduce_source_sum,
                           compute_max_speed=compute_max_speed, compute_max_body_speed=compute_max_body_speed)


per_thread = reduction_kernels(per_block=False, module=__name__)


def for_device(device) -> SimpleNamespace:
    """The reduction kernels to launch on ``device`` (a Warp device or its alias): the block build on CUDA."""
    if wp.get_device(device).is_cuda:
        from . import block_reductions

        return block_reductions.kernels
    return per_thread
