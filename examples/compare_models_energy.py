"""Kinetic energy of one scene under two models: plain DFSPH and a turbulence model (default
Rankine vortex feedback), frame by frame, into a CSV.

    python examples/compare_models_energy.py --scale 0.1 --frames 50 --model vorticity_refinement
"""

import argparse
import csv
import json
from pathlib import Path

import warp as wp

import warpsph

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def energies(data, scale, device, frames):
    """Kinetic energy [J] at frames 0..frames of the scene ``data`` (a scene file's dict)."""
    sim = warpsph.Simulation(warpsph.Scene.from_dict(data, base_dir=SCENES, scale=scale), device=device)
    out = []
    sim.run(frames=frames, on_frame=lambda sim, frame: out.append(sim.kinetic_energy()))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scale", type=float, default=0.1)
    parser.add_argument("--device", default=None)
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--model", default="rankine", choices=["rankine", "vorticity_refinement", "micropolar"])
    parser.add_argument("--out", default="out/examples/energy.csv")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING

    data = json.loads((SCENES / "dam_break.json").read_text())
    runs = {}
    for name, models in (("dfsph", []), (args.model, [{"type": args.model}])):
        runs[name] = energies({**data, "models": models}, args.scale, args.device, args.frames)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fps = data["output"]["fps"]
    with out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "time", *runs])
        for frame, row in enumerate(zip(*runs.values())):
            w.writerow([frame, frame / fps, *(f"{e:.6g}" for e in row)])
    peak = {name: max(e) for name, e in runs.items()}
    print("peak kinetic energy [J]: " + ", ".join(f"{n} {e:.4g}" for n, e in peak.items()))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
