"""Shared pieces of the two DFSPH pressure solvers (Bender & Koschier 2015/2017).

Both solvers iterate: compute a per-particle source term and stiffness k_i from the
current velocities, then apply the pressure acceleration of k to the velocities.
``k`` is pressure over density squared (p / rho^2, per unit rest density), so the
value accumulated over a step is a physical pressure that warm-starts the next step.
"""

import warp as wp

from .density import dfsph_factor
from .free_surface import BULK, SURFACE, off_surface
from .particles import Boundary, Neighbours, SymmetricMatrix, boundary_velocity, pack_symmetric, separation, symmetric_times
from .sph_kernel import cubic_kernel, cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})


@wp.func
def density_rate(
    i: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    fluid_volume: float,
    support_radius: float,
):
    """D(rho_i/rho0)/Dt = sum_f V_j (v_i - v_j).grad W_ij + sum_b V_b (v_i - v_b).grad W_ib."""
    xi = x[i]
    vi = v[i]
    rate = float(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        rate += fluid_volume * wp.dot(vi - v[j], cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius))
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        rate += boundary.volume[b] * wp.dot(vi - boundary_velocity(boundary, b), cubic_kernel_gradient(separation(nb, xi, boundary.x[b]), support_radius))
    return rate


@wp.kernel
def compute_gradient_correction(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    surface: wp.array(dtype=wp.int32),
    fluid_volume: float,
    support_radius: float,
    correction: wp.array(dtype=SymmetricMatrix),
    factor: wp.array(dtype=float),
):
    """L_i = M_i^-T, M_i = sum_f V_j (x_j - x_i) (x) grad W_ij + sum_b V_b (x_b - x_i) (x) grad W_ib (Bonet & Lok
    1999): with it :func:`corrected_density_rate` is the divergence of every linear field exactly, whatever the
    arrangement. Only in the bulk (``surface`` BULK), blended to the identity by the kernel-weighted share of
    its fluid neighbours in the surface band: the identity on the free surface and its band (the support is cut
    there, and the plain gradient's missing-neighbour term is the surface condition DFSPH relies on), beside walls
    and bodies (WALL: with L_i there a box of half the water's density floated 0.13 of its height too deep, and
    the corner columns of a resting tank moved at 0.1 m/s), and where M_i is near singular. ``factor``: the DFSPH
    factor of the corrected solve, 1 / (|sum_f V_j L_i grad W_ij|^2 + sum_f |V_j L_i grad W_ij|^2), the diagonal of its divergence of its
    pressure force (:func:`apply_pressure_acceleration`), as the plain factor is of the plain pair."""
    i = wp.tid()
    xi = x[i]
    m = wp.mat33(0.0)
    g_sum = wp.vec3(0.0)  # sum_f V_j grad W_ij
    g_outer = wp.mat33(0.0)  # sum_f (V_j grad W_ij) (x) (V_j grad W_ij)
    whole = float(0.0)  # neighbours whose own support is whole (neither surface nor band), kernel-weighted
    weight = float(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        xij = separation(nb, xi, x[j])
        g = fluid_volume * cubic_kernel_gradient(xij, support_radius)
        m += wp.outer(-xij, g)
        g_sum += g
        g_outer += wp.outer(g, g)
        w = cubic_kernel(wp.length(xij), support_radius)
        weight += w
        if off_surface(surface[j]):
            whole += w
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        xib = separation(nb, xi, boundary.x[b])
        gb = boundary.volume[b] * cubic_kernel_gradient(xib, support_radius)
        m += wp.outer(-xib, gb)
        g_sum += gb
    li = wp.identity(3, dtype=float)
    if surface[i] == BULK and wp.abs(wp.determinant(m)) > 0.1:
        # blended to the identity by the band's share of the support: a whole inverse beside the band pushed it
        # (p >= 0 there cannot pull back) and a resting tank threw surface particles out at 0.3 m/s
        blend = whole / wp.max(weight, 1.0e-12)
        li = blend * wp.transpose(wp.inverse(m)) + (1.0 - blend) * wp.identity(3, dtype=float)
    correction[i] = pack_symmetric(li)  # M_i is symmetric (grad W_ij is along x_ij), so is L_i
    # sum_f |L_i V_j grad W_ij|^2 = L_i^T L_i : sum_f (V_j grad W_ij) (x) (V_j grad W_ij): one neighbour pass
    factor[i] = dfsph_factor(li * g_sum, wp.ddot(wp.transpose(li) * li, g_outer), support_radius)


@wp.func
def corrected_density_rate(
    i: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    correction: wp.array(dtype=SymmetricMatrix),
    fluid_volume: float,
    support_radius: float,
):
    """:func:`density_rate` with the corrected kernel gradient L_i grad W (:func:`compute_gradient_correction`):
    minus the divergence of v, exact for linear fields on any arrangement. L_i is symmetric: the sum is
    sum_j V_j (L_i (v_i - v_j)) . grad W_ij."""
    xi = x[i]
    vi = v[i]
    li = correction[i]
    rate = float(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        rate += fluid_volume * wp.dot(symmetric_times(li, vi - v[j]),
                                      cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius))
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        rate += boundary.volume[b] * wp.dot(symmetric_times(li, vi - boundary_velocity(boundary, b)),
                                            cubic_kernel_gradient(separation(nb, xi, boundary.x[b]), support_radius))
    return rate


def _pressure_acceleration_kernel(corrected: bool):
    @wp.kernel
    def apply_pressure_acceleration(
        stiffness: wp.array(dtype=float),
        x: wp.array(dtype=wp.vec3),
        nb: Neighbours,
        boundary: Boundary,
        fluid_volume: float,
        support_radius: float,
        dt: wp.array(dtype=float),
        accumulate: int,
        stiffness_sum: wp.array(dtype=float),
        correction: wp.array(dtype=SymmetricMatrix),
        v: wp.array(dtype=wp.vec3),
    ):
        """v_i -= dt (sum_f V_j (k_i + k_j) grad W_ij + sum_b V_b k_i grad W_ib).

        A boundary neighbour uses k_i only (Akinci 2012 mirroring); a sample of a dynamic body gets
        the equal and opposite impulse dt V_b k_i grad W_ib (per unit mass of i). With ``accumulate``
        set, k_i is added to ``stiffness_sum`` (the pressure used in this step, for warm start).

        :data:`apply_corrected_pressure_acceleration` (every solve but the periodic box's drift half) takes L_i of
        :func:`compute_gradient_correction` (the plain kernel does not read ``correction``): v_i -= dt
        (sum_f V_j (k_i L_i + k_j L_j) grad W_ij + sum_b V_b k_i L_i grad W_ib), the negative adjoint of
        :func:`corrected_density_rate`. So the pressure does no work on a velocity whose corrected divergence is
        zero, and the pair forces stay equal and opposite. Its Jacobi step needs the corrected factor of
        :func:`compute_gradient_correction`: with the plain factor it blew up Taylor-Green at 16 across."""
        i = wp.tid()
        ki = stiffness[i]
        xi = x[i]
        dv = wp.vec3(0.0)
        if wp.static(corrected):
            # sum_f V_j (k_i L_i + k_j L_j) grad W_ij: k_i L_i once on the sum of the gradients
            g_sum = wp.vec3(0.0)
            for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
                j = nb.fluid[k]
                grad = cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
                g_sum += grad
                dv += stiffness[j] * symmetric_times(correction[j], grad)
            dv = fluid_volume * (dv + ki * symmetric_times(correction[i], g_sum))
        else:
            for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
                j = nb.fluid[k]
                dv += fluid_volume * (ki + stiffness[j]) * cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
        for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
            b = nb.boundary[k]
            grad_b = cubic_kernel_gradient(separation(nb, xi, boundary.x[b]), support_radius)
            if wp.static(corrected):
                grad_b = symmetric_times(correction[i], grad_b)
            dvb = boundary.volume[b] * ki * grad_b
            if b >= boundary.first_dynamic:
                wp.atomic_add(boundary.impulse, b, dt[0] * dvb)
            dv += dvb
        v[i] = v[i] - dt[0] * dv
        if accumulate != 0:
            stiffness_sum[i] = stiffness_sum[i] + ki

    return apply_pressure_acceleration


apply_pressure_acceleration = _pressure_acceleration_kernel(False)
apply_corrected_pressure_acceleration = _pressure_acceleration_kernel(True)


# threads of the grid-stride reductions (error, max speed); each strides over n / REDUCE_THREADS values. They are
# launched on exactly this many threads (a whole number of blocks: the block sums are cooperative).
# 4096 left most of an H100 idle (0.09 ms for 1M values, five times a step).
REDUCE_THREADS = wp.constant(16384)


@wp.func
def block_sum(value: float):
    """The sum of ``value`` over the threads of the block, in its first thread (:func:`first_in_block`); every
    thread of the block must call it. The reductions add one atomic per block, not per thread: 16384 atomics on
    one address took 0.055 ms a launch at 1M on an H100, 0.36 ms a step in the error sums."""
    return wp.tile_sum(wp.tile(value))[0]


@wp.func
def block_max(value: float):
    """The largest ``value`` over the threads of the block, in its first thread; as :func:`block_sum`."""
    return wp.tile_max(wp.tile(value))[0]


@wp.func
def first_in_block(t: int):
    """Whether thread ``t`` holds its block's :func:`block_sum` and :func:`block_max`."""
    return t % wp.block_dim() == 0

# Where the pressure is signed (not :func:`clamped`) the Jacobi step is relaxed by this factor (the signed
# solve diverged at 0.6 and above on Taylor-Green, docs/notes/solver.md).
BULK_RELAXATION = wp.constant(0.5)


@wp.func
def clamped(surface: int, free_surface: wp.array(dtype=wp.int32)):
    """Whether particle i keeps p >= 0: on the free surface and in its band, and everywhere where
    ``free_surface[0]`` is set (DFSPHSolver.detect_free_surface: under gravity always, else when a particle is on
    a free surface). Signed bulk pressure in free-surface flow tripled the 1M dam break's density iterations
    (6.8 -> 20.8 a step, 5.7 -> 16.6 ms on the H100) with no gain in the front or the hydrostatic pressure, and a
    sealed tank under gravity whose last gap particle closed switched its whole bulk to signed pressure in one step
    (36 m/s at 32 across; docs/notes/solver.md), so only a periodic box or one without gravity and without free
    surface solves for signed pressure."""
    return not off_surface(surface) or free_surface[0] > 0


@wp.func
def pressure_source(s: float, is_clamped: bool):
    """The solver's source for particle i from its raw source s: max(s, 0) where :func:`clamped`
    (SPlisHSPlasH's clamping), else the signed s."""
    if is_clamped:
        return wp.max(s, 0.0)
    return s


@wp.func
def relaxed_stiffness(source: float, is_clamped: bool, factor: float, scale: float):
    """Jacobi step k_i = omega s_i factor_i / scale (omega 1 where the pressure is clamped, BULK_RELAXATION
    where it is signed; scale dt^2 for the density solver, dt for the divergence solver)."""
    omega = BULK_RELAXATION
    if is_clamped:
        omega = 1.0
    return omega * source * factor / scale


@wp.kernel
def reduce_error(error: wp.array(dtype=float), count: int, error_stats: wp.array(dtype=float)):
    """error_stats[0] += sum |e|, error_stats[1] = max(error_stats[1], max |e|) (update_solver_status
    resets both after reading). Launched on REDUCE_THREADS threads: grid-stride partial results, one atomic per
    block (:func:`block_sum`); unlike ``wp.utils.array_sum`` it allocates nothing, so it can sit inside a captured
    ``wp.capture_while`` body."""
    t = wp.tid()
    s = float(0.0)
    m = float(0.0)
    for i in range(t, count, REDUCE_THREADS):
        e = wp.abs(error[i])
        s += e
        m = wp.max(m, e)
    s = block_sum(s)
    m = block_max(m)
    if first_in_block(t):
        wp.atomic_add(error_stats, 0, s)
        wp.atomic_max(error_stats, 1, m)


@wp.kernel
def reduce_source_sum(source: wp.array(dtype=float), count: int, free_surface: wp.array(dtype=wp.int32),
                      error_stats: wp.array(dtype=float)):
    """error_stats[2] += sum of the signed source, in a box without free surface (``free_surface[0]`` 0;
    update_solver_status resets it). Grid-stride like :func:`reduce_error`; allocates nothing."""
    t = wp.tid()
    s = float(0.0)
    if free_surface[0] == 0:
        for i in range(t, count, REDUCE_THREADS):
            s += source[i]
    s = block_sum(s)
    if first_in_block(t) and free_surface[0] == 0:
        wp.atomic_add(error_stats, 2, s)


@wp.kernel
def remove_mean_source(
    error_stats: wp.array(dtype=float),
    count: int,
    free_surface: wp.array(dtype=wp.int32),
    factor: wp.array(dtype=float),
    dt: wp.array(dtype=float),
    per_unit_time: int,
    error: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
):
    """Compatibility condition of a step without free surface (``free_surface[0]`` 0) where the solver removes
    the source's mean (a periodic box, or a sealed box without gravity: DFSPHSolver._removes_mean): the pressure
    problem is (nearly) pure Neumann, a constant pressure moves nothing, so a source with a non-zero sum has no
    solution and Jacobi drifts. s_i := s_i - mean(s) (mean = error_stats[2] / count,
    from :func:`reduce_source_sum`), and k_i again from :func:`relaxed_stiffness`."""
    if free_surface[0] != 0:
        return
    i = wp.tid()
    s = error[i] - error_stats[2] / float(wp.max(count, 1))
    h = dt[0]
    scale = h * h
    if per_unit_time != 0:
        scale = h
    error[i] = s
    stiffness[i] = relaxed_stiffness(s, False, factor[i], scale)


# Where it is capped, the warm start keeps at most this much of last step's pressure, in units of the
# density error it corrects (k dt^2 / factor for the density solver, k dt / factor per second for the
# divergence solver): SPlisHSPlasH caps k dt^2 at 0.00025 m^2, 0.042 of density error at its radius 25 mm.
WARM_START_FACTOR = wp.constant(0.5)
WARM_START_CAP = wp.constant(0.05)
# ... and where the source is clamped (p >= 0), at most this many times the density error (or its rate) this
# step's source still has: dropped whole when the clamped source reached 0, a particle's warm start jumped with
# the last bit of its source (0 against 1e-9), and two runs rounding apart took other paths within 4 steps. (The
# signed bulk keeps the cap alone: ramped, the periodic box's rate half ran out of iterations at 256 across.)
WARM_START_RAMP = wp.constant(4.0)


@wp.kernel
def warm_start_pressure(
    error: wp.array(dtype=float),
    factor: wp.array(dtype=float),
    dt: wp.array(dtype=float),
    dt_previous: wp.array(dtype=float),
    per_unit_time: int,
    surface: wp.array(dtype=wp.int32),
    free_surface: wp.array(dtype=wp.int32),
    pressure_sum: wp.array(dtype=float),
    bulk_applied: int,
    cold_surface: int,
    stiffness: wp.array(dtype=float),
):
    """Warm start: k_i = 0.5 x last step's accumulated k_i, rescaled from dt_prev to dt (dt^2 for the
    density solver, dt for the rate of the divergence solver) where dt grows, never scaled up where it drops
    (a settled tank kicked by one step at dt / 10 jumped from 0.012 to 0.23 m/s). ``error`` holds this step's source before
    any pressure; the value becomes the first iteration's stiffness, ``pressure_sum`` restarts at 0 and
    the first apply adds it.

    It is SPlisHSPlasH's (capped, and kept only where this step's source still has the sign of that
    pressure: still diverging, still compressed, or still expanded in the signed bulk) in the divergence
    solver, on the free surface and its band, and in a box with signed bulk pressure (``free_surface[0]`` 0):
    clamped iterations cannot take back a pressure that is no longer needed where particles can separate.
    ``cold_surface`` 1 (both solves of a scene under gravity): none on the free surface itself, whose stiffness
    stays this step's source's. Its capped warm start grew a wave of the surface layer of a resting pool at the
    viscous step (to 1 m/s within 0.03 s at 32 across; without it the pools rest 4-10x calmer, the 1M dam break
    takes the same density iterations; dropped in the band too, a 14-across tank at dt 0.16 ms opened cavities).
    Without gravity it stays: a box thrown along a filled periodic channel then handed 12 % of the momentum to
    the walls instead of 1.2 % (docs/notes/solver.md). ``bulk_applied`` 1 (the density solve of a
    free-surface scene): the bulk's warm start was applied whole before this measure (:func:`warm_start_bulk`)
    and is left alone here."""
    i = wp.tid()
    if cold_surface != 0 and surface[i] == SURFACE:
        pressure_sum[i] = 0.0
        return
    if bulk_applied != 0 and off_surface(surface[i]):
        return
    h = dt[0]
    hp = dt_previous[0]
    scale = h * h
    previous_scale = hp * hp
    if per_unit_time != 0:
        scale = h
        previous_scale = hp
    k = pressure_sum[i] * previous_scale
    if per_unit_time != 0 or not off_surface(surface[i]) or free_surface[0] == 0:
        limit = WARM_START_CAP * factor[i]
        k = wp.clamp(k, -limit, limit)
        if k * error[i] <= 0.0:
            k = 0.0
        elif clamped(surface[i], free_surface):  # at most WARM_START_RAMP x this source: continuous at its clamp
            ramp = WARM_START_RAMP * wp.abs(error[i]) * factor[i]
            k = wp.clamp(k, -ramp, ramp)
    # never more than last step's pressure: a dt drop would otherwise multiply it by (dt_prev/dt)^2
    k = k * WARM_START_FACTOR / wp.max(scale, previous_scale)
    stiffness[i] = k
    pressure_sum[i] = 0.0


@wp.kernel
def warm_start_bulk(
    pressure_sum: wp.array(dtype=float),
    dt: wp.array(dtype=float),
    dt_previous: wp.array(dtype=float),
    surface: wp.array(dtype=wp.int32),
    stiffness: wp.array(dtype=float),
):
    """The bulk's warm start of the density solve in a free-surface scene, applied before its first measure:
    k_i = 0.5 x last step's accumulated k_i, whole, times (dt_prev/dt)^2 where dt grew (a step at dt / 10 corrects
    its density error with 100x the pressure, which the next step must not apply whole) and never scaled up where
    it dropped (k is a pressure: scaled by 100, a settled tank kicked by one step at dt / 10 jumped from 0.012 to
    0.23 m/s), into ``stiffness`` and
    ``pressure_sum``; 0 on the free surface and its band, whose warm start :func:`warm_start_pressure` decides (none
    on the surface itself, the band's tested against the measured source). In the bulk it is mostly the hydrostatic load, still needed; as the first
    iteration's stiffness, added after the measure, it agitated a resting tank at small steps (50 across,
    dt 0.16 ms: up to 1.2 m/s), and sign-testing it cost the 1M dam break 0.6-0.8 iterations a step
    (docs/notes/solver.md)."""
    i = wp.tid()
    if not off_surface(surface[i]):
        stiffness[i] = 0.0
        return
    h = dt[0]
    hp = dt_previous[0]
    k = pressure_sum[i] * WARM_START_FACTOR * wp.min(hp * hp / (h * h), 1.0)
    stiffness[i] = k
    pressure_sum[i] = k


@wp.kernel
def update_solver_status(
    error_stats: wp.array(dtype=float),
    num_particles: int,
    max_error: float,
    max_peak_error: float,
    per_unit_time: int,
    max_rate: float,
    min_error: float,
    dt: wp.array(dtype=float),
    min_iterations: int,
    max_iterations: int,
    first: int,
    kind: int,
    average_error: wp.array(dtype=float),
    condition: wp.array(dtype=wp.int32),
    iterations: wp.array(dtype=wp.int32),
    totals: wp.array(dtype=wp.int64),
    max_iteration_streak: wp.array(dtype=wp.int32),
    coupling_residual: wp.array(dtype=float),
    coupling_tolerance: float,
):
    """One thread: average error over the fluid and the loop condition, on the device.

    ``condition[0]`` is read by ``wp.capture_while`` (1 = iterate again), ``iterations[0]``
    counts the iterations done. The tolerance is ``max_error`` (relative),
    divided by dt when the error is a rate (divergence solver: SPlisHSPlasH's
    avg <= maxErrorV / dt). ``max_rate`` > 0 [1/s]: the average's tolerance is max_rate x dt, within
    [``min_error``, ``max_error``] (the periodic box's rate half: a tolerance per unit time). Besides the average, the largest error must be below
    ``max_peak_error``: in a tall column the average hides a crushed bottom layer. When the loop ends, its iterations are added to
    ``totals[2 kind]`` and ``totals[2 kind + 1]`` counts the solves; ``max_iteration_streak[kind]``
    counts the consecutive solves that stopped at ``max_iterations``. With dynamic bodies coupled in the solve
    (``coupling_residual`` of one value, else empty: warpsph/bodies.py MovingBodies.couple) the loop also goes on
    while a body's velocity is still moving towards the fluid's reaction by more than the density change it causes
    in a step beside it allows: residual dt > ``coupling_tolerance`` (the solve's relative tolerance x the particle
    diameter); the residual is cleared for the next iteration."""
    if first != 0:
        iterations[0] = 0
    else:
        iterations[0] = iterations[0] + 1
    avg = error_stats[0] / float(wp.max(num_particles, 1))
    peak = error_stats[1]
    error_stats[0] = 0.0  # ready for the next reduce_error, without a memset in the loop body
    error_stats[1] = 0.0
    error_stats[2] = 0.0  # and for the next reduce_source_sum
    average_error[0] = avg
    eta = max_error
    eta_peak = max_peak_error
    if per_unit_time != 0:
        eta = max_error / dt[0]
        eta_peak = max_peak_error / dt[0]
    if max_rate > 0.0:
        eta = wp.max(wp.min(eta, max_rate * dt[0]), min_error)
    done = iterations[0]
    coupled = False
    if coupling_residual.shape[0] > 0:
        coupled = coupling_residual[0] * dt[0] > coupling_tolerance
        coupling_residual[0] = 0.0
    if (avg > eta or peak > eta_peak or coupled or done < min_iterations) and done < max_iterations:
        condition[0] = 1
    else:
        condition[0] = 0
        totals[2 * kind] = totals[2 * kind] + wp.int64(done)
        totals[2 * kind + 1] = totals[2 * kind + 1] + wp.int64(1)
        if done >= max_iterations:  # consecutive solves that ran out of iterations
            max_iteration_streak[kind] = max_iteration_streak[kind] + 1
        else:
            max_iteration_streak[kind] = 0
