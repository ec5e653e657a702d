"""Lamb-Oseen vortex in a box without gravity: u_theta(r, t) and the peak vorticity against the
analytic viscous decay, per method.

    warpsph validate lamb-oseen --resolutions 16 24 32 --device cpu --json lamb_oseen.json
    python -m warpsph.validation.lamb_oseen --resolution 24 --device cpu --out tools/results/lamb_oseen_cpu_res24.json

Set-up: a box L x L (L = 1 m) x ``depth`` particle spacings, walls on the four side faces and periodic in z
(quasi-2D: the vortex axis is z), filled with fluid on the lattice of spacing d = L / resolution, no gravity. The initial velocity is
the Lamb-Oseen vortex about the box centre,

    u_theta(r, t) = Gamma / (2 pi r) (1 - exp(-r^2 / (4 nu (t0 + t)))),

with t0 chosen so that the core radius r_c = sqrt(4 nu t0) is ``--core`` spacings (``warpsph validate``: the
physical CORE_RADIUS = 0.125 m at every resolution, i.e. 0.125 * resolution spacings) and Gamma so that the
peak speed is ``--u-peak``. The analytic solution (unbounded plane) keeps that form with t0 + t; its peak
vorticity is omega_max(t) = Gamma / (4 pi nu (t0 + t)) and its speed peaks at r = 1.1209 r_c(t).
The walls are not in the analytic solution: a potential vortex does not fit a square, so we compare
only inside r < 0.35 L, where the walls' correction (harmonic, 4-fold symmetric: ~r^3) is small.

Measured per output frame, from positions and velocities only:

- u_theta binned in annuli of width d about the box centre (all particles, every z layer), against the
  analytic u_theta averaged over the same particles; L1 error = mean over the bins of |u_sim - u_exact|,
  reported in m/s and relative to the analytic peak speed at that time;
- the radius of the u_theta peak (parabola through the largest bin and its neighbours);
- the peak vorticity, by least squares: in the core u_theta = (omega_0 / 2) r - b r^3 + ..., so we fit
  u_theta_i = a r_i + b r_i^3 over the particles with r_i < r_c(0) and take omega_0 = 2a. This uses every
  particle of the core (about 30 columns x depth), so the noise of single particles averages out, and
  needs no neighbour lists: it is the circulation of a small loop per area, the curl at the axis. The fit
  is biased for the exact profile (the r^5 term: 0.96 of the peak at t = 0 at the default set-up), so
  ``omega_ratio`` divides by the same fit of the analytic field at the same particles (1 at t = 0);
  ``omega_exact`` is the analytic peak itself. ``nu_effective`` is the viscosity whose decay the measured
  peak follows: nu times the slope of 1/omega over that of the analytic 1/omega (linear in t);
- as a cross-check, the SPH curl (kernels/vorticity.py, the field the models use) averaged over the
  particles within one spacing of the axis in the middle z layers (``omega_curl``; its ratio is to the
  analytic peak itself: 0.90 at t = 0, the kernel's smoothing of the core);
- the kinetic energy relative to frame 0.

Methods as in the taylor_green case: plain DFSPH, VR alpha = 1, Rankine beta = 1, micropolar
nu_t = 0.05. Writes JSON, a PNG of the final u_theta profiles (beside it) and ``*_vorticity.png``
(peak vorticity over time).

What it showed with the earlier clamped solver in a box walled in z (3,456 particles, cpu,
tests/data/lamb_oseen_cpu_res24.json): plain DFSPH, Rankine and
micropolar follow the analytic decay with an effective viscosity 1.2-1.25 nu. Most of the excess comes
between t = 0.1 and 0.3 s: DFSPH clamps pressure at >= 0, so the box (at rest density, no background
pressure) cannot hold the low pressure of the core; the core thins (mean density 0.89 rho0 at r < 2
spacings at t = 0.15 s), then collapses again, and the kinetic energy drops faster there.
"""

import argparse

import numpy as np

from warpsph.validation.taylor_green import METHODS  # the same four methods and parameters
from warpsph.kernels.diagnostics import boundary_pressure_torque, gather_by_id, scatter_by_id
from warpsph.models.vorticity import curl_of
from warpsph.plots import write_report
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import InstabilityError, Simulation
from warpsph.solvers.dfsph import DENSITY, DIVERGENCE

