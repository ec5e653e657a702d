"""Dynamic bodies side by side with SPlisHSPlasH on its own scenes (issue #39).

SPlisHSPlasH (pysplishsplash 2.19.0, its own virtual environment, headless) and warpsph run the same
scene file on the CPU, at a coarser ``particleRadius`` when asked (the copy is written beside a link to
SPlisHSPlasH's ``data/models``, so the file's relative mesh paths still resolve; both codes read that
copy). Each dynamic body's position (its centre of mass in both codes; a body a motor joint drives is kinematic
in warpsph, its mesh's centre of mass there) and one corner (the mesh vertex furthest along CORNER at the start,
the same point in both codes) are recorded every step and sampled at 0.1 ... ``--stop`` s by linear interpolation
between steps. Each difference is reported as a percentage of that point's travel in SPlisHSPlasH
(|x(t_end) - x(0)|; none when it stays put, a paddle's centre on its hinge).

    nice -n 10 python tools/splishsplash_bodies.py --pss-python /work/splish-venv/bin/python \
        --scene DamBreakWithObjects.json --radius 0.05 --out tools/results/splishsplash_bodies_dbwo.json
    nice -n 10 python tools/splishsplash_bodies.py --pss-python /work/main/.venv/bin/python \
        --scene MotorScene.json --radius 0.05 --out tools/results/splishsplash_motor_r0.05_cpu.json

The SPlisHSPlasH half runs this file under the other interpreter (``--worker splishsplash``) with
``LD_PRELOAD`` of the system libGLdispatch (its import segfaults without it; nothing is drawn).
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

GLDISPATCH = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"
FLUID_TIMES = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5)  # fluid positions kept in each code's own JSON (not compared)
CORNER = np.array([1.0, 1e-3, 1e-6])  # the tracked corner: the vertex furthest along this at the start


def corner_index(vertices):
    """The vertex furthest along CORNER (ties, as a box's, broken by y, then z)."""
    return int(np.argmax(np.asarray(vertices, np.float64) @ CORNER))


def blocks_at_rest(data, file):
    """Moves each fluid block that starts inside the band where SPlisHSPlasH's volume maps push the fluid away
    (its lattice's first layer 2r from the container's faces, the maps hold it 2.4 r away) by the shift warpsph's
    importer would make, so that both codes start the fluid where their walls hold it at rest. Unmoved,
    SPlisHSPlasH's first step compresses the bottom layer to 1.3-2.4 rho0 and shoots it along the floor at
    3-8 m/s (r = 0.025-0.05 m; the jet, not the dam break, is what first strikes a body beside the column).
    Returns the shifts {block index: [dx, dy, dz]}."""
    import re
    import warnings

    from warpsph.io.splishsplash import translate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        conversion = translate(data, file)
    shifts = {}
    for note in conversion.notes:
        m = re.match(r"FluidBlocks\[(\d+)\] starts inside the band .* moved by \[([^\]]*)\] m", note)
        if m:
            n, delta = int(m.group(1)), [float(c) for c in m.group(2).split(",")]
            block = data["FluidBlocks"][n]
            block["translation"] = [float(a) + d for a, d in zip(block.get("translation", [0, 0, 0]), delta)]
            shifts[n] = delta
    return shifts


def scene_copy(pss_python, scene, radius, work, at_rest=True, map_scale=1, particles=False):
    """The scene file at ``radius`` (unchanged when None), in ``work/Scenes`` beside a link to SPlisHSPlasH's
    models, so its relative paths resolve; with ``at_rest``, its fluid blocks moved out of the walls' band
    (:func:`blocks_at_rest`). Returns the copy's path and the shifts."""
    data_dir = Path(pss_python).parent / "data"
    source = data_dir / "Scenes" / scene
    data = json.loads(source.read_text())
    if radius is not None:
        data["Configuration"]["particleRadius"] = float(radius)
    if particles:  # boundary particles in both codes: SPlisHSPlasH samples each mesh at r itself
        data["Configuration"]["boundaryHandlingMethod"] = 0
        for body in data.get("RigidBodies", []):
            body.pop("particleFile", None)
    shifts = blocks_at_rest(data, source) if at_rest else {}
    if map_scale != 1:  # SPlisHSPlasH's volume maps only (warpsph samples its boundaries itself)
        for body in data.get("RigidBodies", []):
            body["mapResolution"] = [int(round(map_scale * c)) for c in body.get("mapResolution", [10, 10, 10])]
    scenes = Path(work) / "Scenes"
    scenes.mkdir(parents=True, exist_ok=True)
    models = Path(work) / "models"
    if not models.exists():
        models.symlink_to(data_dir / "models")
    out = scenes / (Path(scene).stem + (f"_r{radius:g}" if radius is not None else "") + ("_rest" if at_rest else "")
                    + (f"_map{map_scale:g}" if map_scale != 1 else "") + ("_particles" if particles else "") + ".json")
    out.write_text(json.dumps(data, indent=1))
    return out, shifts


# -- SPlisHSPlasH (runs under pysplishsplash's interpreter) ---------------------------------------
def run_splishsplash(scene_file, stop, out_dir):
    import pysplishsplash as sph

    base = sph.Exec.SimulatorBase()
    base.init(sceneFile=str(scene_file), useGui=False, stopAt=float(stop), outputDir=str(out_dir), initialPause=False)
    steps, fluid, pending = [], [], list(FLUID_TIMES)
    start = time.perf_counter()
    first = {}

    def bodies(sim):
        out = []
        for i in range(sim.numberOfBoundaryModels()):
            rb = sim.getBoundaryModel(i).getRigidBodyObject()
            if rb.isDynamic():
                out.append(rb)
        return out

    def on_step():
        sim = sph.Simulation.getCurrent()
        tm = sph.TimeManager.getCurrent()
        rbs = bodies(sim)
        if not first:
            first.update(particles=sim.getFluidModel(0).numActiveParticles(), radius=sim.getParticleRadius(),
                         masses=[float(rb.getMass()) for rb in rbs],
                         corners=[corner_index(rb.getVertices()) for rb in rbs])
        steps.append([tm.getTime()] + [float(c) for rb in rbs for c in np.asarray(rb.getPosition()).ravel()]
                     + [float(c) for rb in rbs for c in np.asarray(rb.getVelocity()).ravel()]
                     + [float(c) for rb, k in zip(rbs, first["corners"]) for c in np.asarray(rb.getVertices())[k]])
        while pending and tm.getTime() >= pending[0] - 1e-4:
            fm = sim.getFluidModel(0)
            fluid.append({"t": pending.pop(0), "x": np.asarray(fm.getFieldBuffer("position"))[
                :fm.numActiveParticles()].round(4).tolist()})

    base.setTimeStepCB(on_step)
    base.run()
    # the bodies exist from the first step on: their start is the first step's position less v t (to O(g t^2));
    # a corner's, the first step's less the same v t (a motor's body has not turned yet: its first step's spin is 0)
    a = np.asarray(steps[0], np.float64)
    n = len(first["masses"])
    shift = a[1 + 3 * n:1 + 6 * n] * a[0]
    initial = (a[1:1 + 3 * n] - shift).tolist()
    corners = (a[1 + 6 * n:1 + 9 * n] - shift).tolist()
    return {"program": "SPlisHSPlasH (pysplishsplash 2.19.0)", "scene": str(scene_file), "initial": first,
            "initial_positions": initial, "initial_corners": corners, "steps": steps, "fluid": fluid,
            "wall_s": time.perf_counter() - start}


# -- warpsph ---------------------------------------------------------------------------------------
def run_warpsph(scene_file, stop):
    import warnings

    import warp as wp

    wp.config.quiet = True
    from warpsph.io.splishsplash import conversion_of
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(str(scene_file))
    sim = Simulation(scene, device="cpu")
    moving = [b for b in sim.bodies if b.kind != "static"]  # the scene's order: SPlisHSPlasH's dynamic bodies'
    centres = [centre_of_mass(b) for b in moving]
    corners = [corner_index(b.to_world(b.vertices)) for b in moving]

    def row():
        """The moving bodies' centres, their velocities and corners at sim.time (a kinematic body's pose is placed
        at each step's start: taken from its motion at the step's end here)."""
        poses = [pose(b, sim.time) for b in moving]
        x = [R @ c + p for (p, R, _, _), c in zip(poses, centres)]
        v = [u + np.cross(w, R @ c) for (_, R, u, w), c in zip(poses, centres)]
        k = [R @ b.vertices[n] + p for (p, R, _, _), b, n in zip(poses, moving, corners)]
        return [float(c) for part in (x, v, k) for vec in part for c in vec]

    first = np.asarray(row(), np.float64)
    n = len(moving)
    initial, initial_corners = first[:3 * n].reshape(n, 3).tolist(), first[6 * n:].reshape(n, 3).tolist()
    steps, fluid, pending = [], [], list(FLUID_TIMES)
    start = time.perf_counter()
    while sim.time < stop - 1e-9:
        sim.step()
        problem = sim.check_health()
        if problem is not None:
            raise problem
        steps.append([sim.time] + row())
        while pending and sim.time >= pending[0] - 1e-4:
            fluid.append({"t": pending.pop(0), "x": sim.fluid.x.numpy()[:sim.num_fluid].round(4).tolist()})
    conversion = conversion_of(scene)
    return {"program": "warpsph", "scene": str(scene_file), "particles": sim.num_fluid,
            "masses": [b.mass for b in moving], "names": [b.name for b in moving], "kinds": [b.kind for b in moving],
            "initial_positions": initial, "initial_corners": initial_corners, "steps": steps, "fluid": fluid, "wall_s": time.perf_counter() - start,
            "mapped": conversion.mapped if conversion else None, "notes": conversion.notes if conversion else None}


# -- warpsph's bodies -------------------------------------------------------------------------------
def centre_of_mass(body):
    """A moving body's centre of mass in its body space (a dynamic body's origin; a kinematic one's mesh centroid)."""
    if body.kind == "dynamic":
        return np.zeros(3)
    import trimesh

    return np.asarray(trimesh.Trimesh(body.vertices, body.faces).center_mass, np.float64)


def pose(body, t):
    """(position, rotation, velocity, angular velocity) of a moving body at time t."""
    if body.kind == "kinematic":
        from warpsph.bodies import kinematic_pose

        return kinematic_pose(body.obstacle.motion, body.reference, t)
    return body.position, body.rotation, body.velocity, body.angular_velocity


# -- comparison ------------------------------------------------------------------------------------
def at(steps, initial, times, n_bodies, block=0):
    """Positions [time, body, xyz] of the ``block``-th point of each step's row (0: centres, 2: corners)
    interpolated linearly between the recorded steps (t = 0: ``initial``)."""
    a = np.asarray(steps, np.float64)
    t = np.concatenate([[0.0], a[:, 0]])
    lo = 1 + 3 * n_bodies * block
    x = np.concatenate([np.asarray(initial, np.float64).reshape(1, -1), a[:, lo:lo + 3 * n_bodies]])
    return np.stack([[np.interp(s, t, x[:, k]) for k in range(3 * n_bodies)] for s in times]).reshape(len(times), n_bodies, 3)


def rows_of(xs, x0_s, xw, x0_w, times):
    """One tracked point's travel in SPlisHSPlasH and rows: both codes' positions and their difference as a share of
    that travel (None when the point stays put)."""
    travel = float(np.linalg.norm(xs[-1] - x0_s))
    rows = []
    for k, t in enumerate(times):
        miss = float(np.linalg.norm((xw[k] - x0_w) - (xs[k] - x0_s)))
        rows.append({"t": t, "splishsplash": xs[k].round(4).tolist(), "warpsph": xw[k].round(4).tolist(),
                     "difference_m": miss, "percent_of_travel": 100.0 * miss / travel if travel > 1e-6 else None})
    return travel, rows


def compare(theirs, ours, times):
    """Per body, its centre's rows (``rows``) and, when both runs recorded it, its corner's (``corner_rows``)."""
    n = len(ours["initial_positions"])
    tracks = {}
    for prefix, name, block in (("", "initial_positions", 0), ("corner_", "initial_corners", 2)):
        if name in theirs and name in ours:  # (runs saved before the corners have none)
            x0_s = np.asarray(theirs[name] or theirs["steps"][0][1:1 + 3 * n], np.float64).reshape(n, 3)
            x0_w = np.asarray(ours[name], np.float64).reshape(n, 3)
            tracks[prefix] = (x0_s, x0_w, at(theirs["steps"], x0_s, times, n, block),
                              at(ours["steps"], x0_w, times, n, block))
    bodies = []
    for b in range(n):
        body = {"name": ours["names"][b], "kind": ours.get("kinds", ["dynamic"] * n)[b],
                "mass": {"splishsplash": theirs["initial"]["masses"][b], "warpsph": ours["masses"][b]}}
        for prefix, (x0_s, x0_w, xs, xw) in tracks.items():
            travel, rows = rows_of(xs[:, b], x0_s[b], xw[:, b], x0_w[b], times)
            body.update({f"{prefix}initial": {"splishsplash": x0_s[b].round(4).tolist(),
                                              "warpsph": x0_w[b].round(4).tolist()},
                         f"{prefix}travel_splishsplash_m": travel, f"{prefix}rows": rows})
        bodies.append(body)
    return bodies


def machine():
    import platform

    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor())
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version()}


