"""Time of every kernel of a step, launched alone: which neighbour pass costs what.

    python tools/profile_kernels.py --device cuda --particles 1e6 --model all --out tools/results/profile_kernels_1M_h100.json

Runs the dam break at ~N fluid particles for ``--warmup`` steps, records the launches of one
step (kernel, launch size, arguments), then replays each distinct kernel ``--repeats`` times with a
device sync around each and reports the median in ms with how often the step launched it. The
replays run on the state the step left (they may change it: this is a timing tool only). Compare a
kernel with ``compute_density_and_factor`` (one plain neighbour pass) to see what a pass costs.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np
import warp as wp

from bench_dam_break import commit, make_scene


def record_step(sim):
    """Runs one step without a CUDA graph and returns its launches in order."""
    launches = []
    plain = sim.launch

    def recording(kernel, dim, inputs):
        launches.append((kernel, dim, list(inputs)))
        plain(kernel, dim, inputs)

    sim.launch, use_graph = recording, sim.use_graph
    sim.use_graph = False
    try:
        sim.step()
    finally:
        sim.launch, sim.use_graph = plain, use_graph
    return launches


def median_ms(kernel, dim, inputs, device, repeats):
    wp.launch(kernel, dim=dim, inputs=inputs, device=device)
    samples = []
    for _ in range(repeats):
        wp.synchronize_device(device)
        start = time.perf_counter()
        wp.launch(kernel, dim=dim, inputs=inputs, device=device)
        wp.synchronize_device(device)
        samples.append(1e3 * (time.perf_counter() - start))
    return float(np.median(samples))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(Path(__file__).resolve().parent.parent / "scenes" / "dam_break.json"))
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--particles", type=float, default=1e6)
    parser.add_argument("--model", choices=["none", "vorticity_refinement", "rankine", "micropolar", "all"], default="all")
    parser.add_argument("--density-error", type=float, help="override solver.density_max_error [%%]")
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--out")
    args = parser.parse_args()
    args.sort_interval = None

    from warpsph.simulation import Simulation

    wp.config.log_level = wp.LOG_WARNING
    device = wp.get_device(args.device)
    sim = Simulation(make_scene(args, args.particles), device=device)
    for _ in range(args.warmup):
        sim.step()
    launches = record_step(sim)
    counts = Counter(k.key for k, _, _ in launches)
    first = {}
    for kernel, dim, inputs in launches:
        first.setdefault(kernel.key, (kernel, dim, inputs))
    rows = [{"kernel": key, "ms": median_ms(*first[key], device, args.repeats), "launches_per_step": counts[key]}
            for key in first]
    rows.sort(key=lambda r: -r["ms"] * r["launches_per_step"])
    result = {"benchmark": "kernels", "scene": sim.scene.name, "model": args.model,
              "device": device.name if device.is_cuda else "cpu", "warp": wp.__version__, "commit": commit(),
              "fluid_particles": sim.num_fluid, "steps_before": args.warmup, "kernels": rows}
    for r in rows:
        print(f"{r['kernel']:40s} {r['ms']:8.3f} ms x {r['launches_per_step']}")
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
