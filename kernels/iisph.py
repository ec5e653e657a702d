"""Implicit incompressible SPH (Ihmsen, Cornelis, Solenthaler, Horvath & Teschner 2014), as SPlisHSPlasH's
TimeStepIISPH runs it with Akinci boundaries, except for the boundary's part of a_ii
(:func:`compute_iisph_coefficients` says why).

Units as SPlisHSPlasH: densities relative to rho0 (rho^ = rho / rho0), pressure per rest density (p^ = p / rho0,
m^2/s^2), the displacement coefficients d per unit dt^2 (the paper's d carry dt^2; here the solver multiplies
by dt^2 where the paper's d appear). Then q_i = p^_i / rho^_i^2 is the DFSPH solvers' stiffness k (rho0 p /
rho^2), so the pressure acceleration is :func:`warpsph.kernels.pressure.apply_pressure_acceleration` of q.

Per step, after the non-pressure forces have made v into v_adv (eq 4), one neighbour pass gives d_ii, a_ii and
the source b_i = 1 - rho^adv_i and halves last step's pressure (the warm start); then relaxed Jacobi
iterations, each two passes: the pressure displacement c_i = d_ii p_i + sum_j d_ij p_j of the current
pressures (eq 9), then the new p_i (eq 14) from c of the neighbours. Folding d_jj p_j + sum_k d_jk p_k into
c_j leaves each pass one vector per neighbour to read, and makes the update read only its own old pressure,
so it runs in place.
"""

import warp as wp

from .particles import Boundary, Neighbours, boundary_velocity, separation
from .sph_kernel import cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})

# |a_ii| below this x 1/H^2 (a particle with almost no neighbours): p_i = 0. The DFSPH factor's threshold.
MIN_DIAGONAL = wp.constant(1.0e-6)