def commit():
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip()
    except OSError:
        return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pss-python", default="/work/splish-venv/bin/python", help="interpreter with pysplishsplash 2.19.0")
    ap.add_argument("--scene", default="DamBreakWithObjects.json", help="a scene of SPlisHSPlasH's data/Scenes")
    ap.add_argument("--radius", type=float, help="particleRadius of the copy both codes run (default: the file's)")
    ap.add_argument("--stop", type=float, default=0.5)
    ap.add_argument("--map-scale", type=float, default=1.0,
                    help="multiply every body's mapResolution (SPlisHSPlasH's volume maps; the shipped ones are "
                         "coarse for the container: at r = 0.05 m its first step compresses a corner to 2.3 rho0)")
    ap.add_argument("--as-shipped", action="store_true",
                    help="keep the fluid blocks where the file puts them (SPlisHSPlasH's first step then blasts the "
                         "fluid out of its walls' band; warpsph's importer moves it instead)")
    ap.add_argument("--boundary-particles", action="store_true",
                    help="Configuration.boundaryHandlingMethod 0 and no body particleFile in the copy: both codes "
                         "with boundary particles (SPlisHSPlasH samples the meshes itself)")
    ap.add_argument("--out", help="the comparison JSON (required unless --worker or --only)")
    ap.add_argument("--work", default="/tmp/splishsplash_bodies")
    ap.add_argument("--splishsplash-json", help="reuse a finished SPlisHSPlasH run (the worker's JSON)")
    ap.add_argument("--only", choices=["splishsplash", "warpsph"], help="run one code and save its JSON")
    ap.add_argument("--warpsph-json", help="reuse a finished warpsph run")
    ap.add_argument("--worker", choices=["splishsplash"], help=argparse.SUPPRESS)
    ap.add_argument("--scene-file", help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.worker == "splishsplash":
        result = run_splishsplash(args.scene_file, args.stop, args.work)
        Path(args.worker_out).write_text(json.dumps(result))
        return 0

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    scene_file, shifts = scene_copy(args.pss_python, args.scene, args.radius, work, not args.as_shipped, args.map_scale,
                                   args.boundary_particles)
    stem = scene_file.stem
    theirs_file = Path(args.splishsplash_json) if args.splishsplash_json else work / f"{stem}.splishsplash.json"
    if not args.splishsplash_json and args.only != "warpsph":
        env = dict(os.environ)
        if os.path.exists(GLDISPATCH):
            env["LD_PRELOAD"] = GLDISPATCH
        subprocess.run([args.pss_python, __file__, "--worker", "splishsplash", "--stop", str(args.stop),
                        "--work", str(work / f"{stem}.out"), "--scene-file", str(scene_file),
                        "--worker-out", str(theirs_file)], env=env, check=True, stdout=subprocess.DEVNULL)
    if args.only == "splishsplash":
        return 0
    ours_file = Path(args.warpsph_json) if args.warpsph_json else work / f"{stem}.warpsph.json"
    if not args.warpsph_json:
        ours_file.write_text(json.dumps(run_warpsph(scene_file, args.stop)))
    if args.only == "warpsph":
        return 0
    theirs, ours = json.loads(theirs_file.read_text()), json.loads(ours_file.read_text())
    times = [round(0.1 * k, 1) for k in range(1, int(round(args.stop / 0.1)) + 1)]
    bodies = compare(theirs, ours, times)
    import warp as wp

    result = {"scene": f"pysplishsplash 2.19.0 data/Scenes/{args.scene}", "particle_radius": args.radius,
              "fluid_blocks_moved_to_rest_m": shifts, "map_resolution_scale": args.map_scale,
              "boundary_particles": args.boundary_particles,
              "device": "cpu", "machine": machine(), "commit": commit(), "warp": wp.config.version,
              "splishsplash": "pysplishsplash 2.19.0",
              "particles": {"splishsplash": theirs["initial"]["particles"], "warpsph": ours["particles"]},
              "wall_s": {"splishsplash": theirs["wall_s"], "warpsph": ours["wall_s"]},
              "steps": {"splishsplash": len(theirs["steps"]), "warpsph": len(ours["steps"])},
              "bodies": bodies, "warpsph_notes": ours["notes"]}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    for b in bodies:
        print(f"{b['name']} ({b['kind']} in warpsph): mass {b['mass']['splishsplash']:.4g} / "
              f"{b['mass']['warpsph']:.4g} kg")
        for prefix, point in (("", "centre"), ("corner_", "corner")):
            if f"{prefix}rows" in b:
                print(f" {point}: travel {b[f'{prefix}travel_splishsplash_m']:.3f} m")
            for r in b.get(f"{prefix}rows", []):
                share = "-" if r["percent_of_travel"] is None else f"{r['percent_of_travel']:.1f} %"
                print(f"  t={r['t']:.1f}  SPlisHSPlasH {r['splishsplash']}  warpsph {r['warpsph']}  {share} of travel")
    return 0


if __name__ == "__main__":
    sys.exit(main())
