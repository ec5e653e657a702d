"""Tanks at rest (#37) in SPlisHSPlasH: a reference for warpsph/validation/rest.py (rest_vs_splishsplash_cpu.json).

    python tools/results/rest_vs_splishsplash.py all --res 16 24 --fills 1.0 0.88 --boundaries 0 2 --nus 0.05 1e-6 \
        --rows /tmp/rows --json tools/results/rest_vs_splishsplash_cpu.json
    LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 OMP_NUM_THREADS=1 /work/splish-venv/bin/python \
        tools/results/rest_vs_splishsplash.py one --res 16 --fill 1.0 --boundary 0 --inset 1.2 --nu 0.05 --out ROW.json
    python tools/results/rest_vs_splishsplash.py collect ROW.json ... --json tools/results/rest_vs_splishsplash_cpu.json

``one`` (SPlisHSPlasH's venv, one thread) writes a scene file under SPlisHSPlasH's data/Scenes (absolute paths), runs
it headless (pysplishsplash's SimulatorBase, a callback after each step, as time_step_vs_splishsplash.py) and writes
one row. ``all`` (warpsph's venv: it takes ``inset`` from warpsph's importer) runs each case missing from ``--rows`` as
``one``, one at a time, then ``collect``s them. rest_vs_splishsplash_cpu.json: ``one`` runs, two at a time on the
two cores of a shared machine (wall times only indicative), then ``collect``.

The case is rest.py's: a cube of side 0.4 m, walls on every face, ``res`` particles across (r = 0.4 / (2 res)),
water to the lid (fill 1) or to 88 % in whole layers (round(0.88 res) layers), T = 5 s; the largest fluid speed
over the last second (every step) against sqrt(g H), H the water height. The fluid lattice is warpsph's (centres at
r, 3r, ... from the faces: a FluidBlock [-r, side + r], SPlisHSPlasH starting 2r inside it); the container is the
box whose import by warpsph.io.splishsplash is warpsph's domain [0, 0.4]^3: the faces ``inset`` r outside it
(container_inset: 1.40 r for a volume map, which holds the fluid 2.40 r from its surface; 1.2 r for boundary
particles, warpsph's wall layer). Gravity: ``ramp`` sets Simulation.GRAVITATION in the callback before each step to
rest.py's smooth step over 0.2 s (the scene starts at 0); ``full`` starts at -9.81.

The density is SPlisHSPlasH's ``density`` field after the last step: the summation density DFSPH computed at the
start of that step (before its last position update), walls included (its boundary model).
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

SIDE = 0.4
T_END = 5.0
RAMP = 0.2
G = 9.81
POOL_FILL = 0.88
from splishsplash_host import SPLISH_PY, machine, splish_version  # noqa: E402
SCENES = "/work/splish-venv/bin/data/Scenes"
UNIT_BOX = "/work/splish-venv/bin/data/models/UnitBox.obj"
PRELOAD = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"


def layers_of(res, fill):
    """rest.py's whole layers: all of them sealed, else round(fill res) with at least one empty."""
    return res if fill >= 1.0 else max(1, min(res - 1, round(fill * res)))