R_PEAK = 1.1209  # u_theta peaks at r = 1.1209 r_c (root of 1 + 2 s = exp(s), s = r^2 / r_c^2)
L = 1.0  # box side [m]
# the validation case (``warpsph validate lamb-oseen``): initial core radius sqrt(4 nu t0) [m] (3 spacings at
# 24 particles across), simulated time [s], viscosity [m^2/s], initial peak speed [m/s], depth [spacings]
CORE_RADIUS = 0.125
T_END = 0.5
NU = 0.01
U_PEAK = 0.5
DEPTH = 6
# the vortex below a free surface (``warpsph validate vortex-surface``): the same box walled in x and y, under
# gravity along -y, filled to SURFACE_FILL L, so the surface lies 0.38 L above the axis (Froude U / sqrt(g L)
# ~ 0.16) and 0.03 L above the outermost annulus compared
SURFACE_FILL = 0.88
SURFACE_GRAVITY = 9.81
IMAGES = 8  # periods of the image lattice each way (boxed_velocity): 2e-4 m/s of flow left through the sides


def analytic_u_theta(r, t, gamma, nu, t0):
    r = np.maximum(np.asarray(r, dtype=np.float64), 1e-12)
    return gamma / (2 * np.pi * r) * (1 - np.exp(-r**2 / (4 * nu * (t0 + t))))


def boxed_velocity(x, y, t, gamma, nu, t0, centre, width, height, images=IMAGES):
    """(u, v) of the Lamb-Oseen vortex about ``centre`` inside the box [0, width] x [0, height] with no flow
    through its sides: the vortex and its images in the four sides (the odd extension of its vorticity, a lattice
    of period 2 width x 2 height, each image a Lamb-Oseen vortex of circulation +-gamma), ``images`` periods each
    way. The images' vorticity inside the box is negligible (the nearest is twice the distance to a side away), so
    this is the analytic vortex plus the potential flow that cancels its flow through the sides."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    a = 4 * nu * (t0 + t)
    u, v = np.zeros_like(x), np.zeros_like(y)
    for m in range(-images, images + 1):
        for sx, xc in ((1, 2 * m * width + centre[0]), (-1, 2 * m * width - centre[0])):
            for n in range(-images, images + 1):
                for sy, yc in ((1, 2 * n * height + centre[1]), (-1, 2 * n * height - centre[1])):
                    dx, dy = x - xc, y - yc
                    r2 = np.maximum(dx * dx + dy * dy, 1e-24)
                    k = sx * sy * gamma / (2 * np.pi) * (1 - np.exp(-r2 / a)) / r2
                    u -= k * dy
                    v += k * dx
    return u, v


def analytic_peak_vorticity(t, gamma, nu, t0):
    return gamma / (4 * np.pi * nu * (t0 + t))


def analytic_peak_radius(t, nu, t0):
    return R_PEAK * np.sqrt(4 * nu * (t0 + t))


def setup(resolution=24, nu=0.01, core=3.0, u_peak=0.5, depth=6):
    """The vortex parameters: spacing d, t0 (core = ``core`` spacings) and Gamma (peak speed ``u_peak``)."""
    d = L / resolution
    t0 = (core * d) ** 2 / (4 * nu)
    r_max = analytic_peak_radius(0.0, nu, t0)
    gamma = u_peak / float(analytic_u_theta(r_max, 0.0, 1.0, nu, t0))
    return {"L": L, "spacing": d, "depth": depth * d, "nu": nu, "t0": t0, "gamma": gamma, "core_radius_0": core * d,
            "u_peak_0": u_peak, "centre": [0.5 * L, 0.5 * L, 0.5 * depth * d]}


def polar(x, v, centre):
    """Radius about the z axis through ``centre`` and tangential velocity (e_z x r_hat) . v."""
    dx, dy = x[:, 0] - centre[0], x[:, 1] - centre[1]
    r = np.hypot(dx, dy)
    u = (-dy * v[:, 0] + dx * v[:, 1]) / np.maximum(r, 1e-12)
    return r, u


def fit_peak_vorticity(r, u, radius):
    """omega_0 = 2a of the least-squares fit u = a r + b r^3 over r < radius."""
    inside = r < radius
    A = np.stack([r[inside], r[inside] ** 3], axis=1)
    (a, _), *_ = np.linalg.lstsq(A, u[inside], rcond=None)
    return 2.0 * float(a)


def binned(r, u, edges):
    """Mean of u in each annulus [edges[k], edges[k+1]) and the particles' mean radius there."""
    which = np.digitize(r, edges) - 1
    ok = (which >= 0) & (which < len(edges) - 1)
    count = np.bincount(which[ok], minlength=len(edges) - 1)
    mean_u = np.bincount(which[ok], u[ok], minlength=len(edges) - 1) / np.maximum(count, 1)
    mean_r = np.bincount(which[ok], r[ok], minlength=len(edges) - 1) / np.maximum(count, 1)
    return mean_r, mean_u, count


