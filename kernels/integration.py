"""Time integration: CFL time step, velocity prediction with gravity, advection, clock."""

import warp as wp

from .particles import keep_in_domain
from .pressure import REDUCE_THREADS, block_max, first_in_block

wp.set_module_options({"enable_backward": False})


@wp.kernel
def compute_max_speed(
    v: wp.array(dtype=wp.vec3),
    count: int,
    gravity: wp.vec3,
    dt: wp.array(dtype=float),
    viscous_rate: wp.array(dtype=float),
    max_speed_sq: wp.array(dtype=float),
):
    """max_speed_sq[0] = max_i |v_i|^2 and max_speed_sq[1] = max_i |v_i + g dt|^2 with ``dt`` the last step's (reset
    both to 0 first; the second is SPlisHSPlasH's CFL speed |v + a h|, its a the gravity here), and with
    ``viscous_rate`` (not empty) max_speed_sq[2] = its largest value: launched on REDUCE_THREADS threads, grid-stride,
    one atomic per block and value (one atomic per particle on one address took 0.45 ms at 1M on an H100, 7 % of a
    step)."""
    t = wp.tid()
    shift = gravity * dt[0]
    with_rate = viscous_rate.shape[0] > 0
    m = float(0.0)
    m_cfl = float(0.0)
    rate = float(0.0)
    for i in range(t, count, REDUCE_THREADS):
        m = wp.max(m, wp.length_sq(v[i]))
        m_cfl = wp.max(m_cfl, wp.length_sq(v[i] + shift))
        if with_rate:
            rate = wp.max(rate, viscous_rate[i])
    m = block_max(m)
    m_cfl = block_max(m_cfl)
    if first_in_block(t):
        wp.atomic_max(max_speed_sq, 0, m)
        wp.atomic_max(max_speed_sq, 1, m_cfl)
    if with_rate:
        rate = block_max(rate)
        if first_in_block(t):
            wp.atomic_max(max_speed_sq, 2, rate)


@wp.kernel
def compute_max_body_speed(v: wp.array(dtype=wp.vec3), count: int, max_speed_sq: wp.array(dtype=float)):
    """max_speed_sq[1] = max(max_speed_sq[1], max_i |v_i|^2) over moving bodies' boundary samples (SPlisHSPlasH's CFL
    speed takes the moving bodies' too): launched on REDUCE_THREADS threads, as :data:`compute_max_speed`."""
    t = wp.tid()
    m = float(0.0)
    for i in range(t, count, REDUCE_THREADS):
        m = wp.max(m, wp.length_sq(v[i]))
    m = block_max(m)
    if first_in_block(t):
        wp.atomic_max(max_speed_sq, 1, m)


# dt x the viscosity's largest rate at most (explicit Euler is stable to 2): Morris et al.'s 0.125 (H/2)^2 / nu
# on a lattice, where the rate is 2 / (1.14 x that dt)
VISCOUS_MARGIN = wp.constant(1.9)


