"""warpsph and SPlisHSPlasH side by side on SPlisHSPlasH's own DamBreakModel (issue #23).

SPlisHSPlasH runs from pysplishsplash (PyPI) in its own virtual environment, headless (no GUI), on
the CPU; the scene file is read from that installation's data directory at run time (nothing of
SPlisHSPlasH is copied into this repository). warpsph runs the same file on the CPU. Both are
sampled at the first step at or after each sample time: fluid particle count, front (max x of the
fluid, and its 99th percentile), centre of mass and kinetic energy per kg, plus solver iterations.
warpsph's walls are where the importer puts them: where SPlisHSPlasH's volume maps hold the fluid
(``warpsph.io.splishsplash.container_inset``).

    python -m venv /tmp/pssvenv && /tmp/pssvenv/bin/pip install pysplishsplash==2.19.0
    python tools/splishsplash_side_by_side.py --pss-python /tmp/pssvenv/bin/python \
        --out tools/results/splishsplash_side_by_side.json

The SPlisHSPlasH half runs this same file under the other interpreter (``--worker splishsplash``).
pysplishsplash 2.19.0's wheel bundles its own libGLdispatch next to the system's libGLX, and its
import segfaults in ``__glDispatchInit`` unless the system libGLdispatch is loaded first: the worker is
started with ``LD_PRELOAD`` of it where it exists (nothing is drawn).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SCENE = "DamBreakModel.json"
TIMES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
REPORT_TIMES = (0.5, 1.0)
TOLERANCE = 0.05
GLDISPATCH = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"


def summary(t, x, v, mass, density=None, rest_density=1000.0):
    """What is compared at one sample time (equal masses: KE per kg is the mean of |v|^2 / 2)."""
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64)
    m = np.asarray(mass, np.float64) * np.ones(len(x))
    out = {"t": float(t), "particles": int(len(x)),
           "front_max_x": float(x[:, 0].max()), "front_p99_x": float(np.percentile(x[:, 0], 99)),
           "com": [float(c) for c in (m[:, None] * x).sum(0) / m.sum()],
           "max_y": float(x[:, 1].max()), "min_y": float(x[:, 1].min()), "min_x": float(x[:, 0].min()),
           "kinetic_energy_per_kg": float((0.5 * m * (v * v).sum(1)).sum() / m.sum()),
           "mass": float(m.sum())}
    if density is not None:
        d = np.asarray(density, np.float64) / rest_density
        out["density_mean"] = float(d.mean())
        out["density_median"] = float(np.median(d))
        out["density_p99"] = float(np.percentile(d, 99))
    return out


# -- SPlisHSPlasH (runs under pysplishsplash's interpreter) ---------------------------------------
def splishsplash_scene():
    import pysplishsplash  # noqa: F401  (its data directory sits beside the interpreter, as its splash script assumes)

    return Path(sys.executable).parent / "data" / "Scenes" / SCENE


def run_splishsplash(stop, out_dir):
    import pysplishsplash as sph

    scene = splishsplash_scene()
    base = sph.Exec.SimulatorBase()
    base.init(sceneFile=str(scene), useGui=False, stopAt=float(stop), outputDir=str(out_dir), initialPause=False)
    samples, steps, pending = [], [], list(TIMES)
    start = time.perf_counter()
    first = {}

    def on_step():
        sim = sph.Simulation.getCurrent()
        tm = sph.TimeManager.getCurrent()
        ts = sim.getTimeStep()
        fm = sim.getFluidModel(0)
        t = tm.getTime()
        steps.append([t, tm.getTimeStepSize(), ts.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS),
                      ts.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS_V)])
        if not first:
            n = fm.numActiveParticles()
            first.update(mass=fm.getMass(0), volume=fm.getVolume(0), density0=fm.getDensity0(),
                         radius=sim.getParticleRadius(), particles=n,
                         density_after_first_step=[fm.getDensity(i) / fm.getDensity0() for i in range(n)])
        while pending and t >= pending[0] - 1e-4:
            pending.pop(0)
            n = fm.numActiveParticles()
            x = np.array(fm.getFieldBuffer("position"), copy=True)[:n]
            v = np.array(fm.getFieldBuffer("velocity"), copy=True)[:n]
            rho = np.array(fm.getFieldBuffer("density"), copy=True)[:n]
            samples.append(summary(t, x, v, fm.getMass(0), rho, fm.getDensity0()))

    base.setTimeStepCB(on_step)
    base.run()
    d = np.asarray(first.pop("density_after_first_step"))
    first["density_after_first_step"] = {"mean": float(d.mean()), "median": float(np.median(d)), "max": float(d.max())}
    return {"program": "SPlisHSPlasH (pysplishsplash 2.19.0)", "scene": str(scene), "initial": first,
            "samples": samples, "steps": steps, "wall_s": time.perf_counter() - start}


# -- warpsph ---------------------------------------------------------------------------------------
def run_warpsph(scene_file, stop, wall_inset=0.0):
    import dataclasses

    import warp as wp

    wp.config.quiet = True
    from warpsph.io.splishsplash import conversion_of
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation

    scene = load_scene(str(scene_file))
    if wall_inset:  # experiment: the walls (not the top) moved further in than the importer puts them
        lo, hi = np.asarray(scene.domain.min), np.asarray(scene.domain.max)
        hi_inset = np.array([wall_inset, 0.0, wall_inset])
        scene = dataclasses.replace(scene, domain=dataclasses.replace(
            scene.domain, min=tuple(float(c) for c in lo + wall_inset), max=tuple(float(c) for c in hi - hi_inset)))
    sim = Simulation(scene, device="cpu")
    samples, steps, pending = [], [], [t for t in TIMES if t <= stop + 1e-9]
    start = time.perf_counter()
    totals_before = sim.pressure_solver.iteration_totals()
    while pending:
        sim.step()
        problem = sim.check_health()
        if problem is not None:
            raise problem
        t = sim.time
        totals = sim.pressure_solver.iteration_totals()
        steps.append([t, float(sim.dt.numpy()[0]), totals[2] - totals_before[2], totals[0] - totals_before[0]])
        totals_before = totals
        while pending and t >= pending[0] - 1e-4:
            pending.pop(0)
            n = sim.num_fluid
            samples.append(summary(t, sim.fluid.x.numpy()[:n], sim.fluid.v.numpy()[:n], sim.particle_mass,
                                   sim.fluid.density.numpy()[:n], sim.rest_density))
    conversion = conversion_of(scene)
    return {"program": "warpsph", "scene": str(scene_file), "wall_inset": wall_inset,
            "domain": {"min": list(scene.domain.min), "max": list(scene.domain.max)},
            "initial": {"mass": sim.particle_mass, "volume": sim.fluid_volume, "density0": sim.rest_density,
                        "radius": scene.particle_radius, "particles": sim.num_fluid},
            "mapped": conversion.mapped if conversion else None, "notes": conversion.notes if conversion else None,
            "samples": samples, "steps": steps, "wall_s": time.perf_counter() - start}


# -- comparison ------------------------------------------------------------------------------------
def compare(theirs, ours):
    rows = []
    by_time = {round(s["t"] + 1e-4, 1): s for s in ours["samples"]}
    for s in theirs["samples"]:
        t = round(s["t"] + 1e-4, 1)
        if t not in by_time:
            continue
        w = by_time[t]
        row = {"t": t, "t_splishsplash": s["t"], "t_warpsph": w["t"]}
        for key in ("particles", "front_max_x", "front_p99_x", "kinetic_energy_per_kg", "max_y", "min_y", "min_x", "mass"):
            row[key] = {"splishsplash": s[key], "warpsph": w[key],
                        "relative_difference": (w[key] - s[key]) / abs(s[key]) if s[key] else None}
        row["com"] = {"splishsplash": s["com"], "warpsph": w["com"]}
        rows.append(row)
    return rows


def iterations(steps):
    a = np.asarray(steps, np.float64)
    return {"steps": int(len(a)), "mean_dt": float(a[:, 1].mean()) if len(a) else None,
            "density_iterations_per_step": float(a[:, 2].mean()) if len(a) else None,
            "divergence_iterations_per_step": float(a[:, 3].mean()) if len(a) else None}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pss-python", default="/tmp/pssvenv/bin/python", help="interpreter with pysplishsplash 2.19.0")
    ap.add_argument("--stop", type=float, default=1.0)
    ap.add_argument("--out", default="tools/results/splishsplash_side_by_side.json")
    ap.add_argument("--work", default="/tmp/splishsplash_side_by_side", help="SPlisHSPlasH's output directory")
    ap.add_argument("--splishsplash-json", help="reuse a finished SPlisHSPlasH run (the worker's JSON)")
    ap.add_argument("--wall-inset", type=float, default=0.0,
                    help="experiment: move warpsph's walls (not the top) this much [m] further in than the importer "
                         "puts them (where SPlisHSPlasH's volume maps hold the fluid)")
    ap.add_argument("--worker", choices=["splishsplash"], help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.worker == "splishsplash":
        result = run_splishsplash(args.stop, args.work)
        Path(args.worker_out).write_text(json.dumps(result))
        return 0

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    theirs_file = Path(args.splishsplash_json) if args.splishsplash_json else work / "splishsplash.json"
    if not args.splishsplash_json:
        env = dict(os.environ)
        if os.path.exists(GLDISPATCH):
            env["LD_PRELOAD"] = GLDISPATCH
        subprocess.run([args.pss_python, __file__, "--worker", "splishsplash", "--stop", str(args.stop),
                        "--work", str(work), "--worker-out", str(theirs_file)], env=env, check=True,
                       stdout=subprocess.DEVNULL)
    theirs = json.loads(theirs_file.read_text())
    ours = run_warpsph(theirs["scene"], args.stop, args.wall_inset)
    rows = compare(theirs, ours)
    report = [r for r in rows if r["t"] in REPORT_TIMES]
    keys = ("particles", "front_max_x", "kinetic_energy_per_kg")
    agree = all(abs(r[k]["relative_difference"]) <= TOLERANCE for r in report for k in keys)
    result = {
        "scene": f"pysplishsplash 2.19.0 data/Scenes/{SCENE}", "device": "cpu", "tolerance": TOLERANCE,
        "warpsph_wall_inset_m": args.wall_inset, "warpsph_domain": ours["domain"],
        "agree_within_tolerance": agree, "compared": list(keys), "report_times": list(REPORT_TIMES),
        "initial": {"splishsplash": theirs["initial"], "warpsph": ours["initial"]},
        "iterations": {"splishsplash": iterations(theirs["steps"]), "warpsph": iterations(ours["steps"])},
        "wall_s": {"splishsplash": theirs["wall_s"], "warpsph": ours["wall_s"]},
        "rows": rows,
        "warpsph_mapping": ours["mapped"], "warpsph_notes": ours["notes"],
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    for r in rows:
        print(f"t={r['t']:.1f}  " + "  ".join(
            f"{k}: {r[k]['splishsplash']:.4g} vs {r[k]['warpsph']:.4g} ({100 * r[k]['relative_difference']:+.1f} %)"
            for k in ("front_max_x", "front_p99_x", "kinetic_energy_per_kg")))
    print("iterations", result["iterations"])
    print("agree within 5 %:", agree)
    return 0


if __name__ == "__main__":
    sys.exit(main())
