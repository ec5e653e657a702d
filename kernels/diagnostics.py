"""Per-frame diagnostics reduced on the device: a few float64 sums and maxima cross to the host."""

import warp as wp

from .particles import Boundary, Neighbours, SymmetricMatrix, separation, symmetric_times
from .pressure import REDUCE_THREADS
from .sph_kernel import cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})

# slots of the reduction output (float64)
KINETIC = 0  # sum |v|^2
POTENTIAL = 1  # sum (x - origin) . g
ENSTROPHY = 2  # sum V |zeta|^2, V = m / max(rho, 1e-9)
VORTICITY_SQ = 3  # sum |zeta|^2
SPIN_SQ = 4  # sum |omega|^2 (a model's angular velocity)
ERROR_SUM = 5  # sum max(rho / rho0 - 1, 0)
ERROR_MAX = 6  # max (rho / rho0 - 1)
REGION_ENSTROPHY = 7  # ENSTROPHY of the particles inside a box (a wake; 0 without one)
SLOTS = 8


@wp.func
def norm_sq64(a: wp.vec3):
    x = wp.float64(a[0])
    y = wp.float64(a[1])
    z = wp.float64(a[2])
    return x * x + y * y + z * z


@wp.kernel
def reduce_frame_diagnostics(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
    vorticity: wp.array(dtype=wp.vec3),
    spin: wp.array(dtype=wp.vec3),
    count: int,
    origin: wp.vec3d,
    gravity: wp.vec3d,
    particle_mass: wp.float64,
    rest_density: wp.float64,
    region_lower: wp.vec3,
    region_upper: wp.vec3,
    out: wp.array(dtype=wp.float64),
):
    """Launched on min(count, REDUCE_THREADS) threads, grid-stride, one atomic per slot and thread
    (``out`` zeroed first, ERROR_MAX at -inf). ``vorticity`` and ``spin`` may be empty; a region with
    ``region_lower`` above ``region_upper`` holds nothing."""
    t = wp.tid()
    threads = wp.min(count, REDUCE_THREADS)
    has_vorticity = vorticity.shape[0] > 0
    has_spin = spin.shape[0] > 0
    rho0 = rest_density
    m = particle_mass
    kinetic = wp.float64(0.0)
    potential = wp.float64(0.0)
    enstrophy = wp.float64(0.0)
    vorticity_sq = wp.float64(0.0)
    spin_sq = wp.float64(0.0)
    error_sum = wp.float64(0.0)
    error_max = wp.float64(-1.0e300)
    region = wp.float64(0.0)
    for i in range(t, count, threads):
        kinetic += norm_sq64(v[i])
        xi = x[i]
        potential += ((wp.float64(xi[0]) - origin[0]) * gravity[0] + (wp.float64(xi[1]) - origin[1]) * gravity[1]
                      + (wp.float64(xi[2]) - origin[2]) * gravity[2])
        rho = wp.float64(density[i])
        error = rho / rho0 - wp.float64(1.0)
        error_sum += wp.max(error, wp.float64(0.0))
        error_max = wp.max(error_max, error)
        if has_vorticity:
            z = norm_sq64(vorticity[i])
            vorticity_sq += z
            e = m / wp.max(rho, wp.float64(1.0e-9)) * z
            enstrophy += e
            inside = xi[0] >= region_lower[0] and xi[0] <= region_upper[0] and xi[1] >= region_lower[1]
            if inside and xi[1] <= region_upper[1] and xi[2] >= region_lower[2] and xi[2] <= region_upper[2]:
                region += e
        if has_spin:
            spin_sq += norm_sq64(spin[i])
    wp.atomic_add(out, 0, kinetic)
    wp.atomic_add(out, 1, potential)
    wp.atomic_add(out, 2, enstrophy)
    wp.atomic_add(out, 3, vorticity_sq)
    wp.atomic_add(out, 4, spin_sq)
    wp.atomic_add(out, 5, error_sum)
    wp.atomic_max(out, 6, error_max)
    wp.atomic_add(out, 7, region)


@wp.kernel
def scatter_by_id(x: wp.array(dtype=wp.vec3), ids: wp.array(dtype=wp.int32), by_id: wp.array(dtype=wp.vec3)):
    """by_id[ids_i] = x_i: a per-particle vector kept through re-sorting (ids 0 .. n - 1)."""
    i = wp.tid()
    by_id[ids[i]] = x[i]


@wp.kernel
def gather_by_id(by_id: wp.array(dtype=wp.vec3), ids: wp.array(dtype=wp.int32), x: wp.array(dtype=wp.vec3)):
    """x_i = by_id[ids_i] (the inverse of :func:`scatter_by_id` in the current order)."""
    i = wp.tid()
    x[i] = by_id[ids[i]]


@wp.kernel
def boundary_pressure_torque(
    x: wp.array(dtype=wp.vec3),
    stiffness_a: wp.array(dtype=float),
    stiffness_b: wp.array(dtype=float),
    correction: wp.array(dtype=SymmetricMatrix),
    nb: Neighbours,
    boundary: Boundary,
    support_radius: float,
    dt: wp.array(dtype=float),
    centre: wp.vec3,
    torque: wp.array(dtype=wp.vec3),
):
    """torque_i = (x_i - centre) x dv_i of the walls' and bodies' pressure in a step (per unit mass): dv_i = -dt
    sum_b V_b k_i L_i grad W_ib with k_i the step's stiffness of both solves (``stiffness_a + stiffness_b``, as
    :data:`apply_corrected_pressure_acceleration` applied them at ``x``, the step's starting positions)."""
    i = wp.tid()
    xi = x[i]
    k = stiffness_a[i] + stiffness_b[i]
    dv = wp.vec3(0.0)
    for n in range(nb.boundary_offsets[i], nb.boundary_offsets[i + 1]):
        b = nb.boundary[n]
        dv += boundary.volume[b] * k * cubic_kernel_gradient(separation(nb, xi, boundary.x[b]), support_radius)
    torque[i] = wp.cross(xi - centre, -dt[0] * symmetric_times(correction[i], dv))
