"""The Martin & Moyce dam front (issue #37) in SPlisHSPlasH, as a reference for warpsph/validation/dam_front.py
(dam_front_vs_splishsplash_cpu.json).

    J=tools/results/dam_front_vs_splishsplash_cpu.json   # the runs of the JSON, in its order:
    python tools/results/dam_front_vs_splishsplash.py all --res 10 20 --boundaries 2 0 --dt-maxes 0 0.2 \
        --map-cells 2 --map-cells-z 1 --json $J
    python tools/results/dam_front_vs_splishsplash.py all --res 40 --boundaries 2 0 --dt-maxes 0 --map-cells-z 1 --append --json $J
    python tools/results/dam_front_vs_splishsplash.py all --res 40 --boundaries 0 2 --dt-maxes 0.2 --map-cells-z 1 --append --json $J
    python tools/results/dam_front_vs_splishsplash.py all --res 10 --boundaries 2 --map-cells-z 0.5 --append --json $J
    python tools/results/dam_front_vs_splishsplash.py all --res 10 --boundaries 2 --map-cells 1 --append --json $J
    python tools/results/dam_front_vs_splishsplash.py all --res 10 20 --boundaries 2 --append --json $J
    python tools/results/dam_front_vs_splishsplash.py all --res 20 --boundaries 2 --map-cells-z 0.5 --append --json $J
    python tools/results/dam_front_vs_splishsplash.py mark --json $J   # flags (mark()) and warpsph's rows
    LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 OMP_NUM_THREADS=1 /work/splish-venv/bin/python \
        tools/results/dam_front_vs_splishsplash.py one --res 10 --boundary 2 --inset 1.4013 --map-cells-z 1 --out X.json

``all`` (warpsph's venv: it takes the container inset from warpsph.io.splishsplash and scores the fronts with
warpsph.validation.dam_front.compare) runs each case as ``one`` in SPlisHSPlasH's venv, one at a time, on one
thread, and writes the JSON after every case. ``one`` writes a scene file under SPlisHSPlasH's data/Scenes
(absolute paths) and runs it headless (pysplishsplash's SimulatorBase, a callback after each step, as
time_step_vs_splishsplash.py).

The case is dam_front.py's: a column a wide and 2a high (a = 0.05715 m) at the back of a tank 12a long, 2.5a high
and ``depth`` particle diameters deep (4), walls on every face, r = a / (2 res), water (nu 1e-6 m^2/s, SPlisHSPlasH's
Standard viscosity, no boundary viscosity as warpsph's default), gravity -9.81 from t = 0, run to T = 6 with
T = t sqrt(2 g / a). The fluid lattice is warpsph's (centres at r, 3r, ... from the faces: a FluidBlock
[-r, a + r] x [-r, 2a + r] x [-r, depth 2r + r], SPlisHSPlasH starting 2r inside it); the container is the box
whose import by warpsph.io.splishsplash is warpsph's domain [0, 12a] x [0, 2.5a] x [0, depth 2r]: its faces
``inset`` r outside the domain (container_inset: 1.40 r for a volume map, which holds the fluid 2.40 r from its
surface; 1.2 r for boundary particles, warpsph's wall layer), so the fluid rests r inside the domain's faces in
both codes. The front Z after every step is dam_front.py's: the 99.5th percentile of x (from the back face x = 0)
among the particles with y < a. The saved arrays keep the first step at or after each 1/16 of T (every step
where steps are longer) and T = 0; compare() scores them; the score of every step is kept beside it.

DFSPH (simulationMethod 4), maxError 0.01 %, the rest of DFSPH's keys and the CFL rule SPlisHSPlasH's defaults
unless ``--dt-max`` (seconds; then cflMinTimeStepSize dt_max / 50, warpsph's rule) is given (``all``: ``--dt-maxes``
in s/m x r, warpsph's default 0.2). The volume map's cells are ``--map-cells`` r (2), ``--map-cells-z`` r across the
thin depth: with 2 r there (6 cells across) the 20-across run blows up.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

A = 0.05715  # m, as dam_front.py
G = 9.81
T_END = 6.0
DEPTH = 4
from splishsplash_host import SPLISH_PY, machine, splish_version  # noqa: E402
SCENES = "/work/splish-venv/bin/data/Scenes"
UNIT_BOX = "/work/splish-venv/bin/data/models/UnitBox.obj"
PRELOAD = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"
SAMPLES_PER_T = 16
FAST = 3.0  # m/s: well above the front's ~2 m/s (Ritter's 2 sqrt(2 g a) = 2.1 m/s); a faster particle is recorded
# Koshizuka & Oka (1996), experiment, (T, Z/L), from ../shared/reference/sph-facts.md (T = t sqrt(2 g / L))
KOSHIZUKA_OKA = np.array([(0.0, 1.000), (0.381, 1.111), (0.769, 1.252), (1.153, 1.505), (1.537, 1.892),
                          (1.935, 2.241), (2.323, 2.615), (2.719, 3.003), (3.096, 3.624)])


def scene_dict(a):
    r = A / (2 * a.res)
    d = 2 * r
    domain = np.array([12 * A, 2.5 * A, a.depth * d])
    box = domain + 2 * a.inset * r
    sizes = [a.map_cells, a.map_cells, a.map_cells_z or a.map_cells]
    cells = [max(4, int(np.ceil(b / (c * r)))) for b, c in zip(box, sizes)]
    config = {
        "particleRadius": r, "simulationMethod": 4, "boundaryHandlingMethod": a.boundary,
        "gravitation": [0.0, -G, 0.0], "stopAt": a.t_end / np.sqrt(2 * G / A),
        "DFSPH": {"maxError": 0.01},
    }
    if a.dt_max:
        config.update({"timeStepSize": a.dt_max, "cflMaxTimeStepSize": a.dt_max, "cflMinTimeStepSize": a.dt_max / 50})
    material = {"id": "Fluid", "density0": 1000, "viscosityMethod": 1,
                "Standard viscosity": {"viscosity": a.nu, "viscosityBoundary": 0.0}}
    body = {"geometryFile": UNIT_BOX, "translation": (domain / 2).tolist(), "rotationAxis": [1, 0, 0],
            "rotationAngle": 0, "scale": box.tolist(), "isDynamic": False, "isWall": True, "mapInvert": True,
            "mapThickness": 0.0, "mapResolution": cells}
    block = {"denseMode": 0, "start": [-r, -r, -r], "end": [A + r, 2 * A + r, a.depth * d + r],
             "translation": [0, 0, 0], "scale": [1, 1, 1]}
    return {"Configuration": config, "Materials": [material], "RigidBodies": [body], "FluidBlocks": [block]}


def front(x):
    low = x[:, 1] < A
    return float(np.percentile(x[low, 0], 99.5) / A) if low.any() else 0.0


def run_one(a):
    import pysplishsplash as sph

    scale_T = np.sqrt(2 * G / A)
    scene = scene_dict(a)
    name = f"DamFrontVsWarpsph_r{a.res}_b{a.boundary}_d{a.depth}" + (f"_dt{a.dt_max:g}" if a.dt_max else "")
    path = os.path.join(SCENES, name + ".json")
    json.dump(scene, open(path, "w"), indent=1)

    base = sph.Exec.SimulatorBase()
    t0 = time.perf_counter()
    base.init(sceneFile=path, useGui=False, stopAt=scene["Configuration"]["stopAt"],
              outputDir=f"/tmp/dam_front_pss_out/{name}", initialPause=False)
    base.initSimulation()
    sim, tm = sph.Simulation.getCurrent(), sph.TimeManager.getCurrent()
    fm = sim.getFluidModel(0)
    n = fm.numActiveParticles()
    x0 = np.array(fm.getFieldBuffer("position"), copy=True)[:n]
    rows = [(0.0, front(x0), 0.0)]
    speeds = [0.0]
    lo, hi = x0.min(0), x0.max(0)
    state = {"lo": lo.copy(), "hi": hi.copy(), "vmax": 0.0, "fast": None}
    r = A / (2 * a.res)

    def on_step():
        t = tm.getTime()
        x = np.array(fm.getFieldBuffer("position"), copy=False)[:n]
        v = np.array(fm.getFieldBuffer("velocity"), copy=False)[:n]
        rows.append((t * scale_T, front(x), t - (rows[-1][0] / scale_T)))
        state["lo"] = np.minimum(state["lo"], x.min(0))
        state["hi"] = np.maximum(state["hi"], x.max(0))
        speed = np.sqrt((v * v).sum(1))
        speeds.append(float(speed.max()))
        state["vmax"] = max(state["vmax"], speeds[-1])
        if state["fast"] is None and speeds[-1] > FAST:  # the first step with a particle faster than FAST
            i = int(np.argmax(speed))
            state["fast"] = {"T": t * scale_T, "speed": speeds[-1], "x_over_r": (x[i] / r).tolist(),
                             "v": v[i].tolist(), "above_FAST": int((speed > FAST).sum())}

    base.setTimeStepCB(on_step)
    t1 = time.perf_counter()
    base.runSimulation()
    wall = time.perf_counter() - t1
    T, Z, dt = (np.array(c) for c in zip(*rows))
    keep = [0]
    for k in range(1, int(np.ceil(T[-1] * SAMPLES_PER_T)) + 1):
        i = int(np.searchsorted(T, k / SAMPLES_PER_T - 1e-12))
        if i < len(T) and i != keep[-1]:
            keep.append(i)
    params = {"cflMethod": sim.getValueInt(sph.Simulation.CFL_METHOD),
              "cflFactor": sim.getValueFloat(sph.Simulation.CFL_FACTOR),
              "cflMinTimeStepSize": sim.getValueFloat(sph.Simulation.CFL_MIN_TIMESTEPSIZE),
              "cflMaxTimeStepSize": sim.getValueFloat(sph.Simulation.CFL_MAX_TIMESTEPSIZE),
              "kernelMethod": sim.getValueInt(sph.Simulation.KERNEL_METHOD),
              "gradKernelMethod": sim.getValueInt(sph.Simulation.GRAD_KERNEL_METHOD),
              "boundaryHandlingMethod": sim.getValueInt(sph.Simulation.BOUNDARY_HANDLING_METHOD)}
    ts = sim.getTimeStep()
    for key, pid, get in (("minIterations", "MIN_ITERATIONS", "getValueUInt"),
                          ("maxIterations", "MAX_ITERATIONS", "getValueUInt"),
                          ("maxError", "MAX_ERROR", "getValueFloat"),
                          ("maxIterationsV", "MAX_ITERATIONS_V", "getValueUInt"),
                          ("maxErrorV", "MAX_ERROR_V", "getValueFloat"),
                          ("enableDivergenceSolver", "USE_DIVERGENCE_SOLVER", "getValueBool")):
        try:
            params["DFSPH." + key] = getattr(ts, get)(getattr(sph.TimeStepDFSPH, pid))
        except Exception as e:  # noqa: BLE001 - only a record of what the binding offers
            params["DFSPH." + key] = f"not read: {e}"
    try:
        visc = fm.getViscosityBase()
        params["viscosity_read_back"] = visc.getValueFloat(visc.VISCOSITY_COEFFICIENT)
        params["viscosityBoundary_read_back"] = visc.getValueFloat(visc.VISCOSITY_COEFFICIENT_BOUNDARY)
    except Exception as e:  # noqa: BLE001 - only a record of what the binding offers
        params["viscosity_read_back"] = f"not read: {e}"
    out = {"res": a.res, "boundary": a.boundary, "depth": a.depth, "inset_r": a.inset, "map_cells_r": a.map_cells, "map_cells_z_r": a.map_cells_z or a.map_cells,
           "nu": a.nu, "dt_max_arg": a.dt_max, "radius": r, "particles": int(n), "steps": len(rows) - 1,
           "time_end": tm.getTime(), "T_end": float(T[-1]), "dt_mean": float(dt[1:].mean()),
           "dt_min": float(dt[1:].min()), "dt_max": float(dt[1:].max()),
           "steps_at_cfl_min": int(np.sum(dt[1:] <= params["cflMinTimeStepSize"] * (1 + 1e-6))),
           "T_step_max": float(np.diff(T).max()), "vmax": state["vmax"],
           "first_faster_than_3_m_s": state["fast"], "vmax_at_saved_T": np.array(speeds)[keep].tolist(),
           "fluid_start_extent_over_r": [(lo / r).tolist(), (hi / r).tolist()],
           "fluid_extent_over_run_over_r": [(state["lo"] / r).tolist(), (state["hi"] / r).tolist()],
           "settings_read_back": params, "wall_s": wall, "setup_s": t1 - t0,
           "T": T[keep].tolist(), "Z_over_a": Z[keep].tolist(),
           "T_every_step": T.tolist(), "Z_every_step": Z.tolist(), "scene_file": path, "scene": scene}
    json.dump(out, open(a.out, "w"))
    base.cleanup()


def mark(row):
    """Flags from a finished row: the largest speed before T = 0.5 (0.56-0.62 m/s in the Akinci runs at warpsph's
    step bounds; more is the start's jolt), whether a particle beat FAST (a blow-up: the front's own speed is ~2 m/s)
    or left the domain by more than r."""
    if row.get("status") != "ok":
        return row
    T, v = np.array(row["T"]), np.array(row["vmax_at_saved_T"])
    lo, hi = (np.array(e) for e in row["fluid_extent_over_run_over_r"])
    domain = np.array([24 * row["res"], 5 * row["res"], 2 * row["depth"]])  # in r
    row["vmax_before_T_0.5"] = float(v[T <= 0.5].max())
    row["blew_up"] = bool(row["vmax"] > FAST)
    row["left_domain"] = bool((lo < -1.0).any() or (hi > domain + 1.0).any())
    return row


def warpsph_rows():
    """warpsph's own scores of the same case, from the results the docs cite."""
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)))
    rows = []
    cpu = json.load(open(os.path.join(here, "dam_front_martin_moyce_cpu_res10.json")))
    rows.append({"file": "tools/results/dam_front_martin_moyce_cpu_res10.json", "res": 10, "particles": cpu["particles"],
                 "raw_rms": cpu["raw_rms"], "time_shift_T": cpu["time_shift_T"], "shifted_rms": cpu["shifted_rms"]})
    gpu = json.load(open(os.path.join(here, "validate_dam-front_h100_37.json")))
    for r in gpu["rows"]:
        rows.append({"file": f"tools/results/validate_dam-front_h100_37.json (commit {gpu['commit']})", "res": r["resolution"],
                     "particles": r["particles"], "raw_rms": r["front_rms_raw"], "time_shift_T": r["time_shift_T"],
                     "shifted_rms": r["front_rms_shifted"]})
    return rows


