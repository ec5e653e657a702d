"""splashsurf against the preview (Warp's sparse marching cubes) on the same particles (#17): what each surface
method costs and what mesh it makes.

    python -m warpsph.validation.surface_methods --device cpu --out tools/results/surface_methods_cpu.json

Needs pysplashsurf (``pip install 'warpsph[surface]'``) and usd-core.

Particle sets: a frame of the dam break (``--scale``, ``--frame``: simulated here on the CPU, the
splash after the column hits the wall) and a lattice block of ``--block`` particles (the dam's
initial column, larger). Each set is meshed ``--reps`` times by each method (the minimum wall
time kept; the preview's first call, which compiles its kernels, is not timed) and the mesh
described: vertices, triangles, closed or not (edges with one triangle), enclosed volume against
the particles' volume N (2 r)^3, median edge length in r, and the mean angle between the normals
of neighbouring triangles (a roughness measure: the preview has no smoothing).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from warpsph.surface import SurfaceOptions, boundary_edges, mesh_volume, reconstruct, reconstruct_preview
from warpsph.validation.cases import commit_info

ROOT = Path(__file__).resolve().parents[2]


def roughness(points, faces):
    """Mean angle (degrees) between the normals of triangles that share an edge."""
    p = points[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(faces)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    e, o = edges[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    a, b = o[:-1][same], o[1:][same]
    return float(np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n[a], n[b]), -1, 1))).mean())


def describe(mesh, n, r):
    edges = np.linalg.norm(mesh.points[mesh.faces[:, 0]] - mesh.points[mesh.faces[:, 1]], axis=1)
    return {"vertices": len(mesh.points), "triangles": len(mesh.faces), "open_edges": boundary_edges(mesh.faces),
            "volume_vs_particles": mesh_volume(mesh.points, mesh.faces) / (n * (2 * r) ** 3),
            "median_edge_r": float(np.median(edges) / r), "normal_angle_deg": roughness(mesh.points, mesh.faces)}


def dam_frame(scale, frame):
    from pxr import Usd

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "dam.usdc"
        subprocess.run([sys.executable, "-m", "warpsph.cli", "run", str(ROOT / "scenes" / "dam_break.json"), "--scale",
                        str(scale), "--device", "cpu", "--frames", str(frame), "--out", str(out), "--quiet"], check=True)
        stage = Usd.Stage.Open(str(out))
        prim = stage.GetPrimAtPath("/World/Fluid")
        points = np.array(prim.GetAttribute("points").Get(frame), np.float32)
        r = float(prim.GetAttribute("widths").Get(0)[0]) / 2
    return points, r


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--scale", type=float, default=0.25)
    parser.add_argument("--frame", type=int, default=20)
    parser.add_argument("--block", type=int, default=100_000)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--out", help="JSON file")
    args = parser.parse_args(argv)
    import time

    import pysplashsurf
    import warp as wp

    wp.init()
    sets = {}
    points, r = dam_frame(args.scale, args.frame)
    sets[f"dam_break scale {args.scale} frame {args.frame}"] = (points, r)
    side = round(args.block ** (1 / 3))
    g = np.arange(side, dtype=np.float32) * 0.02 + 0.01
    sets[f"block {side}^3"] = (np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3), 0.01)
    methods = {"splashsurf cube 0.75": lambda p, r: reconstruct(p, r, options=SurfaceOptions()),
               "splashsurf cube 1.0": lambda p, r: reconstruct(p, r, options=SurfaceOptions(cube=1.0)),
               "preview cube 0.75": lambda p, r: reconstruct_preview(p, r, options=SurfaceOptions(method="preview"),
                                                                     device=args.device),
               "preview cube 1.0": lambda p, r: reconstruct_preview(
                   p, r, options=SurfaceOptions(method="preview", cube=1.0), device=args.device)}
    report = {"device": str(wp.get_device(args.device)), "warp": wp.__version__,
              "pysplashsurf": pysplashsurf.__version__ if hasattr(pysplashsurf, "__version__") else "0.14.1.0",
              "cpu": platform.processor() or platform.machine(),
              **commit_info(), "sets": {}}
    for name, (points, r) in sets.items():
        entry = {"particles": len(points), "radius": r, "methods": {}}
        for label, run in methods.items():
            if label.startswith("preview"):
                run(points[:100], r)  # compiles the kernels: not timed
            times = []
            for _ in range(args.reps):
                start = time.perf_counter()
                mesh = run(points, r)
                times.append(time.perf_counter() - start)
            entry["methods"][label] = {"seconds": min(times), **describe(mesh, len(points), r)}
            print(name, label, json.dumps(entry["methods"][label]), flush=True)
        report["sets"][name] = entry
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
