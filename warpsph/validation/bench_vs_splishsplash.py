"""Whole-job speed against SPlisHSPlasH on its own DamBreakModel at ~1M particles (issue #24).

Developer script for a lent GPU host. ``splishsplash`` runs pysplishsplash 2.19.0 headless on all CPU
cores on DamBreakModel.json with ``particleRadius`` set (0.005 m: 970,299 fluid particles) and appends
one JSON line per step (simulated time, loop wall, iterations) to ``--progress`` as it goes, so a run
stopped by its time limit still says how far it got. ``compare`` reads that file and a ``warpsph run -v``
log of the same scene file (its per-frame wall lines) and writes the ratio of loop wall per simulated
second over the longest window both finished, at a frame boundary.

    python -m warpsph.validation.bench_vs_splishsplash scene --data DIR --radius 0.005 --out DIR/Scenes/DamBreakModel_r5.json
    python -m warpsph.validation.bench_vs_splishsplash splishsplash --scene DIR/Scenes/DamBreakModel_r5.json --stop 0.4 \
        --progress pss.jsonl
    warpsph run DIR/Scenes/DamBreakModel_r5.json --device cuda --frames 25 -v > warpsph.log
    python -m warpsph.validation.bench_vs_splishsplash compare --progress pss.jsonl --warpsph-log warpsph.log --out R.json

On a bare GPU host pysplishsplash's extension also needs the system's libGL, libGLX, libGLdispatch, libX11,
libxcb, libXext, libXau, libXdmcp, libbsd and libmd: carry them, put them on LD_LIBRARY_PATH, and preload
libGLdispatch as tools/splishsplash_side_by_side.py explains.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path


def write_scene(data: Path, radius: float, out: Path, map_scale: int = 1):
    """SPlisHSPlasH's DamBreakModel.json with another particle radius, beside the original (its model
    paths are relative to the scene file); ``map_scale`` refines SPlisHSPlasH's volume maps by that factor
    per axis (warpsph samples walls with particles and does not read them)."""
    scene = json.loads((data / "Scenes" / "DamBreakModel.json").read_text())
    scene["Configuration"]["particleRadius"] = radius
    for body in scene.get("RigidBodies", []):
        if "mapResolution" in body:
            body["mapResolution"] = [int(n) * map_scale for n in body["mapResolution"]]
    out.write_text(json.dumps(scene, indent=1))


def run_splishsplash(scene: Path, stop: float, progress: Path):
    import pysplishsplash as sph

    base = sph.Exec.SimulatorBase()
    t_process = time.perf_counter()
    base.init(sceneFile=str(scene), useGui=False, stopAt=float(stop), outputDir=str(progress.parent / "pss_out"),
              initialPause=False)
    out = progress.open("w", buffering=1)
    clock = {}

    def on_step():
        sim = sph.Simulation.getCurrent()
        tm = sph.TimeManager.getCurrent()
        ts = sim.getTimeStep()
        now = time.perf_counter()
        if not clock:
            clock["start"] = now
            out.write(json.dumps({"particles": sim.getFluidModel(0).numActiveParticles(),
                                  "radius": sim.getParticleRadius(),
                                  "process_s_to_first_step": now - t_process}) + "\n")
        out.write(json.dumps({"t": tm.getTime(), "wall_s": now - clock["start"],
                              "density_iterations": ts.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS),
                              "divergence_iterations": ts.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS_V)}) + "\n")

    base.setTimeStepCB(on_step)
    base.run()
    out.write(json.dumps({"done": True, "process_wall_s": time.perf_counter() - t_process}) + "\n")


def read_warpsph_log(log: Path):
    """(frame, simulated time, loop wall so far) per frame from ``warpsph run -v``, and its done line."""
    frames, done, wall = [], None, 0.0
    for line in log.read_text().splitlines():
        m = re.search(r"frame (\d+): ([0-9.]+) s wall, (\d+) steps.*t=([0-9.]+)s", line)
        if m:
            wall += float(m.group(2))
            frames.append((int(m.group(1)), float(m.group(4)), wall))
        if "done:" in line:
            done = line[line.index("done:"):]
    return frames, done


def compare(progress: Path, log: Path):
    rows = [json.loads(line) for line in progress.read_text().splitlines() if line.strip()]
    head = rows[0]
    steps = [r for r in rows if "t" in r]
    finished = any(r.get("done") for r in rows)
    frames, done = read_warpsph_log(log)
    # the last warpsph frame that SPlisHSPlasH also reached
    reached = steps[-1]["t"]
    common = [f for f in frames if f[1] <= reached + 1e-6]
    if not common:
        raise SystemExit("SPlisHSPlasH did not reach warpsph's first frame")
    frame, t, warpsph_wall = common[-1]
    n = next(k for k, r in enumerate(steps, 1) if r["t"] >= t - 1e-6)  # SPlisHSPlasH's steps to the window
    first = steps[n - 1]
    return {
        "window_s": t, "frame": frame,
        "splishsplash": {"particles": head["particles"], "loop_wall_s": first["wall_s"], "steps": n,
                         "ms_per_step": 1e3 * first["wall_s"] / n,
                         "process_s_to_first_step": head["process_s_to_first_step"],
                         "reached_s": reached, "finished": finished,
                         "mean_density_iterations": sum(r["density_iterations"] for r in steps[:n]) / n},
        "warpsph": {"loop_wall_s": warpsph_wall, "done_line": done},
        "ratio_per_simulated_second": first["wall_s"] / warpsph_wall,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    s = sub.add_parser("scene")
    s.add_argument("--data", type=Path, required=True, help="pysplishsplash's data directory (Scenes/, models/)")
    s.add_argument("--radius", type=float, default=0.005)
    s.add_argument("--out", type=Path, required=True)
    s.add_argument("--map-scale", type=int, default=1, help="refine SPlisHSPlasH's volume maps by this factor")
    p = sub.add_parser("splishsplash")
    p.add_argument("--scene", type=Path, required=True)
    p.add_argument("--stop", type=float, default=1.0)
    p.add_argument("--progress", type=Path, required=True)
    c = sub.add_parser("compare")
    c.add_argument("--progress", type=Path, required=True)
    c.add_argument("--warpsph-log", type=Path, required=True)
    c.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    if args.what == "scene":
        write_scene(args.data, args.radius, args.out, args.map_scale)
    elif args.what == "splishsplash":
        run_splishsplash(args.scene, args.stop, args.progress)
    else:
        result = compare(args.progress, args.warpsph_log)
        text = json.dumps(result, indent=1)
        print(text)
        if args.out:
            args.out.write_text(text + "\n")


if __name__ == "__main__":
    sys.exit(main())
