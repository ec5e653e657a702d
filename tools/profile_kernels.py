"""GPU time of every kernel of a step: which neighbour pass costs what (CUDA only).

    python tools/profile_kernels.py --device cuda --particles 1e6 --model all --out tools/results/profile_kernels_1M_h100.json

Runs the dam break at ~N fluid particles for ``--warmup`` steps, then ``--steps`` steps without the
CUDA graph under Warp's CUDA activity timing (events around every kernel, memcpy and memset) and
reports per kernel the ms per step, launches per step and ms per launch. Compare a kernel with
``compute_density_and_factor`` (one plain neighbour pass) to see what a pass costs.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import warp as wp

from warpsph.validation.bench import make_scene
from warpsph.validation.cases import commit_info


def kernel_times(sim, steps):
    """GPU time of every kernel (and memcpy/memset) over ``steps`` steps without a CUDA graph, from
    CUDA events (``wp.timing_begin``): {name: [total ms, launches]} per step."""
    use_graph, sim.use_graph = sim.use_graph, False
    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    try:
        for _ in range(steps):
            sim.step()
    finally:
        results = wp.timing_end()
        sim.use_graph = use_graph
    totals = defaultdict(lambda: [0.0, 0])
    for r in results:
        totals[r.name][0] += r.elapsed / steps
        totals[r.name][1] += 1
    return {k: [v[0], v[1] / steps] for k, v in totals.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(Path(__file__).resolve().parent.parent / "scenes" / "dam_break.json"))
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--particles", type=float, default=1e6)
    parser.add_argument("--model", choices=["none", "vorticity_refinement", "rankine", "micropolar", "all"], default="all")
    parser.add_argument("--density-error", type=float, help="override solver.density_max_error [%%]")
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--steps", type=int, default=10, help="steps timed (no CUDA graph)")
    parser.add_argument("--out")
    args = parser.parse_args()

    from warpsph.simulation import Simulation

    wp.config.log_level = wp.LOG_WARNING
    device = wp.get_device(args.device)
    sim = Simulation(make_scene(args, args.particles), device=device)
    for _ in range(args.warmup):
        sim.step()
    times = kernel_times(sim, args.steps)
    rows = sorted(({"kernel": k, "ms_per_step": t, "launches_per_step": n, "ms_per_launch": t / max(n, 1e-9)}
                   for k, (t, n) in times.items()), key=lambda r: -r["ms_per_step"])
    result = {"benchmark": "kernels", "scene": sim.scene.name, "model": args.model,
              "device": device.name if device.is_cuda else "cpu", "warp": wp.__version__, **commit_info(),
              "fluid_particles": sim.num_fluid, "steps_before": args.warmup, "steps_timed": args.steps, "kernels": rows}
    for r in rows:
        print(f"{r['kernel'][:60]:60s} {r['ms_per_step']:8.3f} ms/step  {r['launches_per_step']:5.1f} x {r['ms_per_launch']:.3f} ms")
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
