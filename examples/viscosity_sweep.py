"""A parameter sweep: the dam break at several viscosities; how far the front gets and the kinetic
energy at the end, into a JSON file.

    python examples/viscosity_sweep.py --scale 0.1 --frames 25 --viscosities 0 0.01 0.05 0.2
"""

import argparse
import json
from pathlib import Path

import warp as wp

import warpsph

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scale", type=float, default=0.1)
    parser.add_argument("--device", default=None)
    parser.add_argument("--frames", type=int, default=25)
    parser.add_argument("--viscosities", type=float, nargs="+", default=[0.0, 0.01, 0.05, 0.2], help="nu [m^2/s]")
    parser.add_argument("--out", default="out/examples/viscosity_sweep.json")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING

    data = json.loads((SCENES / "dam_break.json").read_text())
    rows = []
    for nu in args.viscosities:
        scene = warpsph.Scene.from_dict({**data, "fluid": {**data["fluid"], "viscosity": nu}}, scale=args.scale)
        sim = warpsph.Simulation(scene, device=args.device)
        sim.run(frames=args.frames)
        row = {"viscosity": nu, "time": sim.time, "steps": sim.step_count, "particles": sim.num_fluid,
               "front_x": float(sim.positions()[:, 0].max()), "kinetic_energy": sim.kinetic_energy()}
        rows.append(row)
        print(f"nu = {nu:<6g} front x = {row['front_x']:.3f} m  kinetic energy = {row['kinetic_energy']:.4g} J  "
              f"({row['steps']} steps)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