def peak_radius(r_bins, u_bins):
    """Radius of the maximum of u_theta: the vertex of the parabola through the largest bin and its neighbours."""
    k = int(np.argmax(u_bins))
    if k == 0 or k == len(u_bins) - 1:
        return float(r_bins[k])
    (r0, r1, r2), (u0, u1, u2) = r_bins[k - 1:k + 2], u_bins[k - 1:k + 2]
    p = np.polyfit([r0, r1, r2], [u0, u1, u2], 2)
    if p[0] >= 0:
        return float(r1)
    return float(np.clip(-p[1] / (2 * p[0]), r0, r2))


def sph_curl_z(sim):
    """z-vorticity of the current state with the simulator's SPH curl (fresh neighbour lists and densities)."""
    import warp as wp

    f = sim.fluid
    with wp.ScopedDevice(sim.device):
        sim.update_densities()
        curl = curl_of(sim, f.v, wp.zeros(sim.num_fluid, dtype=wp.vec3))
    return curl.numpy()[:, 2].astype(np.float64)


def measure(sim, p, edges, t):
    x, v = sim.fluid.x.numpy().astype(np.float64), sim.fluid.v.numpy().astype(np.float64)
    centre = p["centre"]
    r, u = polar(x, v, centre)
    r_bins, u_bins, count = binned(r, u, edges)
    exact_r, exact_u, _ = binned(r, analytic_u_theta(r, t, p["gamma"], p["nu"], p["t0"]), edges)
    full = count > 0
    err = np.abs(u_bins - exact_u)[full]
    u_peak_exact = float(analytic_u_theta(analytic_peak_radius(t, p["nu"], p["t0"]), t, p["gamma"], p["nu"], p["t0"]))
    omega_exact = float(analytic_peak_vorticity(t, p["gamma"], p["nu"], p["t0"]))
    omega_fit = fit_peak_vorticity(r, u, p["core_radius_0"])
    # the same fit of the analytic field at the same particles: the measurement's own bias cancels in the ratio
    omega_fit_exact = fit_peak_vorticity(r, analytic_u_theta(r, t, p["gamma"], p["nu"], p["t0"]), p["core_radius_0"])
    d = p["spacing"]
    zeta = sph_curl_z(sim)
    mid = np.abs(x[:, 2] - centre[2]) < d  # the two middle layers: full neighbourhoods in z at depth 6
    axis = mid & (r < d)
    omega_curl = float(zeta[axis].mean()) if axis.any() else float("nan")
    core = mid & (r < 2 * p["core_radius_0"]) & (zeta > 0)
    offset = (np.average(x[core, :2], axis=0, weights=zeta[core]) - centre[:2]) if core.any() else np.zeros(2)
    # total angular momentum about the box centre's z axis per unit mass (walls and surface included)
    angular = float(((x[:, 0] - centre[0]) * v[:, 1] - (x[:, 1] - centre[1]) * v[:, 0]).sum())
    inside = r < edges[-1]
    kinetic_exact = float((analytic_u_theta(r[inside], t, p["gamma"], p["nu"], p["t0"]) ** 2).sum())
    return {"time": t, "u_theta": u_bins.tolist(), "u_theta_exact": exact_u.tolist(),
            "ke_exact_ratio": float((v[inside] ** 2).sum()) / kinetic_exact, "angular_momentum": angular,
            "l1_error": float(err.mean()), "l1_relative": float(err.mean() / u_peak_exact),
            "r_peak": peak_radius(r_bins[full], u_bins[full]),
            "r_peak_exact": float(analytic_peak_radius(t, p["nu"], p["t0"])),
            "omega_fit": omega_fit, "omega_curl": omega_curl, "omega_exact": omega_exact,
            "omega_fit_exact": omega_fit_exact, "omega_ratio": omega_fit / omega_fit_exact, "omega_curl_ratio": omega_curl / omega_exact,
            "centre_offset": float(np.hypot(*offset)), "kinetic": float((v**2).sum())}


