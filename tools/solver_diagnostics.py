"""Diagnostics of the default solver on the Taylor-Green vortex (developer script; not part of the package;
issue #16 and the confined mode's history, docs/notes/solver.md and docs/notes/confined-mode.md):

- ``energy-budget``: where Taylor-Green's kinetic energy goes, by solver stage;
- ``viscosity-moments``: the viscosity Laplacian of the VR paper's eq 4 against the exact one, in numpy;
- ``scan``: a scan of the solver's knobs (it overrides a module constant: not a supported interface).

    python tools/solver_diagnostics.py energy-budget --device cuda --resolution 256 [--solver '{"shifting": 0}']
    python tools/solver_diagnostics.py viscosity-moments --resolutions 16 32 --out tools/results/viscosity_operator_moments_cpu.json
    python tools/solver_diagnostics.py scan --device cuda --variants '[{"res": 128, "pre": 40, "jitter": 0.1}]' --out /tmp/scan.json

``python tools/solver_diagnostics.py COMMAND --help`` describes each. They were tools/taylor_green_energy_budget.py,
tools/viscosity_operator_moments.py and tools/scan_confined.py (same options).
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the checkout's warpsph, also without an installed one
wp.config.log_level = wp.LOG_WARNING
from warpsph.validation import taylor_green as tg  # noqa: E402


# -- energy-budget (was tools/taylor_green_energy_budget.py) -----------------------------------------------------
BUDGET_DOC = """Where Taylor-Green's kinetic energy goes, by solver stage: the change of sum |v|^2 (as a fraction of its
value at t = 0) inside the divergence solve, inside the density solve, and in the rest of the step (the
viscosity's acceleration; shifting moves positions only), against the analytic exp(-16 pi^2 nu t) - 1.
Default solver and validation scene (warpsph.validation.taylor_green, packed start). The step runs without
a captured graph so each solve can be measured. Developer diagnostic for issue #16 (docs/notes/solver.md).

    python tools/solver_diagnostics.py energy-budget --device cuda --resolution 256 [--solver '{"shifting": 0}']
"""


BUDGET_TIMES = (0.05, 0.1, 0.2, 0.3)


def budget(device, resolution, solver=None, times=BUDGET_TIMES):
    """Rows at each time in ``times``: the energy changes by stage, as fractions of KE(0)."""
    overrides = {f"solver.{k}": v for k, v in (solver or {}).items()} or None
    sim, _ = tg.build([], resolution, tg.NU, max(times), device, pack_steps=tg.PACK_STEPS, overrides=overrides)
    sim.use_graph = False
    energy = sim.kinetic_energy
    ke0 = energy()

    spent = {"divergence_solve": 0.0, "density_solve": 0.0}

    def measured(solve, label):
        def run(*args, **kwargs):
            before = energy()
            result = solve(*args, **kwargs)
            spent[label] += (energy() - before) / ke0
            return result
        return run

    ps = sim.pressure_solver
    ps.correct_divergence = measured(ps.correct_divergence, "divergence_solve")
    ps.correct_density = measured(ps.correct_density, "density_solve")
    rows, pending = [], list(times)
    while pending:
        sim.step()
        if sim.time >= pending[0]:
            pending.pop(0)
            total = (energy() - ke0) / ke0
            rows.append({"across": resolution, "solver_keys": solver or {}, "t": sim.time, "steps": sim.step_count,
                         "dKE_over_KE0": total, "analytic": float(np.exp(-16 * np.pi**2 * tg.NU * sim.time) - 1),
                         **spent, "rest_viscosity": total - sum(spent.values())})
    return rows


def budget_main(argv=None, prog=None):
    ap = argparse.ArgumentParser(prog=prog, description=BUDGET_DOC,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--resolution", type=int, default=32, help="particles across L = 1 m")
    ap.add_argument("--solver", type=json.loads, default=None, help='scene "solver" keys as JSON')
    ap.add_argument("--out", help="write the rows here (JSON)")
    args = ap.parse_args(argv)
    rows = budget(args.device, args.resolution, args.solver)
    for r in rows:
        print(f"t {r['t']:.3f} ({r['steps']} steps): dKE/KE0 {r['dKE_over_KE0']:+.4f} (analytic {r['analytic']:+.4f}) = "
              f"divergence {r['divergence_solve']:+.4f} + density {r['density_solve']:+.4f} + rest {r['rest_viscosity']:+.4f}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


# -- viscosity-moments (was tools/viscosity_operator_moments.py) -------------------------------------------------
MOMENTS_DOC = """The viscosity Laplacian of the VR paper's eq 4 (Koschier's form, kernels/viscosity.py) applied in numpy to
analytic divergence-free fields at the particles of the Taylor-Green box (periodic, L = 1, 6 spacings deep;
the cubic lattice and the validation's 40-step packing), projected on the exact Laplacian (1 = exact).
Developer diagnostic for issue #16's plateaus (docs/notes/solver.md).

    python tools/solver_diagnostics.py viscosity-moments --resolutions 16 32 --out tools/results/viscosity_operator_moments_cpu.json
"""


pi = np.pi


def grad_w(xij, r, H):
    """The cubic spline's gradient (kernels/sph_kernel.py) for offsets x_ij of length r, support H."""
    q = r / H
    l = 48.0 / pi / H**3
    g = np.where(q <= 0.5, l * q * (3 * q - 2), -l * (1 - q) ** 2)
    g = np.where((r > 1e-9 * H) & (r <= H), g, 0.0)
    return (g / np.maximum(r, 1e-12) / H)[:, None] * xij

FIELDS = {
    "Taylor-Green": (lambda x: np.stack([-np.cos(2*pi*x[:,0])*np.sin(2*pi*x[:,1]), np.sin(2*pi*x[:,0])*np.cos(2*pi*x[:,1]), 0*x[:,0]], 1), -8*pi**2),
    "shear along an axis, v_x(y)": (lambda x: np.stack([np.sin(2*pi*x[:,1]), 0*x[:,0], 0*x[:,0]], 1), -4*pi**2),
    "shear at 45 deg": (lambda x: np.stack([np.sin(2*pi*(x[:,0]+x[:,1])), -np.sin(2*pi*(x[:,0]+x[:,1])), 0*x[:,0]], 1), -8*pi**2),
}

def operator(x, v, V, H, period):
    """Eq 4 at every particle: 2(d+2) sum_j V (v_ij . x_ij) / (r^2 + 0.01 H^2) grad W_ij, minimum image."""
    out = np.zeros_like(v)
    for s in range(0, len(x), 256):
        xij = x[s:s+256, None, :] - x[None, :, :]
        xij -= period * np.round(xij / period)
        r = np.linalg.norm(xij, axis=2)
        m = (r > 0) & (r < H)
        ii, jj = np.nonzero(m)
        xs = xij[ii, jj]; rs = r[ii, jj]
        vij = v[s + ii] - v[jj]
        term = (10.0 * V * (vij * xs).sum(1) / (rs**2 + 0.01 * H**2))[:, None] * grad_w(xs, rs, H)
        np.add.at(out, s + ii, term)
    return out

def factors(res):
    dx = 1.0 / res
    H = 2 * dx
    period = np.array([1.0, 1.0, 6 * dx])
    lattice = (np.stack(np.meshgrid(np.arange(res), np.arange(res), np.arange(6), indexing="ij"), -1).reshape(-1, 3) + 0.5) * dx
    sim, _ = tg.build([], res, tg.NU, tg.T_END, "cpu", 4, pack_steps=tg.PACK_STEPS)
    packed = sim.host(sim.fluid.x).astype(np.float64)
    rows = []
    for name, x in (("lattice", lattice), ("packed", packed)):
        for field, (f, lap) in FIELDS.items():
            v = f(x)
            L = operator(x, v, dx**3, H, period)
            exact = lap * v
            rows.append({"resolution": res, "arrangement": name, "field": field,
                         "factor": round(float((L * exact).sum() / (exact * exact).sum()), 4)})
            print(rows[-1], flush=True)
    return rows


def moments_main(argv=None, prog=None):
    ap = argparse.ArgumentParser(prog=prog, description=MOMENTS_DOC,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[16, 32])
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    rows = [r for res in args.resolutions for r in factors(res)]
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"what": "eq 4's Laplacian / the exact one, projected (1 = exact); cubic spline, support 2 spacings",
                       "device": "cpu (numpy)", "warp": wp.__version__, "rows": rows}, f, indent=1)


