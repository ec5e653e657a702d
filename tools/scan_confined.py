"""Scan of the solver's knobs on Taylor-Green (diagnostic): KE/KE_exact - 1, mean and max density at 10
frames, per variant (keys: res, A (solver.shifting, default 2), max_shift, tol, dt_max, jitter (spacings), pre
(packing steps at rest in the same simulation), method, T, max_wall). It overrides the solver's module constant
MAX_SHIFT for a variant, so it is a diagnostic, not a supported interface; the packing used by the validation
cases is the scene key initial_packing (warpsph.packing). Results of the earlier confined mode (its keys B, w
and relax are gone with it): docs/notes/confined-mode.md ("Packed start").

    python tools/scan_confined.py --device cuda --variants '[{"res": 128, "pre": 40, "jitter": 0.1}]' --out /tmp/scan.json
"""
import argparse, json, time
import numpy as np
import warp as wp

from warpsph.validation.taylor_green import analytic_velocity, scene_data


def run(v, device):
    import warpsph.solver as S
    from warpsph.scene import scene_from_dict
    from warpsph.simulation import Simulation, InstabilityError
    S.MAX_SHIFT = v.get("max_shift", 0.1)
    res, nu, T = v["res"], v.get("nu", 0.01), v.get("T", 0.3)
    d = 1.0 / res
    depth = 6 * d
    solver = {"density_max_error": v.get("tol", 0.05), "shifting": v.get("A", 2.0)}
    models = {"dfsph": [], "vr": [{"type": "vorticity_refinement", "alpha": 1.0}]}[v.get("method", "dfsph")]
    data = scene_data(models, res, nu, T, 10, solver)
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
    sim.fluid.v.assign(analytic_velocity(x0.astype(np.float64), 0.0, nu).astype(np.float32))
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


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--device", default="cpu")
    p.add_argument("--variants", required=True)
    p.add_argument("--out")
    a = p.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    out = []
    for v in json.loads(a.variants):
        r = run(v, a.device)
        out.append(r)
        print(json.dumps(v), r["particles"], r["steps"], f"it {r['density_iterations']:.1f}", f"{r['wall_s']}s")
        for row in r["rows"]:
            print("   ", row)
        if a.out:
            json.dump(out, open(a.out, "w"), indent=1)


if __name__ == "__main__":
    main()
