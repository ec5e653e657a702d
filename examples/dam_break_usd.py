"""A dam break written to a USD point cache (open it in Blender, usdview or Omniverse).

    python examples/dam_break_usd.py --scale 0.1 --device cuda --frames 50 --out out/dam_break.usdc
"""

import argparse
from pathlib import Path

import warp as wp

import warpsph

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scale", type=float, default=0.1, help="particle-count factor (1: the scene's 16K particles)")
    parser.add_argument("--device", default=None, help="cpu, cuda, cuda:0 (default: Warp's default device)")
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--out", default="out/examples/dam_break.usdc")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING  # no line per kernel module loaded

    scene = warpsph.Scene.load(SCENES / "dam_break.json", scale=args.scale)
    sim = warpsph.Simulation(scene, device=args.device)
    print(f"{sim.num_fluid} particles of radius {scene.particle_radius * 1000:.1f} mm on {sim.device}")

    def report(sim, frame):  # a second on_frame callback next to the writer
        x = sim.positions()
        print(f"frame {frame:3d}  t = {sim.time:.3f} s  front x = {x[:, 0].max():.3f} m  "
              f"kinetic energy = {sim.kinetic_energy():.3f} J")

    with warpsph.io.UsdWriter(args.out, sim) as usd:
        sim.run(frames=args.frames, on_frame=lambda sim, frame: (usd(sim, frame), report(sim, frame)))
    print(f"wrote {usd.frames} frames to {args.out}")


if __name__ == "__main__":
    main()
