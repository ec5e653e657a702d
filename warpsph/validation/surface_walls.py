"""How far the fluid's surface mesh pokes through the domain's walls (#42), in particle radii r.

    python -m warpsph.validation.surface_walls OUT.surface.usdc --scene scenes/dam_break.json [--json RESULT.json]

Reads every time sample of ``/World/FluidSurface`` in a surface cache (``warpsph run --surface`` or
``warpsph surface``) and, for the walled faces of the scene's domain (``domain.min``/``max`` along the
axes that are not periodic, none for ``walls: false``: what the simulation keeps the particles
inside, ``inside_lo``/``inside_hi`` in warpsph/simulation.py), prints per frame the largest distance
of a vertex outside a walled face and the share of the vertices more than 0.001 r outside, and the largest
over the frames; with bodies in the cache (closed meshes under /World/Bodies, the moving ones at the
frame's pose) also the largest depth of a vertex inside a body. The particle radius comes from the
cache's widths (or ``--radius``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from warpsph.scene import Scene
from warpsph.surface import stage_clip, stage_poses
from warpsph.surface_clip import push_out_of_bodies


def outside(points, lo, hi):
    """Per vertex: how far it lies outside the box lo..hi (0 inside; +-inf bounds never count)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    return np.maximum(np.maximum(lo - p, p - hi), 0.0).max(axis=1) if len(p) else np.zeros(0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cache", help="a USD file with /World/FluidSurface (and /World/Fluid, or a sublayer with it)")
    parser.add_argument("--scene", required=True, help="the scene JSON the cache was run from")
    parser.add_argument("--radius", type=float, help="particle radius in metres (default: the cache's widths / 2)")
    parser.add_argument("--json", help="also write the numbers here")
    args = parser.parse_args(argv)

    from pxr import Usd

    domain = Scene.load(args.scene).domain
    walled = [domain.walls and "xyz"[k] not in domain.periodic for k in range(3)]
    lo = np.array([domain.min[k] if walled[k] else -np.inf for k in range(3)])
    hi = np.array([domain.max[k] if walled[k] else np.inf for k in range(3)])
    stage = Usd.Stage.Open(args.cache)
    mesh = stage.GetPrimAtPath("/World/FluidSurface")
    radius = args.radius
    if radius is None:
        widths = stage.GetPrimAtPath("/World/Fluid").GetAttribute("widths")
        samples = widths.GetTimeSamples()
        radius = float(widths.Get(samples[0])[0]) / 2.0
    rows = []
    clip, _ = stage_clip(stage)
    bodies = clip.bodies if clip is not None else ()
    for t in mesh.GetAttribute("points").GetTimeSamples():
        points = np.asarray(mesh.GetAttribute("points").Get(t), np.float32)
        d = outside(points, lo, hi) / radius
        rows.append({"frame": int(round(t)), "vertices": int(len(d)), "max_outside_r": float(d.max()) if len(d) else 0.0,
                     "share_outside": float((d > 1e-3).mean()) if len(d) else 0.0})
        line = (f"frame {rows[-1]['frame']:4d}: {len(d):7d} vertices, largest outside {rows[-1]['max_outside_r']:.3f} r, "
                f"{100 * rows[-1]['share_outside']:.1f} % outside")
        if bodies and len(points):
            pushed = points.copy()
            push_out_of_bodies(pushed, bodies, stage_poses(stage, clip, t))
            depth = np.linalg.norm(pushed.astype(np.float64) - points, axis=1) / radius
            rows[-1]["max_inside_body_r"] = float(depth.max())
            line += f"; largest depth inside a body {depth.max():.3f} r"
        print(line)
    worst = max((r["max_outside_r"] for r in rows), default=0.0)
    print(f"{args.cache}: r = {radius:.4g} m, walled axes {''.join('xyz'[k] for k in range(3) if walled[k]) or 'none'}; "
          f"largest distance of a vertex outside a wall over {len(rows)} frames: {worst:.3f} r")
    if bodies:
        deepest = max(r.get("max_inside_body_r", 0.0) for r in rows) if rows else 0.0
        print(f"largest depth of a vertex inside one of the {len(bodies)} bodies: {deepest:.3f} r")
    if args.json:
        Path(args.json).write_text(json.dumps({"cache": args.cache, "scene": args.scene, "radius": radius,
                                               "max_outside_r": worst, "frames": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
