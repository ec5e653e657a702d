"""How far the fluid's surface mesh pokes through the domain's walls and into the bodies (#42), in particle radii r.

    python -m warpsph.validation.surface_walls OUT.surface.usdc --scene scenes/dam_break.json [--json RESULT.json]
    python -m warpsph.validation.surface_walls --study [--scenes dam_break,funnel] [--methods preview] \
        [--work DIR] [--json tools/results/surface_walls_scenes_cpu.json]

Reads every time sample of ``/World/FluidSurface`` in a surface cache (``warpsph run --surface`` or
``warpsph surface``) and, for the walled faces of the scene's domain (``domain.min``/``max`` along the
axes that are not periodic, none for ``walls: false``: what the simulation keeps the particles
inside, ``inside_lo``/``inside_hi`` in warpsph/simulation.py), prints per frame the largest distance
of a vertex outside a walled face and the share of the vertices more than 0.001 r outside, and the largest
over the frames; with bodies in the cache (the meshes under /World/Bodies, the moving ones at the
frame's pose) also the largest depth of a vertex in a body: inside a closed mesh, or, for an open
one (a shell: the funnel, the hemisphere), into the shell of ``surface_clip.SHELL`` r (1.2 r) either
side of the mesh, where the fluid's reachable space ends as it does BODY_INSET r from a closed body's
samples and WALL_OFFSET r from the walls' (the fluid particles obey the samples; an open mesh's lie on
the mesh). The particle radius comes from the cache's widths (or ``--radius``).

``--study``: every shipped scene (scenes/*.json, :data:`STUDY`: a scale of 2-8K particles and frames
enough for splashes and contact with the bodies) run on the CPU with ``warpsph run --surface
--surface-method M`` for each method, and the above for every written mesh; the JSON gives each
scene's and method's largest distances over its frames, with the commands and the commit.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from warpsph.scene import Scene
from warpsph.surface import stage_clip, stage_poses
from warpsph.surface_clip import SHELL, depths_in_bodies
from warpsph.validation.cases import commit_info


def outside(points, lo, hi):
    """Per vertex: how far it lies outside the box lo..hi (0 inside; +-inf bounds never count)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    return np.maximum(np.maximum(lo - p, p - hi), 0.0).max(axis=1) if len(p) else np.zeros(0)


ROOT = Path(__file__).resolve().parents[2]

# scene: (--scale, last frame): 2-8K particles, 0.4-1.2 s, to the first contact with the bodies and the splash
# (the propellers reach the water at about 1.0 s; the emitters' fronts pass their body by 0.8 s)
STUDY = {
    "boat_pillars": (0.003, 10), "dam_break": (0.25, 12), "dam_break_board": (0.0035, 15),
    "dam_break_pillars": (0.01, 15), "energy_dam_break": (0.01, 12), "falling_blocks": (0.0045, 12),
    "falling_blocks_one_by_one": (0.0045, 12), "funnel": (0.003, 12), "hemisphere": (0.005, 15),
    "pillar_flow": (0.05, 20), "propeller": (0.002, 30), "propeller_rankine": (0.002, 30),
    "river_tunnel": (0.12, 20), "stirring_rod": (0.003, 12), "stirring_rod_rankine": (0.003, 12),
}
METHODS = ("splashsurf", "preview")