def build(models, resolution=24, nu=0.01, T=0.5, core=3.0, u_peak=0.5, depth=6, device="cpu", frames=10,
          r_max=0.35, solver=None, pack_steps=0, overrides=None, free_surface=False):
    """The simulation at t = 0 with the vortex's velocity; returns (simulation, set-up with the bins, bin
    edges). ``free_surface``: filled to SURFACE_FILL L under gravity along -y (the box keeps its height L), and the
    initial velocity is the vortex in the box below a lid at the surface (:func:`boxed_velocity`): the analytic
    vortex there carries a net momentum along x (it lies nearer the surface than the floor: +0.024 m/s over the
    fluid) and flows through the surface, which no wall takes out, so it started the first sloshing mode, whose
    flow at T (reversed, strongest at the surface) gave the kinetic energy at r < 0.35 L 7 % above the analytic.
    ``solver``: scene "solver" keys (e.g. {"density_max_error": 0.05}); None: the defaults.
    ``pack_steps`` > 0: the scene's ``initial_packing`` of that many steps instead of the lattice.
    ``overrides``: dotted scene keys to set (:func:`warpsph.scene.with_overrides`)."""
    p = setup(resolution, nu, core, u_peak, depth)
    d = p["spacing"]
    fill = SURFACE_FILL * L if free_surface else L
    data = {"name": "lamb_oseen", "particle_radius": d / 2, "gravity": [0, -SURFACE_GRAVITY if free_surface else 0, 0],
            "domain": {"min": [0, 0, 0], "max": [L, L, p["depth"]], "periodic": ["z"]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [L, fill, p["depth"]]}],
            "fluid": {"viscosity": nu}, "models": list(models), "output": {"fps": frames / T}}
    if solver:
        data["solver"] = dict(solver)
    if pack_steps:
        data["initial_packing"] = {"steps": pack_steps}
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    x0 = sim.fluid.x.numpy().astype(np.float64)
    dx, dy = x0[:, 0] - p["centre"][0], x0[:, 1] - p["centre"][1]
    r = np.hypot(dx, dy)
    if free_surface:  # the vortex in the box, the surface as a lid: no flow through it, so no sloshing at t = 0
        u, v = boxed_velocity(x0[:, 0], x0[:, 1], 0.0, p["gamma"], nu, p["t0"], p["centre"], L, fill)
        v0 = np.stack([u, v, np.zeros(len(r))], axis=1)
    else:  # the walls' projection in the first step takes out the flow through them (6e-4 of the energy at r < 0.35 L)
        speed = analytic_u_theta(r, 0.0, p["gamma"], nu, p["t0"])
        v0 = np.stack([-dy / np.maximum(r, 1e-12) * speed, dx / np.maximum(r, 1e-12) * speed, np.zeros(len(r))], axis=1)
    sim.fluid.v.assign(v0.astype(np.float32))
    edges = np.arange(0.0, r_max * L + 1e-9, d)
    p["r_bins"] = (0.5 * (edges[1:] + edges[:-1])).tolist()
    return sim, p, edges


