"""Command line: ``warpsph run SCENE.json [--device cpu|cuda] [--out FILE.usdc] [--frames N] [--scale S]``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .errors import SceneError


def _pick_device(name):
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    if name == "auto":
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise SceneError(None, "--device", f"'{name}' was asked for but this machine has no CUDA device; use --device cpu")
    return name


class Progress:
    """One status line per frame on stderr: frames, sim time, steps/s, solver iterations."""

    def __init__(self, frames, stream=None):
        self.frames = frames
        self.stream = stream or sys.stderr
        self.start = time.perf_counter()
        self.tty = self.stream.isatty()

    def __call__(self, sim, frame):
        elapsed = time.perf_counter() - self.start
        stats = sim.statistics()
        rate = sim.step_count / elapsed if elapsed > 0 else 0.0
        eta = elapsed / frame * (self.frames - frame) if frame else 0.0
        line = (f"frame {frame}/{self.frames}  t={sim.time:.3f}s  steps={sim.step_count}  {rate:.1f} steps/s  "
                f"iterations div {stats['divergence_iterations']:.1f} dens {stats['density_iterations']:.1f}  "
                f"eta {eta:.0f}s")
        self.stream.write(("\r" + line.ljust(100)) if self.tty else line + "\n")
        self.stream.flush()


def run_command(args):
    from .diagnostics import DiagnosticsWriter
    from .io.usd import UsdPointCache, frame_writer
    from .scene import load_scene

    scene = load_scene(args.scene, scale=args.scale)
    device = _pick_device(args.device)
    from .simulation import Simulation

    sim = Simulation(scene, device=device)
    frames = args.frames or scene.output.frames
    out = Path(args.out or f"out/{scene.name}.usdc")
    print(f"warpsph: {scene.name} on {device}: {sim.num_fluid} fluid + {sim.num_boundary} boundary particles, "
          f"r = {scene.particle_radius:.4g} m, {frames} frames at {scene.output.fps:g} fps -> {out}", file=sys.stderr)
    cache = UsdPointCache(out, scene.output.fps, scene.output.up_axis,
                          boundary_points=sim.boundary.x.numpy(), boundary_radius=scene.particle_radius)
    write = frame_writer(cache)
    diagnostics = DiagnosticsWriter(out.with_suffix(".stats.csv"))
    progress = None if args.quiet else Progress(frames)

    def on_frame(sim, frame):
        write(sim, frame)
        diagnostics(sim, frame)
        if progress is not None:
            progress(sim, frame)

    start = time.perf_counter()
    try:
        sim.run(frames=frames, on_frame=on_frame)
    finally:
        diagnostics.close()
    wall = time.perf_counter() - start
    stats = sim.statistics()
    if progress is not None and progress.tty:
        print(file=sys.stderr)
    print(f"done: {frames} frames, {stats['steps']} steps, {sim.time:.3f} s simulated in {wall:.1f} s wall "
          f"({stats['steps'] / max(wall, 1e-9):.1f} steps/s); mean iterations: divergence "
          f"{stats['divergence_iterations']:.2f}, density {stats['density_iterations']:.2f}; wrote {out} and "
          f"{out.with_suffix('.stats.csv').name}",
          file=sys.stderr)
    return 0


def build_parser():
    parser = argparse.ArgumentParser(prog="warpsph", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="simulate a scene and write a USD point cache")
    run.add_argument("scene", help="scene file (JSON), e.g. scenes/dam_break.json")
    run.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto (CUDA when present)")
    run.add_argument("--out", help="output .usdc/.usda file (default out/<scene name>.usdc)")
    run.add_argument("--frames", type=int, help="frames to simulate (default: the scene's output.frames)")
    run.add_argument("--scale", type=float, default=1.0,
                     help="particle-count factor: 0.1 runs about a tenth of the particles (radius / scale^(1/3))")
    run.add_argument("--quiet", action="store_true", help="no progress line")
    run.set_defaults(func=run_command)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except SceneError as exc:
        print(f"warpsph: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\nwarpsph: interrupted; the frames written so far are in the output file", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