def measure(cache, scene, radius=None, log=print):
    """{"radius", "walled", "bodies", "frames": [per frame: vertices, max_outside_r, share_outside,
    max_in_body_r (with bodies)], "max_outside_r", "max_in_body_r"} of the surface meshes in ``cache``
    (a USD file) of the run of ``scene`` (a scene file; its domain's walled faces), distances in radii."""
    from pxr import Usd

    domain = Scene.load(scene).domain
    walled = [domain.walls and "xyz"[k] not in domain.periodic for k in range(3)]
    lo = np.array([domain.min[k] if walled[k] else -np.inf for k in range(3)])
    hi = np.array([domain.max[k] if walled[k] else np.inf for k in range(3)])
    stage = Usd.Stage.Open(str(cache))
    mesh = stage.GetPrimAtPath("/World/FluidSurface")
    if radius is None:
        widths = stage.GetPrimAtPath("/World/Fluid").GetAttribute("widths")
        radius = float(widths.Get(widths.GetTimeSamples()[0])[0]) / 2.0
    rows = []
    clip, _ = stage_clip(stage)
    bodies = clip.bodies if clip is not None else ()
    for t in mesh.GetAttribute("points").GetTimeSamples():
        points = np.asarray(mesh.GetAttribute("points").Get(t), np.float32)
        d = outside(points, lo, hi) / radius
        row = {"frame": int(round(t)), "vertices": int(len(d)), "max_outside_r": float(d.max()) if len(d) else 0.0,
               "share_outside": float((d > 1e-3).mean()) if len(d) else 0.0}
        line = (f"frame {row['frame']:4d}: {len(d):7d} vertices, largest outside {row['max_outside_r']:.3f} r, "
                f"{100 * row['share_outside']:.1f} % outside")
        if bodies:
            depth = depths_in_bodies(points, bodies, stage_poses(stage, clip, t), radius) / radius if len(points) \
                else np.zeros(0)
            row["max_in_body_r"] = float(depth.max()) if len(depth) else 0.0
            row["share_in_body"] = float((depth > 1e-3).mean()) if len(depth) else 0.0
            line += f"; largest depth in a body {row['max_in_body_r']:.3f} r"
        rows.append(row)
        if log:
            log(line)
    result = {"radius": radius, "walled": "".join("xyz"[k] for k in range(3) if walled[k]),
              "bodies": [{"name": b.name, "closed": bool(getattr(b, "closed", True)), "moving": bool(b.moving)}
                         for b in bodies],
              "frames": rows, "max_outside_r": max((r["max_outside_r"] for r in rows), default=0.0)}
    if bodies:
        result["max_in_body_r"] = max((r["max_in_body_r"] for r in rows), default=0.0)
    return result


def study(work, scenes=None, methods=METHODS, measure_meshes=True, log=print):
    """Runs each scene of :data:`STUDY` (or ``scenes``) on the CPU into ``work``/NAME.usdc (the particles: a cache
    there already is not run again), meshes it with each method (``warpsph surface --method M``: the run's
    ``clip_mesh``, the walls and bodies the cache records; into ``work``/meshes/NAME.M.usdc unless there) and
    measures the meshes; {"rows": [...]}."""
    import subprocess
    import time

    work = Path(work)
    (work / "meshes").mkdir(parents=True, exist_ok=True)
    rows = []

    def cli(*argv):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "warpsph.cli", *argv], cwd=ROOT, check=True)
        return round(time.perf_counter() - start, 1)

    for name in scenes or STUDY:
        scale, frames = STUDY[name]
        scene = ROOT / "scenes" / f"{name}.json"
        cache = work / f"{name}.usdc"
        run = ["run", f"scenes/{name}.json", "--scale", str(scale), "--frames", str(frames), "--device", "cpu",
               "--quiet", "--overwrite", "--out", str(cache)]
        run_seconds = None if cache.exists() else cli(*run)
        for method in methods:
            out = work / "meshes" / f"{name}.{method}.usdc"
            surface = ["surface", str(cache), "--method", method, "--device", "cpu", "--quiet", "--overwrite",
                       "--out", str(out)]
            mesh_seconds = None if out.exists() else cli(*surface)
            if not measure_meshes:
                continue
            m = measure(out, scene, measure_radius(cache), log=None)
            row = {"scene": name, "method": method, "scale": scale, "frames": frames, "particles": _particles(cache),
                   "radius": m["radius"], "walled": m["walled"], "bodies": m["bodies"],
                   "max_outside_r": round(m["max_outside_r"], 4),
                   "max_in_body_r": round(m["max_in_body_r"], 4) if "max_in_body_r" in m else None,
                   "vertices_max": max((r["vertices"] for r in m["frames"]), default=0),
                   "meshes": len(m["frames"]), "run_seconds": run_seconds, "mesh_seconds": mesh_seconds,
                   "commands": ["warpsph " + " ".join(run), "warpsph " + " ".join(surface)]}
            rows.append(row)
            if log:
                log(f"{name:26s} {method:10s} {row['particles']:6d} particles, {row['meshes']} meshes: outside walls "
                    f"{row['max_outside_r']:.3f} r, in bodies "
                    + ("-" if row["max_in_body_r"] is None else f"{row['max_in_body_r']:.3f} r"))
    return {"rows": rows}