def scene_dict(res, fill, boundary, nu, inset, gravity, cfl, map_cells, t_end=T_END):
    """The SPlisHSPlasH scene; ``inset`` in r: how far the container's faces stand outside [0, SIDE]."""
    r = SIDE / (2 * res)
    height = layers_of(res, fill) * 2 * r
    # warpsph's bounds: dt_max 0.2 s/m x r, dt_min that / 50, and the explicit viscous limit 0.125 (2r)^2 / nu
    # (solver.viscosity_substeps 1, the default) on dt_max; SPlisHSPlasH has no viscous limit of its own: without
    # it the 16-across sealed box at nu = 0.05 stepped at 2.1 ms on average (1.3x the limit) and reached 215 % of
    # sqrt(gH)
    dt_min = 0.2 * r / 50
    dt_max = min(0.2 * r, 0.125 * (2 * r) ** 2 / nu) if nu > 0 else 0.2 * r
    box = SIDE + 2 * inset * r
    material = {"id": "Fluid", "density0": 1000}
    if nu > 0:
        material.update({"viscosityMethod": 1, "Standard viscosity": {"viscosity": nu, "viscosityBoundary": 0.0}})
    else:
        material["viscosityMethod"] = 0
    # volume map: SPlisHSPlasH 2.19's grid spans the box and 32 r beyond each face (its log); cells of about
    # map_cells x r over it. Coarser maps over-weight the walls along the edges: the sealed box at 16 across, t = 0,
    # edge particles at rho / rho0 2.64 / 2.44 / 1.41 with 9 / 18 / 35 cells (11 / 5.5 / 2.8 r; Akinci 0.99)
    cells = max(4, int(np.ceil((box + 64 * r) / (map_cells * r))))
    return {
        "Configuration": {
            "particleRadius": r, "simulationMethod": 4, "boundaryHandlingMethod": boundary,
            "gravitation": [0.0, 0.0, 0.0] if gravity == "ramp" else [0.0, -G, 0.0],
            "timeStepSize": dt_max, "cflMethod": 1, "cflFactor": cfl,
            "cflMinTimeStepSize": dt_min, "cflMaxTimeStepSize": dt_max,
            "stopAt": t_end, "enableZSort": True,
            "DFSPH": {"minIterations": 2, "maxIterations": 100, "maxError": 0.01,
                      "maxIterationsV": 100, "maxErrorV": 0.1, "enableDivergenceSolver": True},
        },
        "Materials": [material],
        "RigidBodies": [{
            "geometryFile": UNIT_BOX, "translation": [SIDE / 2] * 3, "rotationAxis": [1, 0, 0], "rotationAngle": 0,
            "scale": [box] * 3, "isDynamic": False, "isWall": True, "mapInvert": True, "mapThickness": 0.0,
            "mapResolution": [cells] * 3,
        }],
        "FluidBlocks": [{"denseMode": 0, "start": [-r, -r, -r], "end": [SIDE + r, height + r, SIDE + r],
                         "translation": [0, 0, 0], "scale": [1, 1, 1]}],
    }


