"""Benchmark of ``warpsph run --surface`` (#17): ms/step with and without surface meshes, and
seconds per meshed frame.

    python -m warpsph.validation.bench_surface --device cpu --scale 0.25 --frames 12 --reps 3 --out tools/results/bench_surface_cpu.json
    python -m warpsph.validation.bench_surface --device cuda --scale 1 --frames 10 --out tools/results/bench_surface_h100.json

Runs the dam break (scenes/dam_break.json, ``--scale``: particle-count factor) through the CLI,
alternating ``plain`` (points only), ``surface`` (``--surface``: splashsurf on the background
writer's thread) and ``surface-sync`` (``--surface --sync-output``: meshing on the simulation's
thread, the cost of meshing made visible), ``--reps`` times each; reports the minimum and median
loop wall per step, the meshing seconds per frame and how long the simulation waited for the
writer. JSON with the device, Warp and pysplashsurf versions and the commit.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
from pathlib import Path
from warpsph import cli
from warpsph.scene import load_scene
from warpsph.simulation import sample_scene
from warpsph.validation.cases import commit_info

ROOT = Path(__file__).resolve().parents[2]

MODES = {"plain": [], "surface": ["--surface"], "surface-sync": ["--surface", "--sync-output"],
         "surface-every-4": ["--surface", "--surface-every", "4"], "preview": ["--surface", "--surface-method", "preview"]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "dam_break.json"))
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--scale", type=float, default=0.25)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    parser.add_argument("--cube", type=float, default=0.75)
    parser.add_argument("--out", help="JSON file")
    args = parser.parse_args(argv)

    import pysplashsurf  # noqa: F401
    import warp as wp

    runs = {m: [] for m in args.modes}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.reps + 1):  # rep 0 warms the kernel cache and is not counted
            for mode in args.modes:
                code = cli.main(["run", args.scene, "--device", args.device, "--scale", str(args.scale), "--frames",
                                 str(args.frames), "--out", f"{tmp}/bench.usdc", "--overwrite", "--quiet",
                                 "--surface-cube", str(args.cube), *MODES[mode]])
                if code:
                    sys.exit(f"warpsph run failed ({code}) in mode {mode}")
                r = dict(cli.last_run)
                if rep:
                    runs[mode].append(r)
                print(f"rep {rep} {mode}: {1e3 * r['wall'] / r['steps']:.2f} ms/step, {r['frames']} frames"
                      + (f", {r['surface_seconds'] / r['frames']:.3f} s meshing per frame" if r.get("surface_seconds")
                         else "") + f", waited {r['writer_waited']:.2f} s", file=sys.stderr, flush=True)
    fluid = len(sample_scene(load_scene(args.scene, scale=args.scale))[0])
    rows = {}
    for mode, rs in runs.items():
        ms = [1e3 * r["wall"] / r["steps"] for r in rs]
        rows[mode] = {"ms_per_step_min": min(ms), "ms_per_step_median": statistics.median(ms), "ms_per_step": ms,
                      "steps": rs[0]["steps"], "frames": rs[0]["frames"],
                      "writer_waited_s": [r["writer_waited"] for r in rs]}
        if rs[0].get("surface_seconds") is not None:
            rows[mode]["meshing_s_per_frame"] = statistics.median(r["surface_seconds"] / r["frames"] for r in rs)
    if "plain" in rows:
        for mode in rows:
            rows[mode]["vs_plain_min"] = rows[mode]["ms_per_step_min"] / rows["plain"]["ms_per_step_min"]
    report = {"scene": Path(args.scene).name, "scale": args.scale, "fluid_particles": fluid, "frames": args.frames,
              "reps": args.reps, "cube": args.cube, "device": str(wp.get_device(args.device if args.device != "cuda"
                                                                                  else "cuda:0").name),
              "warp": wp.config.version, "pysplashsurf": __import__("importlib.metadata").metadata.version("pysplashsurf"),
              "cpu": platform.processor() or platform.machine(), **commit_info(), "modes": rows}
    print(json.dumps(report, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    sys.exit(main())
