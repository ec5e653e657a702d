"""Taylor-Green vortex in a periodic box: kinetic energy against its analytic decay, per method.

    warpsph validate taylor-green --resolutions 16 24 32 --device cpu --json taylor_green.json
    python -m warpsph.validation.taylor_green --resolution 20 --device cpu --out tools/results/taylor_green_cpu.json

The 2D field u = -U cos(2 pi x) sin(2 pi y), v = U sin(2 pi x) cos(2 pi y) (L = 1, U = 1), extruded in z,
in a box periodic along x, y and z (no walls, no gravity). Its kinetic energy decays as
KE(t) = KE(0) exp(-16 pi^2 nu t / L^2). For each method (plain DFSPH, VR alpha = 1, Rankine beta = 1,
micropolar nu_t = 0.05) we report KE(t)/KE(0) against the analytic curve, the relative KE error at the end,
and the L1 error of the velocity magnitude against the analytic field; this is the quantitative form of
the papers' claim that refinement recovers numerical dissipation.
"""

import argparse

import numpy as np
from warpsph.plots import write_report
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import InstabilityError, Simulation

METHODS = {
    "dfsph": [],
    "vr": [{"type": "vorticity_refinement", "alpha": 1.0}],
    "rankine": [{"type": "rankine", "beta": 1.0}],
    "micropolar": [{"type": "micropolar", "transfer_coefficient": 0.05}],
}


# particle packing (--pack-steps): jitter in spacings, steps at rest
PACK_JITTER = 0.1
PACK_STEPS = 40
# the validation case (``warpsph validate taylor-green``): simulated time [s], viscosity [m^2/s]
T_END = 0.3
NU = 0.01


def peak_speed(t, nu):
    """The analytic peak speed at time t (U = 1): exp(-8 pi^2 nu t)."""
    return np.exp(-8 * np.pi**2 * nu * t)


def analytic_velocity(x, t, nu):
    decay = peak_speed(t, nu)
    u = -np.cos(2 * np.pi * x[:, 0]) * np.sin(2 * np.pi * x[:, 1])
    v = np.sin(2 * np.pi * x[:, 0]) * np.cos(2 * np.pi * x[:, 1])
    return decay * np.stack([u, v, np.zeros(len(x))], axis=1)


def scene_data(models, resolution, nu, T, frames, solver=None):
    """The vortex's scene: L = 1 box periodic along x, y and z, 6 spacings deep, no gravity."""
    d = 1.0 / resolution
    depth = 6 * d  # the periodic z extent must hold 3 support radii
    data = {"name": "taylor_green", "particle_radius": d / 2, "gravity": [0, 0, 0],
            "domain": {"min": [0, 0, 0], "max": [1, 1, depth], "periodic": ["x", "y", "z"]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [1, 1, depth]}],
            "fluid": {"viscosity": nu}, "models": list(models), "output": {"fps": frames / T}}
    if solver:
        data["solver"] = dict(solver)
    return data


def build(models, resolution=20, nu=0.01, T=0.5, device="cpu", frames=10, solver=None, pack_steps=0, overrides=None):
    """The vortex at t = 0: (simulation, KE(0)). ``pack_steps`` > 0 starts from the scene's
    ``initial_packing`` of that many steps instead of the cubic lattice; the velocity is the analytic field at the particles.
    ``overrides``: dotted scene keys to set (:func:`warpsph.scene.with_overrides`)."""
    data = scene_data(models, resolution, nu, T, frames, solver)
    if pack_steps:
        data["initial_packing"] = {"steps": pack_steps, "jitter": PACK_JITTER}
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    x0 = sim.host(sim.fluid.x)  # float32 arithmetic, as the recorded runs (tests/test_confined.py) had it
    sim.active(sim.fluid.v).assign(analytic_velocity(x0, 0.0, nu).astype(np.float32))
    return sim, float((sim.host(sim.fluid.v).astype(np.float64) ** 2).sum())