def run_one(a):
    import pysplishsplash as sph

    r = SIDE / (2 * a.res)
    height = layers_of(a.res, a.fill) * 2 * r
    scene = scene_dict(a.res, a.fill, a.boundary, a.nu, a.inset, a.gravity, a.cfl, a.map_cells, a.t_end)
    name = f"RestVsWarpsph_r{a.res}_f{int(round(100 * a.fill))}_b{a.boundary}_nu{a.nu:g}_{a.gravity}"
    path = os.path.join(SCENES, name + ".json")
    json.dump(scene, open(path, "w"), indent=1)

    base = sph.Exec.SimulatorBase()
    t0 = time.perf_counter()
    base.init(sceneFile=path, useGui=False, stopAt=a.t_end, outputDir=f"/tmp/rest_vs_pss_out/{name}",
              initialPause=False)
    state = {"events": [], "t_last": 0.0, "steps": 0, "vmax_last_s": 0.0, "t_vmax": None, "first": None, "dts": [],
             "series": []}

    def on_step():
        sim, tm = sph.Simulation.getCurrent(), sph.TimeManager.getCurrent()
        fm = sim.getFluidModel(0)
        n = fm.numActiveParticles()
        t = tm.getTime()
        if state["first"] is None:
            x0 = np.array(fm.getFieldBuffer("position"), copy=True)[:n]
            state["first"] = {"n": int(n), "xmin": x0.min(0).tolist(), "xmax": x0.max(0).tolist()}
        v = np.array(fm.getFieldBuffer("velocity"), copy=False)[:n]
        speed = float(np.sqrt((v * v).sum(1).max()))
        state["steps"] += 1
        state["dts"].append(tm.getTimeStepSize())
        if state["steps"] % 20 == 0:
            state["series"].append([round(t, 4), speed])
        if int(t / 0.25) != int(state["t_last"] / 0.25):  # progress, every 0.25 s simulated
            print(f"progress t {t:.3f} steps {state['steps']} dt {tm.getTimeStepSize():.2e} vmax {speed:.3e} "
                  f"wall {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        state["t_last"] = t
        if t > a.t_end - 1.0:
            if speed > state["vmax_last_s"]:
                state["vmax_last_s"], state["t_vmax"] = speed, t
            if speed > 0.05 and len(state["events"]) < 400:  # where the fast particles are (a burst)
                sp = np.sqrt((v * v).sum(1))
                x = np.array(fm.getFieldBuffer("position"), copy=False)[:n]
                i = int(sp.argmax())
                fast = sp > 0.05
                state["events"].append({"t": round(t, 5), "vmax": speed, "x_fastest": x[i].round(5).tolist(),
                                        "n_above_0.05": int(fast.sum()),
                                        "y_of_above_0.05": [float(x[fast, 1].min()), float(x[fast, 1].max())]})
            if state["steps"] % 10 == 0:  # the 99th percentile and the mean: is the largest speed a few particles'?
                sp = np.sqrt((v * v).sum(1))
                state["p99"] = max(state.get("p99", 0.0), float(np.percentile(sp, 99)))
                state["mean"] = max(state.get("mean", 0.0), float(sp.mean()))
        if a.gravity == "ramp":  # the next step's gravity, at this time (rest.py's ramp_gravity before sim.step())
            s = min(t / RAMP, 1.0)
            sim.setVec3ValueReal(sph.Simulation.GRAVITATION, [0.0, -G * (3 * s * s - 2 * s * s * s), 0.0])

    base.setTimeStepCB(on_step)
    base.initSimulation()
    t1 = time.perf_counter()
    base.runSimulation()  # run() = initSimulation, runSimulation, cleanup: the fields are read before cleanup
    wall = time.perf_counter() - t1
    sim, tm = sph.Simulation.getCurrent(), sph.TimeManager.getCurrent()
    fm = sim.getFluidModel(0)
    n = fm.numActiveParticles()
    x = np.array(fm.getFieldBuffer("position"), copy=True)[:n]
    v = np.array(fm.getFieldBuffer("velocity"), copy=True)[:n]
    rho = np.array(fm.getFieldBuffer("density"), copy=True)[:n]
    err = rho / fm.getDensity0() - 1.0
    # away from the free surface: below the top three layers' starting heights (all of a sealed box)
    deep = x[:, 1] < height - 6 * r if a.fill < 1.0 else np.ones(n, bool)
    speed_end = float(np.linalg.norm(v, axis=1).max())
    vmax = max(state["vmax_last_s"], speed_end)
    scale = float(np.sqrt(G * height))
    out = {"res": a.res, "fill": a.fill, "boundary": a.boundary, "nu": a.nu, "gravity": a.gravity, "cfl": a.cfl,
           "inset_r": a.inset, "radius": r, "water_height_m": height, "particles": int(n), "steps": state["steps"],
           "time_end": tm.getTime(), "dt_mean": float(np.mean(state["dts"])), "dt_min": float(np.min(state["dts"])),
           "max_speed_last_second": vmax, "p99_speed_last_second_max": state.get("p99"),
           "mean_speed_last_second_max": state.get("mean"),
           "last_second_steps_above_0.05_m_s": state["events"], "t_of_max": state["t_vmax"], "speed_end": speed_end,
           "max_speed_over_sqrt_gH": vmax / scale, "max_speed_over_sqrt_gH_pct": 100 * vmax / scale,
           "density_error_mean_pct": 100 * float(err.mean()),
           "density_error_mean_abs_pct": 100 * float(np.abs(err).mean()),
           "density_error_mean_deep_pct": 100 * float(err[deep].mean()),
           "density_error_min_pct": 100 * float(err.min()), "density_error_max_pct": 100 * float(err.max()),
           "fluid_y_range_end": [float(x[:, 1].min()), float(x[:, 1].max())],
           "first_step_lattice": state["first"], "wall_s": wall, "setup_s": t1 - t0,
           "speed_series_every_20_steps": state["series"], "scene_file": path, "scene": scene}
    json.dump(out, open(a.out, "w"))
    base.cleanup()


def row_name(res, fill, boundary, nu, gravity, t_end):
    return f"r{res}_f{fill:g}_b{boundary}_nu{nu:g}_{gravity}_T{t_end:g}"


def run_all(a):
    """Runs each case not yet in ``a.rows`` (one at a time), then collects every row there into ``a.json``."""
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))
    from warpsph.io.splishsplash import container_inset

    os.makedirs(a.rows, exist_ok=True)
    for res in a.res:
        for fill in a.fills:
            for boundary in a.boundaries:
                for nu in a.nus:
                    for gravity in a.gravities:
                        out = os.path.join(a.rows, row_name(res, fill, boundary, nu, gravity, a.t_end) + ".json")
                        if os.path.exists(out):
                            continue
                        inset = container_inset(boundary, 0.0, 1.0)[0]
                        cmd = [SPLISH_PY, __file__, "one", "--res", str(res), "--fill", str(fill), "--boundary",
                               str(boundary), "--nu", str(nu), "--gravity", gravity, "--inset", repr(inset),
                               "--cfl", str(a.cfl), "--map-cells", str(a.map_cells), "--t-end", str(a.t_end),
                               "--out", out]
                        env = dict(os.environ, LD_PRELOAD=PRELOAD, OMP_NUM_THREADS="1")
                        p = subprocess.run(cmd, env=env, capture_output=True, text=True)
                        with open(out[:-5] + ".log", "w") as log:  # SPlisHSPlasH's timings and counters: collect
                            log.write(p.stdout + p.stderr)
                        if p.returncode != 0 or not os.path.exists(out):
                            print(f"{out}: failed rc {p.returncode}\n{p.stderr[-2000:]}", flush=True)
    collect(sorted(os.path.join(a.rows, f) for f in os.listdir(a.rows) if f.endswith(".json")), a.json)