class AngularMomentumBudget:
    """What changed the total angular momentum about the vortex axis (z through ``centre``, per unit mass, as
    :func:`measure`'s ``angular_momentum``), summed over the steps (``on_step`` of :meth:`Simulation.run`):

    - ``wall``: the walls' pressure, sum (x_i - c) x dv_i of the step's two solves against the boundary samples
      (kernels/diagnostics.py boundary_pressure_torque), at the step's starting positions;
    - ``gravity``: dt sum (x_i - c) x g at those positions.

    Both are external. In a square box the walls turn a swirling flow's momentum (its pressure is not axisymmetric
    there, and the analytic start crosses the walls), and under gravity a sloshing surface moves the centre of mass
    off the axis, so the total is not conserved; what the fluid's own forces (viscosity, shift) change is the
    total's change less these two (``internal`` of :meth:`shares`). ``seconds``: its own time, device synchronised
    (the validation subtracts it from the run's wall time). DFSPH only (it reads the solves' stiffness)."""

    def __init__(self, sim, centre):
        import warp as wp

        self.centre = wp.vec3(*map(float, centre))
        n = sim.num_fluid
        self.by_id = wp.zeros(n, dtype=wp.vec3, device=sim.device)
        self.start = wp.zeros(n, dtype=wp.vec3, device=sim.device)  # x^n in the current order
        self.torque = wp.zeros(n, dtype=wp.vec3, device=sim.device)
        self.wall = 0.0
        self.gravity = 0.0
        self.seconds = 0.0
        self._remember(sim)

    def _remember(self, sim):
        import warp as wp

        wp.launch(scatter_by_id, sim.num_fluid, inputs=[sim.fluid.x, sim.fluid.ids, self.by_id], device=sim.device)

    def __call__(self, sim):
        import time

        import warp as wp

        wp.synchronize_device(sim.device)
        begin = time.perf_counter()
        ps, n = sim.pressure_solver, sim.num_fluid
        # the step re-sorted the particles at its start: x^n in this step's order, from the ids
        wp.launch(gather_by_id, n, inputs=[self.by_id, sim.fluid.ids, self.start], device=sim.device)
        wp.launch(boundary_pressure_torque, n, device=sim.device,
                  inputs=[self.start, ps.pressure_sum[DIVERGENCE], ps.pressure_sum[DENSITY], ps.gradient_correction,
                          sim.neighbours.lists, sim.boundary.samples, sim.support_radius, sim.dt, self.centre,
                          self.torque])
        dt = float(sim.dt.numpy()[0])
        self.wall += float(self.torque.numpy()[:, 2].astype(np.float64).sum())
        x = self.start.numpy().astype(np.float64)
        g = np.asarray(sim.gravity, dtype=np.float64)
        c = np.asarray(self.centre, dtype=np.float64)
        self.gravity += dt * float(((x[:, 0] - c[0]) * g[1] - (x[:, 1] - c[1]) * g[0]).sum())
        self._remember(sim)
        wp.synchronize_device(sim.device)
        self.seconds += time.perf_counter() - begin

    def shares(self, first, last):
        """The changes from frame ``first`` to ``last`` (two :func:`measure` rows, the budget run between them), as
        fractions of the first's angular momentum: total, wall, gravity and internal (the rest)."""
        start = first["angular_momentum"]
        total = last["angular_momentum"] - start
        return {"angular_momentum_ratio": last["angular_momentum"] / start, "wall_share": self.wall / start,
                "gravity_share": self.gravity / start,
                "internal_share": (total - self.wall - self.gravity) / start}


def kinetic_ratios(rows):
    """Replaces each row's kinetic energy by its ratio to frame 0's (``ke_ratio``)."""
    k0 = rows[0]["kinetic"]
    for row in rows:
        row["ke_ratio"] = row.pop("kinetic") / k0
    return rows


def lamb_oseen(models, resolution=24, nu=0.01, T=0.5, core=3.0, u_peak=0.5, depth=6, device="cpu", frames=10,
               r_max=0.35, solver=None):
    """Runs the vortex; returns (rows per frame, the simulation, the set-up with the bins)."""
    sim, p, edges = build(models, resolution, nu, T, core, u_peak, depth, device, frames, r_max, solver)
    rows = []
    sim.run(frames=frames, on_frame=lambda s, f: rows.append(measure(s, p, edges, s.time)))
    return kinetic_ratios(rows), sim, p


def effective_viscosity(rows, nu):
    """nu times the slope of 1/omega_max(t) measured over the slope of the same measurement of the analytic
    field: 1/omega_max = 4 pi nu (t0 + t) / Gamma is linear in t with slope ~ nu, so this is the viscosity
    that the measured decay corresponds to (physical plus numerical)."""
    t = [r["time"] for r in rows]
    measured = np.polyfit(t, [1.0 / r["omega_fit"] for r in rows], 1)[0]
    exact = np.polyfit(t, [1.0 / r["omega_fit_exact"] for r in rows], 1)[0]
    return float(nu * measured / exact)