# -- scan (was tools/scan_confined.py) ---------------------------------------------------------------------------
SCAN_DOC = """Scan of the solver's knobs on Taylor-Green (diagnostic): KE/KE_exact - 1, mean and max density at 10
frames, per variant (keys: res, A (solver.shifting, default 2), max_shift, tol, dt_max, jitter (spacings), pre
(packing steps at rest in the same simulation), method, T, max_wall). It overrides the solver's module constant
MAX_SHIFT for a variant, so it is a diagnostic, not a supported interface; the packing used by the validation
cases is the scene key initial_packing (warpsph.packing). Results of the earlier confined mode (its keys B, w
and relax are gone with it): docs/notes/confined-mode.md ("Packed start").

    python tools/solver_diagnostics.py scan --device cuda --variants '[{"res": 128, "pre": 40, "jitter": 0.1}]' --out /tmp/scan.json
"""


def scan_variant(v, device):
    import warpsph.solvers.dfsph as S
    from warpsph.scene import scene_from_dict
    from warpsph.simulation import Simulation, InstabilityError
    S.MAX_SHIFT = v.get("max_shift", 0.1)
    res, nu, T = v["res"], v.get("nu", 0.01), v.get("T", 0.3)
    d = 1.0 / res
    depth = 6 * d
    solver = {"density_max_error": v.get("tol", 0.05), "shifting": v.get("A", 2.0)}
    models = {"dfsph": [], "vr": [{"type": "vorticity_refinement", "alpha": 1.0}]}[v.get("method", "dfsph")]
    data = tg.scene_data(models, res, nu, T, 10, solver)
    if v.get("dt_max"):
        data["time"] = {"dt_max": v["dt_max"]}
    sim = Simulation(scene_from_dict(data), device=device)
    rng = np.random.default_rng(1)
    x = sim.fluid.x.numpy()
    if v.get("jitter"):
        x = x + rng.uniform(-v["jitter"] * d, v["jitter"] * d, x.shape).astype(np.float32)
        x = np.mod(x, np.array([1, 1, depth], np.float32))
        sim.fluid.x.assign(x)
    for _ in range(v.get("pre", 0)):  # packing: steps at rest, velocity zeroed after each
        sim.fluid.v.zero_()
        sim.step()
    if v.get("pre", 0):
        sim.fluid.v.zero_()
    x0 = sim.fluid.x.numpy()
    t_start = sim.time
    sim.fluid.v.assign(tg.analytic_velocity(x0.astype(np.float64), 0.0, nu).astype(np.float32))
    ke0 = float((sim.fluid.v.numpy().astype(np.float64) ** 2).sum())
    rows = []
    n_frames = 10
    t0 = time.time()
    try:
        for f in range(1, n_frames + 1):
            target = t_start + f * T / n_frames
            while sim.time < target - 1e-9:
                sim.step()
                if time.time() - t0 > v.get("max_wall", 45):
                    raise TimeoutError(f"over {v.get('max_wall', 45)} s wall at t = {sim.time:.4f}")
            vv = sim.fluid.v.numpy().astype(np.float64)
            t = sim.time - t_start
            ex = float(np.exp(-16 * np.pi**2 * nu * t))
            rho = sim.fluid.density.numpy()
            rows.append([round(t, 4), round(float((vv**2).sum() / ke0 / ex - 1), 4), round(float(rho.mean() / 1000), 4),
                         round(float(rho.max() / 1000), 4)])
    except (InstabilityError, TimeoutError) as e:
        rows.append(str(e))
    it = sim.pressure_solver.iteration_totals()
    return {"variant": v, "particles": sim.num_fluid, "rows": rows, "steps": sim.step_count,
            "density_iterations": it[2] / max(it[3], 1), "wall_s": round(time.time() - t0, 1)}


def scan_main(argv=None, prog=None):
    p = argparse.ArgumentParser(prog=prog, description=SCAN_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--variants", required=True)
    p.add_argument("--out")
    a = p.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING
    out = []
    for v in json.loads(a.variants):
        r = scan_variant(v, a.device)
        out.append(r)
        print(json.dumps(v), r["particles"], r["steps"], f"it {r['density_iterations']:.1f}", f"{r['wall_s']}s")
        for row in r["rows"]:
            print("   ", row)
        if a.out:
            json.dump(out, open(a.out, "w"), indent=1)


COMMANDS = {"energy-budget": budget_main, "viscosity-moments": moments_main, "scan": scan_main}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=list(COMMANDS), help="the diagnostic")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="its options (COMMAND --help lists them)")
    args = parser.parse_args(argv)
    return COMMANDS[args.command](args.options, prog=f"{Path(parser.prog).name} {args.command}")


if __name__ == "__main__":
    sys.exit(main())
