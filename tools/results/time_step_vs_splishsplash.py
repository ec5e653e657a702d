"""The dt of every step, warpsph and SPlisHSPlasH on the same scene file (time_step_vs_splishsplash_cpu.json).

    LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 SPLISH_VENV/bin/python \
        tools/results/time_step_vs_splishsplash.py splishsplash SCENE.json 0.3 OUT.json [where]
    python tools/results/time_step_vs_splishsplash.py warpsph SCENE.json 0.3 OUT.json [sub=N] [nolimit] [where]

SPlisHSPlasH runs headless (pysplishsplash's SimulatorBase, a callback after each step; the preload is why
tools/splishsplash_side_by_side.py gives); its step k took t_k - t_(k-1). warpsph runs on the CPU; ``sub=N`` sets
solver.viscosity_substeps, ``nolimit`` removes the viscous limit (an experiment: the explicit viscosity at the
whole step). ``where`` (either code) adds to each row the position of the fastest particle (``x_fastest``).
Each row: time, dt, the largest fluid speed after the step. The SPlisHSPlasH output also gives the fluid count, the
boundary method and, for boundary particles (method 0), their count.
"""

import dataclasses
import json
import sys
import time

import numpy as np


def run_splishsplash(scene, stop, out, opts=()):
    import pysplishsplash as sph

    base = sph.Exec.SimulatorBase()
    base.init(sceneFile=scene, useGui=False, stopAt=stop, outputDir="/tmp/time_step_pss_out", initialPause=False)
    rows, last, info = [], [0.0], {}

    def on_step():
        sim, tm = sph.Simulation.getCurrent(), sph.TimeManager.getCurrent()
        fm = sim.getFluidModel(0)
        v = np.array(fm.getFieldBuffer("velocity"), copy=True)[: fm.numActiveParticles()]
        t = tm.getTime()
        speed = (v * v).sum(1)
        rows.append({"t": t, "dt": t - last[0], "next_dt": tm.getTimeStepSize(),
                     "vmax": float(np.sqrt(speed.max()))})
        if "where" in opts:
            x = np.array(fm.getFieldBuffer("position"), copy=True)[: fm.numActiveParticles()]
            rows[-1]["x_fastest"] = x[int(speed.argmax())].tolist()
        last[0] = t
        if not info:
            method = int(sim.getBoundaryHandlingMethod())
            info.update(fluid=int(fm.numActiveParticles()), boundary_method=method,
                        boundary_particles=[int(sim.getBoundaryModel(i).numberOfParticles())
                                            for i in range(sim.numberOfBoundaryModels())] if method == 0 else None)

    base.setTimeStepCB(on_step)
    start = time.perf_counter()
    base.run()  # the simulation is gone after it (Simulation.getCurrent() then crashes): counts taken in on_step
    json.dump({"scene": scene, "opts": list(opts), "steps": rows, "wall_s": time.perf_counter() - start, **info},
              open(out, "w"))


def run_warpsph(scene_file, stop, out, opts):
    import warp as wp

    wp.config.quiet = True
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation

    scene = load_scene(scene_file)
    for o in opts:
        if o.startswith("sub="):
            scene = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, viscosity_substeps=int(o[4:])))
    sim = Simulation(scene, device="cpu")
    if "nolimit" in opts:
        sim.viscous_dt = 1.0e30
    rows, status, start = [], "ok", time.perf_counter()
    while sim.time < stop - 1e-9:
        sim.step()
        v = sim.fluid.v.numpy()[: sim.num_fluid]
        speed = (v * v).sum(1)
        rows.append({"t": sim.time, "dt": float(sim.dt.numpy()[0]),
                     "vmax_end": float(np.sqrt(speed.max()))})
        if "where" in opts:
            rows[-1]["x_fastest"] = sim.fluid.x.numpy()[int(speed.argmax())].tolist()
        problem = sim.check_health()
        if problem is not None:
            status = f"failed: {problem}"
            break
    json.dump({"scene": scene_file, "opts": opts, "status": status, "steps": rows,
               "wall_s": time.perf_counter() - start,
               "viscous_dt": sim.viscous_dt, "max_substeps": sim.max_viscous_substeps,
               "bounds": list(scene.time_step_bounds), "fluid": sim.num_fluid}, open(out, "w"))


if __name__ == "__main__":
    what, scene, stop, out, *opts = sys.argv[1:]
    if what == "splishsplash":
        run_splishsplash(scene, float(stop), out, opts)
    else:
        run_warpsph(scene, float(stop), out, opts)