SUMMARY = ("res", "fill", "boundary", "nu", "gravity", "time_end", "particles", "steps", "dt_mean",
           "max_speed_last_second", "max_speed_over_sqrt_gH_pct", "p99_speed_last_second_max",
           "mean_speed_last_second_max", "density_error_mean_pct", "density_error_mean_deep_pct",
           "density_iterations_mean", "wall_s")


NOTES = (
    "DFSPH (simulationMethod 4): maxError 0.01 %, maxErrorV 0.1 %/s, minIterations 2, maxIterations(V) 100, "
    "divergence solver on: warpsph's solver defaults (scene.py Solver)",
    "CFL: cflMethod 1, cflFactor 0.5 (warpsph's time.cfl default; the same rule cfl x 0.4 x 2r / u), "
    "cflMaxTimeStepSize min(0.2 s/m x r, 0.125 (2r)^2 / nu) (warpsph's dt_max and its explicit viscous limit with "
    "solver.viscosity_substeps 1; SPlisHSPlasH has no viscous limit: without it the 16-across sealed box at "
    "nu 0.05 stepped at 2.1 ms on average (1.3x the limit of 1.56 ms, at most 2.5 ms) and reached 215 % of "
    "sqrt(gH) (0.38 % with the limit)), cflMinTimeStepSize 0.2 r / 50",
    "viscosity: 'Standard viscosity' (viscosityMethod 1), viscosity = warpsph's fluid.viscosity (kinematic, "
    "m^2/s; warpsph.io.splishsplash maps it one to one), viscosityBoundary 0 (warpsph's boundary_viscosity 0); "
    "water: 1e-6 in the same model",
    "boundary: 0 = Akinci 2012 (boundary particles, SPlisHSPlasH's regular triangle sampling of UnitBox.obj), "
    "container faces 1.2 r outside [0, 0.4]; 2 = Bender 2019 volume map, faces 1.40 r outside, map cells ~2 r",
    "gravity 'ramp': Simulation.GRAVITATION set in the step callback to rest.py's smooth step over 0.2 s; "
    "'full': -9.81 from t = 0",
    "density: SPlisHSPlasH's density field after the last step (computed at that step's start), boundary "
    "included; 'deep' = particles below H - 6 r (all in the sealed box)",
    "the boundary 2 sealed box is run to 0.1 s only: it blows up (dt at cflMinTimeStepSize, 99 density "
    "iterations a step, speeds of 100s of m/s) from the edges' over-weighting at t = 0",
)