def measure_radius(cache):
    """The particle radius of a cache (its first widths / 2)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(cache))
    widths = stage.GetPrimAtPath("/World/Fluid").GetAttribute("widths")
    return float(widths.Get(widths.GetTimeSamples()[0])[0]) / 2.0


def _particles(cache):
    """The largest particle count of a cache's frames."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(cache))
    points = stage.GetPrimAtPath("/World/Fluid").GetAttribute("points")
    return max((len(points.Get(t)) for t in points.GetTimeSamples()), default=0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cache", nargs="?", help="a USD file with /World/FluidSurface (and /World/Fluid, or a "
                                                 "sublayer with it)")
    parser.add_argument("--scene", help="the scene JSON the cache was run from")
    parser.add_argument("--radius", type=float, help="particle radius in metres (default: the cache's widths / 2)")
    parser.add_argument("--json", help="also write the numbers here")
    parser.add_argument("--study", action="store_true", help="run and measure every shipped scene (STUDY)")
    parser.add_argument("--scenes", help="--study: these scenes only (comma-separated names)")
    parser.add_argument("--methods", default=",".join(METHODS), help="--study: these methods (comma-separated)")
    parser.add_argument("--work", default="out/surface_walls", help="--study: the runs' folder (a cache there is "
                                                                    "measured, not run again)")
    parser.add_argument("--runs-only", action="store_true", help="--study: run and mesh, measure nothing (e.g. "
                                                                  "with an earlier warpsph's clip on PYTHONPATH)")
    args = parser.parse_args(argv)

    if args.study:
        result = study(args.work, args.scenes.split(",") if args.scenes else None, tuple(args.methods.split(",")),
                       not args.runs_only)
        if args.runs_only:
            return 0
        rows = result["rows"]
        worst_walls = max((r["max_outside_r"] for r in rows), default=0.0)
        worst_bodies = max((r["max_in_body_r"] or 0.0 for r in rows), default=0.0)
        print(f"largest distance outside the walls {worst_walls:.3f} r, into a body {worst_bodies:.3f} r "
              f"(goal: 0.25 r)")
        if args.json:
            Path(args.json).write_text(json.dumps({"study": "surface meshes vs walls and bodies (#42)",
                                                   "device": "cpu", "commit": commit_info(),
                                                   "shell_r": SHELL, "goal_r": 0.25,
                                                   "max_outside_r": worst_walls, "max_in_body_r": worst_bodies,
                                                   **result}, indent=1) + "\n")
        return 0
    if args.cache is None or args.scene is None:
        parser.error("a cache and --scene, or --study")
    m = measure(args.cache, args.scene, args.radius)
    print(f"{args.cache}: r = {m['radius']:.4g} m, walled axes {m['walled'] or 'none'}; largest distance of a vertex "
          f"outside a wall over {len(m['frames'])} frames: {m['max_outside_r']:.3f} r")
    if "max_in_body_r" in m:
        print(f"largest depth of a vertex in one of the {len(m['bodies'])} bodies: {m['max_in_body_r']:.3f} r")
    if args.json:
        Path(args.json).write_text(json.dumps({"cache": args.cache, "scene": args.scene, **m}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
