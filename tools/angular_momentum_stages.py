"""Developer script (#37): where the vortex cases' angular momentum about the vortex axis changes, stage by stage of
the step, printed as one JSON object.

    python tools/angular_momentum_stages.py [--resolution 16] [--T 0.5] [--full-tank] [--device cpu]

Builds the scene of `warpsph validate vortex-surface` (or, with --full-tank, of `lamb-oseen`) with the case's own
`lamb_oseen.build` and runs it with the instance's pressure solver, models and launches of `Simulation._solve_step`
wrapped (the shipped code is not changed). Per step it adds L = sum (x_i - c) x v_i (z component about the box
centre, per unit mass, float64 on the host, as `lamb_oseen.measure`) before and after each stage:

- divergence_solve, density_solve: split into `*_walls` (the solve's accumulated stiffness against the boundary
  samples, `boundary_pressure_torque`, as `lamb_oseen.AngularMomentumBudget`) and `*_fluid` (the rest: the
  fluid-fluid pressure pairs);
- viscosity: the models' step (sub-stepped: their change of v) plus dt sum (x - c) x a of the acceleration they
  leave for the prediction; gravity: dt sum (x - c) x g;
- integration: x += dt v with the walls' hold (`advect_positions`: v into a wall is zeroed, x clamped);
- shifting: sum dx_i x v_i (`shift_particles`).

Shares are fractions of L at t = 0; `by_flag` splits each stage's per-particle terms by the step's surface flag
(bulk / band / surface / wall; a pair force's torque is split between its two particles, so only the stage's sum
is physical). `closure`: (L(T) - L(0)) / L(0) less the sum of the stages (0 when nothing is missed).
The environment's WARPSPH_* switches apply (prototypes).
"""

import argparse
import json
import os
import subprocess
import time

import numpy as np

FLAGS = ("bulk", "band", "surface", "wall")  # kernels/free_surface.py BULK, BAND, SURFACE, WALL


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=16, help="particles across L = 1 m")
    parser.add_argument("--T", type=float, default=0.5, help="simulated time [s] (the case's: 0.5)")
    parser.add_argument("--full-tank", action="store_true", help="lamb-oseen's full tank without gravity")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--frames", type=int, default=10)
    args = parser.parse_args(argv)

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    from warpsph.kernels.diagnostics import boundary_pressure_torque
    from warpsph.kernels.integration import advect_positions, predict_velocity
    from warpsph.solvers.dfsph import DENSITY, DIVERGENCE
    from warpsph.validation import lamb_oseen as lo
    from warpsph.validation.taylor_green import METHODS, PACK_STEPS

    start_wall = time.perf_counter()
    core = lo.CORE_RADIUS * args.resolution / lo.L
    sim, p, _ = lo.build(METHODS["dfsph"], args.resolution, lo.NU, args.T, core, lo.U_PEAK, lo.DEPTH, args.device,
                         args.frames, pack_steps=PACK_STEPS, free_surface=not args.full_tank)
    sim.use_graph = False
    ps, c = sim.pressure_solver, np.asarray(p["centre"], dtype=np.float64)
    centre = wp.vec3(*map(float, c))
    zeros = wp.zeros(sim.fluid.x.shape[0], dtype=float, device=sim.device)
    torque = wp.zeros(sim.fluid.x.shape[0], dtype=wp.vec3, device=sim.device)
    sums = {}  # stage -> [sum, per-flag sums]
    steps = [0]

    def n():
        return sim.num_fluid

    def xv():
        return (sim.fluid.x.numpy()[:n()].astype(np.float64) - c, sim.fluid.v.numpy()[:n()].astype(np.float64))

    def lz(x, v):  # per particle
        return x[:, 0] * v[:, 1] - x[:, 1] * v[:, 0]

    def flags():
        return ps.surface.numpy()[:n()]

    def add(stage, per_particle):
        entry = sums.setdefault(stage, [0.0, np.zeros(len(FLAGS))])
        entry[0] += float(per_particle.sum())
        entry[1] += np.bincount(flags(), per_particle, minlength=len(FLAGS))[:len(FLAGS)]

    def walls(kind):
        wp.launch(boundary_pressure_torque, n(), device=sim.device,
                  inputs=[sim.fluid.x, ps.pressure_sum[kind], zeros, ps.gradient_correction, sim.neighbours.lists,
                          sim.boundary.samples, sim.support_radius, sim.dt, centre, torque])
        return torque.numpy()[:n(), 2].astype(np.float64)

    def solve(method, kind, name):
        def wrapped():
            x, v0 = xv()
            method()
            _, v1 = xv()
            total = lz(x, v1 - v0)
            wall = walls(kind)
            add(f"{name}_walls", wall)
            add(f"{name}_fluid", total - wall)
        return wrapped

    ps.correct_divergence = solve(ps.correct_divergence, DIVERGENCE, "divergence_solve")
    ps.correct_density = solve(ps.correct_density, DENSITY, "density_solve")

    shift = ps.shift_particles

    def shifting():
        x0, v = xv()
        shift()
        x1, _ = xv()
        add("shifting", lz(x1 - x0, v))
    ps.shift_particles = shifting

    for model in sim.models:
        def model_step(ctx, step=model.step):
            x, v0 = xv()
            step(ctx)
            _, v1 = xv()
            add("viscosity", lz(x, v1 - v0))
        model.step = model_step

    launch = sim.launch

    def launched(kernel, dim, inputs):
        if kernel is predict_velocity:
            x, _ = xv()
            dt = float(sim.dt.numpy()[0])
            a = sim.fluid.acceleration.numpy()[:n()].astype(np.float64)
            g = np.broadcast_to(np.asarray(sim.gravity, dtype=np.float64), a.shape)
            add("viscosity", dt * lz(x, a))
            add("gravity", dt * lz(x, g))
            return launch(kernel, dim, inputs)
        if kernel is advect_positions:
            x0, v0 = xv()
            launch(kernel, dim, inputs)
            x1, v1 = xv()
            add("integration", lz(x1, v1) - lz(x0, v0))
            steps[0] += 1
            return None
        return launch(kernel, dim, inputs)
    sim.launch = launched

    x, v = xv()
    l0 = float(lz(x, v).sum())
    sim.run(frames=args.frames)
    x, v = xv()
    l1 = float(lz(x, v).sum())
    shares = {k: s / l0 for k, (s, _) in sums.items()}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=os.path.dirname(os.path.abspath(__file__))).stdout.strip()
    internal = sum(v for k, v in shares.items() if not k.endswith("_walls") and k != "gravity")
    print(json.dumps({
        "case": "lamb-oseen (full tank)" if args.full_tank else "vortex-surface", "resolution": args.resolution,
        "particles": n(), "T": args.T, "time": sim.time, "steps": sim.step_count, "device": str(sim.device),
        "warp": wp.__version__, "commit": commit,
        "env": {k: v for k, v in os.environ.items() if k.startswith("WARPSPH_")},
        "angular_momentum_ratio": l1 / l0, "shares": shares, "internal_share": internal,
        "closure": (l1 - l0) / l0 - sum(shares.values()),
        "by_flag": {k: dict(zip(FLAGS, (f / l0).tolist())) for k, (_, f) in sums.items()},
        "wall_s": time.perf_counter() - start_wall}, indent=1))


if __name__ == "__main__":
    main()