def measure(sim, ke0, nu):
    """KE(t)/KE(0) against exp(-16 pi^2 nu t) and the L1 error of the velocity magnitude (m/s)."""
    x, v = sim.host(sim.fluid.x).astype(np.float64), sim.host(sim.fluid.v).astype(np.float64)
    exact = analytic_velocity(x, sim.time, nu)
    return {"time": sim.time, "ke_ratio": float((v**2).sum() / ke0),
            "ke_ratio_exact": float(np.exp(-16 * np.pi**2 * nu * sim.time)),
            "l1_speed_error": float(np.mean(np.abs(np.linalg.norm(v, axis=1) - np.linalg.norm(exact, axis=1))))}


def taylor_green(models, resolution=20, nu=0.01, T=0.5, device="cpu", frames=10, solver=None, pack_steps=0):
    """Runs the vortex; returns (rows per frame, the simulation). ``solver``: scene "solver" keys (e.g.
    {"density_max_error": 0.05}); None: the defaults."""
    sim, ke0 = build(models, resolution, nu, T, device, frames, solver, pack_steps)
    rows = []
    sim.run(frames=frames, on_frame=lambda s, frame: rows.append(measure(s, ke0, nu)))
    return rows, sim


def figures(report):
    """The report's figure, from the report alone: KE(t)/KE(0) per method against the analytic decay."""
    curves = [([r["time"] for r in res["frames"]], [r["ke_ratio"] for r in res["frames"]], "-", name)
              for name, res in report["methods"].items() if "frames" in res]
    t = np.linspace(0, report["T"], 50)
    curves.append((t, np.exp(-16 * np.pi**2 * report["nu"] * t), "k--", "analytic"))
    return [("", curves, "t [s]", "KE / KE(0)", (6, 4))]


def main(argv=None):
    parser = argparse.ArgumentParser(prog=f"python -m {__name__}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=20, help="particles across L")
    parser.add_argument("--nu", type=float, default=0.01, help="kinematic viscosity [m^2/s]")
    parser.add_argument("--T", type=float, default=T_END, help="simulated time [s]")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--pack-steps", type=int, default=PACK_STEPS, metavar="N",
                        help=f"start from a particle packing (lattice jittered by {PACK_JITTER} spacings, N steps at rest; "
                             f"0: the cubic lattice, which a full periodic box shakes apart)")
    parser.add_argument("--out")
    args = parser.parse_args(argv)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    report = {"case": "Taylor-Green, periodic, L = 1, U = 1", "resolution": args.resolution, "nu": args.nu,
              "T": args.T, "pack_steps": args.pack_steps, "warp": wp.__version__, "methods": {}}
    for name in args.methods:
        try:
            rows, sim = taylor_green(METHODS[name], args.resolution, args.nu, args.T, args.device,
                                     pack_steps=args.pack_steps)
        except InstabilityError as exc:
            report["methods"][name] = {"unstable": str(exc)}
            print(f"{name:11s} {exc}")
            continue
        last = rows[-1]
        report["device"] = str(sim.device)
        report["particles"] = sim.num_fluid
        report["methods"][name] = {"frames": rows, "ke_ratio_end": last["ke_ratio"], "ke_ratio_exact": last["ke_ratio_exact"],
                                   "ke_relative_error": last["ke_ratio"] / last["ke_ratio_exact"] - 1.0,
                                   "l1_speed_error_end": last["l1_speed_error"], "steps": sim.step_count}
        print(f"{name:11s} KE(T)/KE0 {last['ke_ratio']:.4f} (exact {last['ke_ratio_exact']:.4f}, "
              f"error {100 * (last['ke_ratio'] / last['ke_ratio_exact'] - 1):+.1f} %), L1 |u| error {last['l1_speed_error']:.4f}")
    if args.out:
        write_report(report, args.out, figures(report))