@wp.kernel
def compute_iisph_coefficients(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    boundary: Boundary,
    density: wp.array(dtype=float),
    fluid_volume: float,
    rest_density: float,
    support_radius: float,
    dt: wp.array(dtype=float),
    warm_start: float,
    d_ii: wp.array(dtype=wp.vec3),
    a_ii: wp.array(dtype=float),
    source: wp.array(dtype=float),
    pressure: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
):
    """One neighbour pass (``v`` is v_adv):

    - d_ii = -sum_f V_f / rho^_i^2 grad W_if - sum_b V_b / rho^_i^2 grad W_ib (eq 9: the boundary mirrors p_i);
    - rho^adv_i = rho^_i + dt (sum_f V_f v_if . grad W_if + sum_b V_b (v_i - v_b) . grad W_ib) (eq 4), stored as
      the source b_i = 1 - rho^adv_i (eq 7);
    - a_ii = sum_f V_f (d_ii - d_fi) . grad W_if + sum_b V_b d_ii . grad W_ib, d_fi = V_i / rho^_i^2 grad W_if
      (eq 13): the coefficient of p_i in row i of the system that the pressure force solves. With G = sum_j V_j
      grad W_ij (fluid and boundary) and S = sum_f V_f |grad W_if|^2 that is -(|G|^2 + V_i S) / rho^_i^2 (the
      DFSPH factor's denominator over -rho^_i^2), so one pass gives both. SPlisHSPlasH also subtracts
      sum_b V_b d_bi . grad W_ib, as if the samples moved under p_i; they do not, and that diagonal leaves the
      particles at walls compressed by dt^2 V_i q_i sum_b V_b |grad W_ib|^2 after convergence (hydrostatic tank,
      10 across: mean density error 0.29 %, largest 2.3 %; 0.024 % and 0.044 % without it);
    - the warm start p_i := ``warm_start`` x last step's p_i (SPlisHSPlasH: 0.5; 0 with warm_start off), and
      its q_i = p_i / rho^_i^2 (Algorithm 1, PREDICT ADVECTION)."""
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    g = wp.vec3(0.0)
    s = float(0.0)
    rate = float(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        grad = cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
        g += fluid_volume * grad
        s += fluid_volume * wp.dot(grad, grad)
        rate += fluid_volume * wp.dot(vi - v[j], grad)
    for k in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[k]
        grad = cubic_kernel_gradient(separation(nb, xi, boundary.x[b]), support_radius)
        volume = boundary.volume[b]
        g += volume * grad
        rate += volume * wp.dot(vi - boundary_velocity(boundary, b), grad)
    rho = density[i] / rest_density
    inverse_rho2 = 1.0 / (rho * rho)
    d_ii[i] = -inverse_rho2 * g
    a_ii[i] = -inverse_rho2 * (wp.dot(g, g) + fluid_volume * s)
    source[i] = 1.0 - (rho + dt[0] * rate)
    p = warm_start * pressure[i]
    pressure[i] = p
    stiffness[i] = p * inverse_rho2


@wp.kernel
def compute_pressure_displacement(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    fluid_volume: float,
    support_radius: float,
    d_ii: wp.array(dtype=wp.vec3),
    pressure: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
    displacement: wp.array(dtype=wp.vec3),
):
    """c_i = d_ii p_i + sum_f d_if p_f with d_if = -V_f / rho^_f^2 grad W_if (eq 9 per unit dt^2): the
    acceleration of i by the current pressures (q_f = p_f / rho^_f^2 from ``stiffness``). SPlisHSPlasH's
    pass computes sum_f d_if p_f alone; the update recovers it as c_i - d_ii p_i."""
    i = wp.tid()
    xi = x[i]
    dp = wp.vec3(0.0)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        dp -= fluid_volume * stiffness[j] * cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
    displacement[i] = d_ii[i] * pressure[i] + dp


@wp.kernel
def update_iisph_pressure(
    x: wp.array(dtype=wp.vec3),
    nb: Neighbours,
    density: wp.array(dtype=float),
    fluid_volume: float,
    rest_density: float,
    support_radius: float,
    support_floor: float,
    dt: wp.array(dtype=float),
    omega: float,
    d_ii: wp.array(dtype=wp.vec3),
    a_ii: wp.array(dtype=float),
    source: wp.array(dtype=float),
    displacement: wp.array(dtype=wp.vec3),
    pressure: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
    error: wp.array(dtype=float),
):
    """Relaxed Jacobi step (eq 14) with p >= 0 (SPlisHSPlasH's clamp), ``omega`` the relaxation (Ihmsen et al.
    2014, section 3.2; ``solver.relaxation``, SPlisHSPlasH's 0.5):

    p_i := max((1 - omega) p_i + omega (b_i - dt^2 s_i) / (dt^2 a_ii), 0),
    s_i = sum_f V_f (sum_k d_ik p_k - d_ff p_f - sum_{k != i} d_fk p_k) . grad W_if + sum_b V_b sum_k d_ik p_k
    . grad W_ib, the off-diagonal part of row i (eqs 10-12). With c from :func:`compute_pressure_displacement`:
    sum_k d_ik p_k = c_i - d_ii p_i, d_ff p_f + sum_{k != i} d_fk p_k = c_f - d_fi p_i, and the boundary and
    fluid sums of the first term are (c_i - d_ii p_i) . G_i with G_i = -rho^_i^2 d_ii. 0 where |a_ii| <
    ``support_floor`` (MIN_DIAGONAL / H^2). ``error`` gets the row's residual (a_ii p_i + s_i) dt^2 - b_i (the
    relative density error left, SPlisHSPlasH's measure) where p_i > 0, else 0; q_i = p_i / rho^_i^2."""
    i = wp.tid()
    xi = x[i]
    rho = density[i] / rest_density
    inverse_rho2 = 1.0 / (rho * rho)
    p = pressure[i]
    q = stiffness[i]
    dii = d_ii[i]
    own = displacement[i] - dii * p  # sum_k d_ik p_k
    s = -rho * rho * wp.dot(own, dii)
    for k in range(nb.fluid_offsets[i], nb.fluid_offsets[i + 1]):
        j = nb.fluid[k]
        grad = cubic_kernel_gradient(separation(nb, xi, x[j]), support_radius)
        s += fluid_volume * wp.dot(fluid_volume * q * grad - displacement[j], grad)
    h2 = dt[0] * dt[0]
    a = a_ii[i]
    b = source[i]
    p_new = float(0.0)
    if wp.abs(a) > support_floor:
        p_new = wp.max((1.0 - omega) * p + omega * (b - h2 * s) / (a * h2), 0.0)
    e = float(0.0)
    if p_new > 0.0:
        e = (a * p_new + s) * h2 - b
    pressure[i] = p_new
    stiffness[i] = p_new * inverse_rho2
    error[i] = e


@wp.kernel
def start_pressure_solve(condition: wp.array(dtype=wp.int32), iterations: wp.array(dtype=wp.int32)):
    """One thread: the Jacobi loop runs at least once (SPlisHSPlasH's do-while); the iterations count from 0 and
    :func:`warpsph.kernels.pressure.update_solver_status` adds one after each."""
    condition[0] = 1
    iterations[0] = 0