@wp.kernel
def compute_time_step(
    max_speed_sq: wp.array(dtype=float),
    particle_diameter: float,
    cfl_factor: float,
    dt_min: float,
    dt_max: float,
    fixed_dt: float,
    viscous_dt: float,
    max_substeps: int,
    dt_scale: float,
    dt_previous: wp.array(dtype=float),
    dt: wp.array(dtype=float),
    substeps: wp.array(dtype=wp.int32),
    substep_dt: wp.array(dtype=float),
):
    """One thread: dt = clamp(min(cfl * 0.4 * d / u, max_substeps x h_visc), dt_min, dt_max), u =
    sqrt(max_speed_sq[1]) the largest of |v + g dt_last| over the fluid and |v| over moving bodies (SPlisHSPlasH's
    CFL rule, Simulation::updateTimeStepSizeCFL, and the explicit-viscosity limit, which the viscosity's sub-steps
    stretch; SPlisHSPlasH has no viscous limit), or ``fixed_dt`` when it is positive, times ``dt_scale`` (< 1 when a
    step is retried after an instability); the old dt moves to ``dt_previous``. h_visc = min(``viscous_dt``,
    VISCOUS_MARGIN / max_speed_sq[2]) where the density pass bounded the viscosity's largest rate in max_speed_sq[2]
    (a lattice's ``viscous_dt``, Morris et al.'s, is only 1.14x below its stability limit 2 / rate; a compressed pair
    exceeds it). With ``substeps`` (not empty): the viscosity's sub-steps n = ceil(dt / h_visc), at most
    ``max_substeps``, and their dt / n into ``substep_dt``."""
    h_visc = viscous_dt
    if max_speed_sq.shape[0] > 2:
        if max_speed_sq[2] > 0.0:
            h_visc = wp.min(h_visc, VISCOUS_MARGIN / max_speed_sq[2])
    if dt[0] > 0.0:
        dt_previous[0] = dt[0]
    if fixed_dt > 0.0:
        dt[0] = fixed_dt * dt_scale
    else:
        speed = wp.sqrt(max_speed_sq[1])
        h = dt_max
        if speed > 1.0e-9:
            h = cfl_factor * 0.4 * particle_diameter / speed
        h = wp.min(h, h_visc * float(max_substeps))
        dt[0] = wp.clamp(h, dt_min, dt_max) * dt_scale
    if substeps.shape[0] > 0:
        n = wp.min(max_substeps, wp.max(1, int(wp.ceil(dt[0] / h_visc * (1.0 - 1.0e-5)))))
        substeps[0] = n
        substep_dt[0] = dt[0] / float(n)


@wp.kernel
def start_substeps(substeps: wp.array(dtype=wp.int32), left: wp.array(dtype=wp.int32)):
    """One thread: ``left`` = this step's viscosity sub-steps (the loop's condition)."""
    left[0] = substeps[0]


@wp.kernel
def advance_substep(
    acceleration: wp.array(dtype=wp.vec3),
    substep_dt: wp.array(dtype=float),
    v: wp.array(dtype=wp.vec3),
):
    """v += (dt / n) a_visc: one sub-step of the explicit viscosity."""
    i = wp.tid()
    v[i] = v[i] + substep_dt[0] * acceleration[i]


@wp.kernel
def count_down(left: wp.array(dtype=wp.int32)):
    """One thread: one sub-step fewer left."""
    left[0] = left[0] - 1


@wp.kernel
def predict_velocity(
    acceleration: wp.array(dtype=wp.vec3),
    gravity: wp.vec3,
    dt: wp.array(dtype=float),
    v: wp.array(dtype=wp.vec3),
):
    """v~ = v^n + dt (a_adv + g) (Algorithm 1, advection)."""
    i = wp.tid()
    v[i] = v[i] + dt[0] * (acceleration[i] + gravity)


@wp.kernel
def advect_positions(
    v: wp.array(dtype=wp.vec3),
    dt: wp.array(dtype=float),
    lower: wp.vec3,
    period: wp.vec3,
    inside_lo: wp.vec3,
    inside_hi: wp.vec3,
    x: wp.array(dtype=wp.vec3),
):
    """x^{n+1} = x^n + dt v (after the density solve), wrapped into the domain along periodic axes and held
    inside its walled faces, where the velocity into the wall is removed."""
    i = wp.tid()
    moved = x[i] + dt[0] * v[i]
    kept = keep_in_domain(moved, lower, period, inside_lo, inside_hi)
    vi = v[i]
    for k in range(3):
        if (moved[k] < inside_lo[k] and vi[k] < 0.0) or (moved[k] > inside_hi[k] and vi[k] > 0.0):
            vi[k] = 0.0
    v[i] = vi
    x[i] = kept


@wp.kernel
def advance_clock(dt: wp.array(dtype=float), time: wp.array(dtype=wp.float64), steps: wp.array(dtype=wp.int64)):
    """One thread: t += dt, step += 1, kept on the device so a step needs no host sync."""
    time[0] = time[0] + wp.float64(dt[0])
    steps[0] = steps[0] + wp.int64(1)
