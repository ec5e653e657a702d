"""The two surface methods side by side on the same particles (#42): :func:`warpsph.surface.mesh_quality` of the
mesh a run writes with each method's defaults, clipped to the scene's walls and bodies, the splashsurf mesh the
reference of the preview's distances.

    python -m warpsph.validation.mesh_quality [--work DIR] [--json tools/results/mesh_quality_cpu.json]

Runs three shipped scenes small on the CPU (:data:`CASES`: the dam break, the falling blocks, the dam break with
pillars), then meshes frames 10 and 20 (15 for the pillars) of each with ``mesh_frame(..., clip=the cache's
walls and bodies)`` and prints a row per frame and method: vertices, faces, watertight, slivers (faces with an
angle under 10 degrees), median smallest angle, mean / largest distance to splashsurf's mesh, the share of
splashsurf's vertices more than 1 r from the preview's, the largest distance outside the walls, area, volume and
the CPU seconds of the mesh. Needs pysplashsurf.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import trimesh

from warpsph.surface import SurfaceOptions, mesh_frame, mesh_quality, open_frames
from warpsph.validation.cases import commit_info

ROOT = Path(__file__).resolve().parents[2]
CASES = {"dam_break": (0.3, 20, (10, 20)), "falling_blocks": (0.005, 20, (10, 20)),
         "dam_break_pillars": (0.02, 15, (8, 15))}  # scene: --scale, --frames, frames measured
COLUMNS = ("vertices", "faces", "watertight", "sliver_fraction", "min_angle_median", "distance_mean", "distance_max",
           "reverse_over_1r", "outside_walls_max", "area", "volume")


def rows_of(name, cache, frames):
    """The rows of one scene's cache: each frame meshed by both methods (splashsurf first: the reference)."""
    src = open_frames(cache)
    rows = []
    for frame in frames:
        points = src.read(frame)[0]
        reference = None
        for method in ("splashsurf", "preview"):
            start = time.perf_counter()
            mesh = mesh_frame(points, src.radius, options=SurfaceOptions(method=method), device="cpu", clip=src.clip,
                              poses=src.poses(frame))
            seconds = time.perf_counter() - start
            q = mesh_quality(mesh, reference, radius=src.radius, clip=src.clip)
            if reference is None:
                reference = trimesh.Trimesh(mesh.points, mesh.faces, process=False)
            rows.append({"scene": name, "frame": frame, "particles": len(points), "method": method,
                         "mesh_seconds_cpu": round(seconds, 3),
                         **{k: (round(q[k], 4) if isinstance(q.get(k), float) else q.get(k)) for k in COLUMNS}})
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", default="out/mesh_quality", help="the runs' folder (a cache there is reused)")
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    rows, commands = [], []
    for name, (scale, frames, measured) in CASES.items():
        cache = work / f"{name}.usdc"
        run = ["run", f"scenes/{name}.json", "--scale", str(scale), "--frames", str(frames), "--device", "cpu",
               "--quiet", "--overwrite", "--out", str(cache.resolve())]
        commands.append("warpsph " + " ".join(run))
        if not cache.exists():
            subprocess.run([sys.executable, "-m", "warpsph.cli", *run], cwd=ROOT, check=True)
        for row in rows_of(name, cache, measured):
            rows.append(row)
            print(" ".join(f"{row[k]}" for k in ("scene", "frame", "particles", "method", *COLUMNS,
                                                 "mesh_seconds_cpu")))
    if args.json:
        Path(args.json).write_text(json.dumps({
            "what": "mesh quality of the two surface methods side by side (#42): mesh_quality of the mesh a run "
                    "writes (mesh_frame, each method's defaults, clipped to the walls and bodies); distances to "
                    "splashsurf's mesh of the same frame, in particle radii",
            "commands": commands, "device": "cpu", "commit": commit_info(), "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