def run_all(a):
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))
    from warpsph.io.splishsplash import container_inset
    from warpsph.validation.dam_front import MARTIN_MOYCE, compare

    doc = {"what": "Martin & Moyce dam front (#37) in SPlisHSPlasH, warpsph/validation/dam_front.py's case; "
                   "see the script's docstring", "script": "tools/results/dam_front_vs_splishsplash.py",
           "machine": machine(), "threads": 1, "splishsplash": splish_version(),
           "front": "99.5th percentile of x (from the back face x = 0) among particles with y < a, over a",
           "T": "t sqrt(2 g / a), a = 0.05715 m", "scored_by": "warpsph.validation.dam_front.compare",
           "wall_s": "runSimulation's wall time on one thread of a shared 2-core VM; it includes the volume map's "
                     "generation where the map was not in SPlisHSPlasH's cache yet",
           "warpsph": warpsph_rows(), "runs": []}
    if os.path.exists(a.json) and a.append:
        doc["runs"] = json.load(open(a.json))["runs"]
    for res in a.res:
        for boundary in a.boundaries:
            for dt_max in a.dt_maxes:
                inset, why = container_inset(boundary, 0.0, 1.0)
                tmp = f"/tmp/dam_front_pss_{res}_{boundary}_{dt_max}.json"
                cmd = [SPLISH_PY, __file__, "one", "--res", str(res), "--boundary", str(boundary), "--depth",
                       str(a.depth), "--inset", repr(inset), "--nu", str(a.nu), "--map-cells", str(a.map_cells), "--map-cells-z", str(a.map_cells_z),
                       "--t-end", str(a.t_end), "--out", tmp]
                dt = dt_max * A / (2 * res) if dt_max else 0.0  # --dt-maxes in s/m x r (warpsph: 0.2)
                if dt:
                    cmd += ["--dt-max", repr(dt)]
                env = dict(os.environ, LD_PRELOAD=PRELOAD, OMP_NUM_THREADS="1")
                start = time.perf_counter()
                p = subprocess.run(cmd, env=env, capture_output=True, text=True)
                if p.returncode != 0 or not os.path.exists(tmp):
                    row = {"res": res, "boundary": boundary, "dt_max_per_r": dt_max,
                           "status": f"failed rc {p.returncode}", "stderr_tail": p.stderr[-2000:]}
                else:
                    row = {**json.load(open(tmp)), "status": "ok", "dt_max_per_r": dt_max, "inset_why": why}
                    os.remove(tmp)
                    T, Z = np.array(row["T"]), np.array(row["Z_over_a"])
                    row.update(compare(T, Z))
                    every = compare(np.array(row["T_every_step"]), np.array(row["Z_every_step"]))
                    row["every_step"] = {k: every[k] for k in ("raw_rms", "time_shift_T", "shifted_rms")}
                    ko = compare(T, Z, reference=KOSHIZUKA_OKA)
                    row["koshizuka_oka"] = {k: ko[k] for k in ("raw_rms", "raw_errors", "raw_points", "time_shift_T",
                                                                "shifted_rms")}
                    # the front at the experiment's times, to set beside warpsph's
                    row["Z_at_reference_T"] = np.interp(MARTIN_MOYCE[:, 0], T, Z, right=np.nan).tolist()
                    del row["T_every_step"], row["Z_every_step"]
                row["process_wall_s"] = time.perf_counter() - start
                mark(row)
                doc["runs"].append(row)
                print(json.dumps({k: row.get(k) for k in ("res", "boundary", "dt_max_per_r", "status", "particles",
                                                          "steps", "raw_rms", "time_shift_T", "shifted_rms",
                                                          "wall_s")}), flush=True)
                json.dump(doc, open(a.json, "w"), indent=1)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["one", "all", "mark"])
    ap.add_argument("--res", type=int, nargs="+", default=[10, 20])
    ap.add_argument("--boundary", type=int, default=2)
    ap.add_argument("--boundaries", type=int, nargs="+", default=[2])
    ap.add_argument("--depth", type=int, default=DEPTH)
    ap.add_argument("--inset", type=float, default=1.401272890620082)
    ap.add_argument("--nu", type=float, default=1.0e-6)
    ap.add_argument("--map-cells", type=float, default=2.0)  # volume map cell in r
    ap.add_argument("--map-cells-z", type=float, default=0.0)  # across the thin depth, in r; 0: --map-cells
    ap.add_argument("--dt-max", type=float, default=0.0)  # one: seconds; 0: SPlisHSPlasH's default CFL bounds
    ap.add_argument("--dt-maxes", type=float, nargs="+", default=[0.0])  # all: s/m x r (warpsph's 0.2); 0: default
    ap.add_argument("--t-end", type=float, default=T_END)
    ap.add_argument("--out", default="/tmp/dam_front_pss.json")
    ap.add_argument("--json", default="tools/results/dam_front_vs_splishsplash_cpu.json")
    ap.add_argument("--append", action="store_true")
    a = ap.parse_args()
    if a.mode == "one":
        a.res = a.res[0]
        run_one(a)
    elif a.mode == "mark":  # the flags of mark() on an existing JSON's rows
        doc = json.load(open(a.json))
        doc["runs"] = [mark(row) for row in doc["runs"]]
        doc["warpsph"] = warpsph_rows()
        doc["wall_s"] = ("runSimulation's wall time on one thread of a shared 2-core VM; it includes the volume map's "
                         "generation where the map was not in SPlisHSPlasH's cache yet")
        json.dump(doc, open(a.json, "w"), indent=1)
    else:
        run_all(a)