def collect(files, path, notes=NOTES):
    """Writes the rows in ``files`` (``one``'s outputs) into ``path``, a summary first."""
    runs = [json.load(open(f)) for f in files]
    for f, r in zip(files, runs):  # SPlisHSPlasH's averages a step, from the run's log (ROW.log) where it is there
        log = f[:-5] + ".log"
        if os.path.exists(log):
            for line in open(log, errors="replace"):
                for key, name in (("DFSPH - iterations:", "density_iterations_mean"),
                                  ("DFSPH - iterationsV:", "divergence_iterations_mean")):
                    if line.startswith("Average number: " + key):
                        r[name] = float(line.split()[-1])
    for r in runs:  # the burst's record, thinned to ~30 steps (one in k) and the fastest one
        ev = r.get("last_second_steps_above_0.05_m_s")
        if ev:
            r["last_second_steps_above_0.05_m_s_count"] = len(ev)
            k = max(1, len(ev) // 30)
            fastest = max(ev, key=lambda e: e["vmax"])
            r["last_second_steps_above_0.05_m_s"] = sorted({id(e): e for e in ev[::k] + [fastest]}.values(),
                                                          key=lambda e: e["t"])
    runs.sort(key=lambda r: (r["boundary"], -r["nu"], r["res"], -r["fill"], r["gravity"], r["time_end"]))
    doc = {"what": "tanks at rest (#37) in SPlisHSPlasH, warpsph/validation/rest.py's case (see the script's "
                   "docstring); max speed over the last second of [0, time_end] against sqrt(g H)",
           "script": "tools/results/rest_vs_splishsplash.py", "machine": machine(), "threads": 1,
           "splishsplash": splish_version(), "notes": list(notes),
           "summary": [{k: r.get(k) for k in SUMMARY} for r in runs], "runs": runs}
    json.dump(doc, open(path, "w"), indent=1)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["one", "all", "collect"])
    ap.add_argument("--res", type=int, nargs="+", default=[16])
    ap.add_argument("--fill", type=float, default=1.0)
    ap.add_argument("--fills", type=float, nargs="+", default=[1.0, POOL_FILL])
    ap.add_argument("--boundary", type=int, default=2)
    ap.add_argument("--boundaries", type=int, nargs="+", default=[2])
    ap.add_argument("--nu", type=float, default=0.05)
    ap.add_argument("--nus", type=float, nargs="+", default=[0.05])
    ap.add_argument("--gravity", choices=["ramp", "full"], default="ramp")
    ap.add_argument("--gravities", nargs="+", default=["ramp"])
    ap.add_argument("--inset", type=float, default=1.401272890620082)
    ap.add_argument("--cfl", type=float, default=0.5)  # warpsph's time.cfl default (same rule: cfl x 0.4 x 2r / u)
    ap.add_argument("--map-cells", type=float, default=2.0)  # volume map cell in r
    ap.add_argument("--t-end", type=float, default=T_END)  # a shorter run: a test
    ap.add_argument("--out", default="/tmp/rest_vs_pss.json")
    ap.add_argument("--json", default="tools/results/rest_vs_splishsplash_cpu.json")
    ap.add_argument("--rows", default="/tmp/rest_vs_splishsplash_rows")  # all: one JSON a case, kept between calls
    ap.add_argument("files", nargs="*")  # collect: the rows to write into --json
    a = ap.parse_args()
    if a.mode == "one":
        a.res = a.res[0]
        run_one(a)
    elif a.mode == "collect":
        collect(a.files, a.json)
    else:
        run_all(a)
