"""#37: is the resting tank's agitation at water's viscosity (nu = 1e-6) the start-up transient only?

rest.py's 0.4 m tank (walls on every face), small and on the CPU. Variants of the start:
  ramp       gravity ramped over 0.2 s (rest.py), no damping
  settle     full gravity from t = 0, velocities damped v *= (1 - c) after every step for ``settle`` seconds
  pack+settle  initial_packing (40 steps, no gravity) then the same settling
After the start: ``T`` seconds at nu = 1e-6, undamped. Reported: rms and largest speed over the last second
(speeds sampled every step) / sqrt(gH), rms every 0.02 s to 0.3 s and every 0.1 s after, the mean density error
(validation.cases.density_error). ``--where``: the settled speeds by walls within reach and by layer.

    PYTHONPATH=. python tools/settle_rest.py --start settle --settle 2 --damping 0.2 --T 3 --fill 0.88 [--packing 40]

docs/notes/solver.md, "Settling under gravity with damping" (#37, session 23) has the numbers.
"""
import argparse
import json
import time

import numpy as np
import warp as wp

from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation
from warpsph.validation.cases import density_error
from warpsph.validation.hydrostatic import ramp_gravity

SIDE, G = 0.4, 9.81


def where(x, u, fill, height, radius):
    """Prints the share of the velocities ``u`` that is particle-scale (u less its average over the particles within
    the support 4r, the kernel's), then the rms speed of the first-layer particles by the number of walls within 1.5 spacings (the lid
    counts only for the sealed box), of the top two layers, and layer by layer from the floor."""
    near = np.linalg.norm(x[:, None] - x[None], axis=2) < 4.0 * radius
    fine = u - near @ u / near.sum(1)[:, None]
    print(f"  particle-scale rms {np.sqrt((fine**2).sum(1).mean()):.2e} of {np.sqrt((u**2).sum(1).mean()):.2e}")
    v = np.linalg.norm(u, axis=1)
    faces = [x[:, 0], SIDE - x[:, 0], x[:, 1], x[:, 2], SIDE - x[:, 2]] + ([SIDE - x[:, 1]] if fill >= 1.0 else [])
    walls = (np.stack(faces, 1) < 3.0 * radius).sum(1)
    top = x[:, 1] > height - 4.0 * radius
    rms = lambda m: np.sqrt((v[m] ** 2).mean())  # noqa: E731
    for k in range(4):
        m = (walls == k) & ~top
        if m.any():
            print(f"  {k} walls within reach (top two layers aside): {m.sum()} particles, rms {rms(m):.2e}")
    print(f"  top two layers: {top.sum()} particles, rms {rms(top):.2e}")
    layer = np.round(x[:, 1] / (2 * radius) - 0.5).astype(int)
    print("  rms by layer from the floor:", " ".join(f"{rms(layer == k):.1e}" for k in range(layer.max() + 1)))


def run(resolution, fill, start, settle, damping, T, nu, packing, extra, show_where=False):
    radius = SIDE / (2 * resolution)
    layers = resolution if fill >= 1.0 else max(1, min(resolution - 1, round(fill * resolution)))
    height = layers * SIDE / resolution
    data = {"name": "rest", "particle_radius": radius, "gravity": [0, 0, 0],
            "domain": {"min": [0, 0, 0], "max": [SIDE, SIDE, SIDE]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [SIDE, height, SIDE]}]}
    over = {"fluid.viscosity": nu, **extra}
    if packing:
        over["initial_packing"] = {"steps": packing}
    t0 = time.perf_counter()
    sim = Simulation(scene_from_dict(with_overrides(data, over)), device="cpu")
    setup = time.perf_counter() - t0
    scale = np.sqrt(G * height)
    t0 = time.perf_counter()
    settle_steps = 0
    if start == "settle":
        sim.gravity = wp.vec3(0.0, -G, 0.0)
        next_report = 0.0
        while sim.time < settle:
            sim.step()
            v = sim.active(sim.fluid.v).numpy()  # a view on the CPU
            v *= (1.0 - damping)
            settle_steps += 1
            if sim.time >= next_report:
                s = np.linalg.norm(v, axis=1)
                print(f"  settle t {sim.time:5.2f} rms {np.sqrt((s**2).mean()):.2e} max {s.max():.2e}", flush=True)
                next_report += 0.25
        v = np.linalg.norm(sim.velocities(), axis=1)
        print(f"  settled {settle_steps} steps: rms {np.sqrt((v**2).mean()):.2e} max {v.max():.2e}", flush=True)
        if show_where:
            where(sim.positions(), sim.velocities().astype(np.float64), fill, height, radius)
    t_start = sim.time
    rms_series, last = [], []
    next_report = t_start
    while sim.time < t_start + T:
        if start == "ramp":
            ramp_gravity(sim, 0.2, G)
        sim.step()
        t = sim.time - t_start
        v = np.linalg.norm(sim.velocities(), axis=1)
        if t > T - 1.0:
            last.append((np.sqrt((v**2).mean()), v.max()))
        if sim.time >= next_report:
            rms_series.append((round(t, 3), float(np.sqrt((v**2).mean())), float(v.max())))
            next_report += 0.02 if t < 0.3 else 0.1
    wall = time.perf_counter() - t0
    if show_where:
        print(f"  at the end ({T} s undamped):")
        where(sim.positions(), sim.velocities().astype(np.float64), fill, height, radius)
    last = np.array(last)
    d = density_error(sim)
    return {"resolution": resolution, "fill": fill, "start": start, "settle_s": settle if start == "settle" else 0,
            "damping": damping, "packing": packing, "nu": nu, "T": T, "extra": extra, "particles": sim.num_fluid,
            "settle_steps": settle_steps, "steps": sim.step_count - settle_steps,
            "rms_last_s": float(np.sqrt((last[:, 0] ** 2).mean())), "max_last_s": float(last[:, 1].max()),
            "rms_last_s_over_sqrt_gH": float(np.sqrt((last[:, 0] ** 2).mean()) / scale),
            "max_last_s_over_sqrt_gH": float(last[:, 1].max() / scale), **d, "wall_s": wall, "setup_s": setup,
            "series": rms_series}


if __name__ == "__main__":
    a = argparse.ArgumentParser()
    a.add_argument("--resolution", type=int, default=12)
    a.add_argument("--fill", type=float, default=0.88)
    a.add_argument("--start", choices=["ramp", "settle"], default="settle")
    a.add_argument("--settle", type=float, default=1.0)
    a.add_argument("--damping", type=float, default=0.05)
    a.add_argument("--T", type=float, default=3.0)
    a.add_argument("--nu", type=float, default=1e-6)
    a.add_argument("--packing", type=int, default=0)
    a.add_argument("--set", nargs="*", default=[], help="key=json overrides")
    a.add_argument("--where", action="store_true", help="the settled speeds by place")
    a.add_argument("--out")
    args = a.parse_args()
    extra = {k: json.loads(v) for k, v in (s.split("=", 1) for s in args.set)}
    wp.config.quiet = True
    r = run(args.resolution, args.fill, args.start, args.settle, args.damping, args.T, args.nu, args.packing, extra, args.where)
    for t, rms, mx in r["series"]:
        print(f"  t {t:5.2f} rms {rms:.4f} max {mx:.4f}")
    s = {k: v for k, v in r.items() if k != "series"}
    print(json.dumps(s))
    if args.out:
        with open(args.out, "a") as fh:
            fh.write(json.dumps(r) + "\n")