def summary(rows, nu):
    first, last = rows[0], rows[-1]
    return {"nu_effective": effective_viscosity(rows, nu),"l1_error_end": last["l1_error"], "l1_relative_end": last["l1_relative"],
            "omega_ratio_end": last["omega_ratio"], "omega_ratio_start": first["omega_ratio"],
            "omega_curl_ratio_end": last["omega_curl_ratio"], "omega_decay": last["omega_fit"] / first["omega_fit"],
            "omega_decay_exact": last["omega_exact"] / first["omega_exact"],
            "r_peak_end": last["r_peak"], "r_peak_exact_end": last["r_peak_exact"],
            "ke_ratio_end": last["ke_ratio"], "ke_exact_ratio_end": last["ke_exact_ratio"],
            "angular_momentum_ratio_end": last["angular_momentum"] / first["angular_momentum"],
            "centre_offset_end": last["centre_offset"]}


def figures(report):
    """The report's figures, from the report alone: u_theta(r) at T per method against the analytic profile
    (and the initial one), and the peak vorticity over time (suffix ``_vorticity``)."""
    T, gamma, nu, t0 = report["T"], report["gamma"], report["nu"], report["t0"]
    runs = [(name, res["frames"]) for name, res in report["methods"].items() if "frames" in res]
    r = np.linspace(1e-3, 0.35 * L, 100)
    profile = [(report["r_bins"], frames[-1]["u_theta"], "-", name) for name, frames in runs]
    profile += [(r, analytic_u_theta(r, T, gamma, nu, t0), "k--", f"analytic t = {T:g} s"),
                (r, analytic_u_theta(r, 0.0, gamma, nu, t0), "k:", "initial")]
    t = np.linspace(0, T, 50)
    peak = [([f["time"] for f in frames], [f["omega_fit"] for f in frames], "-o", name) for name, frames in runs]
    peak.append((t, analytic_peak_vorticity(t, gamma, nu, t0), "k--", "analytic"))
    return [("", profile, "r [m]", "u_theta [m/s]", (6, 4)), ("_vorticity", peak, "t [s]", "peak vorticity [1/s]", (6, 4))]


def main(argv=None):
    parser = argparse.ArgumentParser(prog=f"python -m {__name__}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=24, help="particles across L = 1 m")
    parser.add_argument("--nu", type=float, default=0.01, help="kinematic viscosity [m^2/s]")
    parser.add_argument("--T", type=float, default=0.5, help="simulated time [s]")
    parser.add_argument("--core", type=float, default=3.0, help="initial core radius sqrt(4 nu t0) in spacings")
    parser.add_argument("--u-peak", type=float, default=0.5, help="initial peak speed [m/s]")
    parser.add_argument("--depth", type=int, default=6, help="box depth in particle spacings")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--out", help="JSON file (PNGs beside it when matplotlib is present)")
    args = parser.parse_args(argv)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    p = setup(args.resolution, args.nu, args.core, args.u_peak, args.depth)
    report = {"case": "Lamb-Oseen vortex, box L = 1 m periodic in z, quasi-2D, no gravity", "resolution": args.resolution,
              "T": args.T, "warp": wp.__version__, **p, "methods": {}}
    for name in args.methods:
        try:
            rows, sim, p = lamb_oseen(METHODS[name], args.resolution, args.nu, args.T, args.core, args.u_peak,
                                      args.depth, args.device, args.frames)
        except InstabilityError as exc:
            report["methods"][name] = {"unstable": str(exc), "step": exc.step, "time": exc.time, "check": exc.check}
            print(f"{name:11s} {exc}")
            continue
        report.update(device=str(sim.device), particles=sim.num_fluid, r_bins=p["r_bins"])
        s = summary(rows, args.nu)
        report["methods"][name] = {**s, "steps": sim.step_count, "frames": rows}
        print(f"{name:11s} L1 u_theta {s['l1_error_end']:.4f} m/s ({100 * s['l1_relative_end']:.1f} % of peak), "
              f"omega_max/exact {s['omega_ratio_end']:.3f} (t=0: {s['omega_ratio_start']:.3f}; SPH curl "
              f"{s['omega_curl_ratio_end']:.3f}), decay {s['omega_decay']:.3f} (exact {s['omega_decay_exact']:.3f}), "
              f"r_peak {s['r_peak_end']:.3f} (exact {s['r_peak_exact_end']:.3f}), KE {s['ke_ratio_end']:.3f}, "
              f"nu_eff {s['nu_effective']:.4f}")
    if args.out:
        write_report(report, args.out, figures(report))
