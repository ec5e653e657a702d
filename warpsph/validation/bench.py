"""Benchmark: a scene (default the dam break) at ~N fluid particles, ms per step in total and per stage.

    warpsph bench steps --device cuda --particles 1e6 --out tools/results/bench_dam_break_h100.json
    warpsph bench steps --device cuda --particles 125e3 1e6 4e6 --out tools/results/scaling_h100.json
    warpsph bench steps --scene scenes/propeller.json --particles 1.29e6 --warmup 200 ...
    warpsph bench steps --device cuda --particles 1e6 --method iisph --out tools/results/bench_dam_break_1M_iisph_h100.json

With several ``--particles`` the JSON holds one result per size and a markdown table (step time,
stages in %, iterations, neighbour passes k, bytes per particle, steps/s) is written beside it;
``warpsph plot results OUT.json`` draws the step time against the particle count.

Runs ``--warmup`` steps, then ``--steps`` steps with a synchronised per-stage timer
(stage times), then ``--steps`` steps as the production stepper runs them (CUDA graph
for the solver part where available) for the total. Writes JSON with the device, Warp
version and commit (``WARPSPH_COMMIT`` overrides git's: set it on a copy of the tree whose .git is
absent or stale), memory per particle (device free memory before/after the allocation and the
warm-up, with the memory pool returning freed blocks at once, so retained temporaries are not
counted; and the pool's live bytes) and the mean solver iterations.
"""

from __future__ import annotations

import gc
import json
import math
import time
from pathlib import Path

from warpsph.errors import SceneError
from warpsph.validation.cases import commit_info
from warpsph.decomposition import DecomposedSimulation, device_names
from warpsph.plots import _pyplot
from warpsph.scene import load_scene, model_types, replace_solver
from warpsph.simulation import Simulation, sample_scene
from warpsph.solvers import solver_class, solver_names
from warpsph.validation import study_main

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_SCENE = ROOT / "scenes" / "dam_break.json"
MODELS = ["none", "vorticity_refinement", "rankine", "micropolar", "all"]


def add_arguments(parser):
    """The benchmark's options (``warpsph bench steps`` and ``main``)."""
    parser.add_argument("--scene", default=str(DEFAULT_SCENE), help="scene file (default the dam break)")
    parser.add_argument("--device", default="cuda", help="cpu, cuda or cuda:N (default cuda)")
    parser.add_argument("--particles", type=float, nargs="+", default=[1e6], help="target fluid particle count(s)")
    parser.add_argument("--warmup", type=int, default=100, help="steps before the timed ones (default 100)")
    parser.add_argument("--steps", type=int, default=50, help="timed steps, per timer (default 50)")
    parser.add_argument("--density-error", type=float, help="override solver.density_max_error [%%]")
    parser.add_argument("--method", choices=solver_names(), help="override solver.method (the pressure solver)")
    parser.add_argument("--model", choices=MODELS,
                        help="turbulence model to run with its default parameters instead of the scene's models "
                             "(none: plain DFSPH/IISPH; all: the three at once); default: the scene's own")
    parser.add_argument("--sort-interval", type=int, help="override solver.sort_interval (0: never re-sort)")
    parser.add_argument("--devices", help="D[,D...] or N: one simulation over several devices (slab subdomains, "
                                          "warpsph.decomposition), e.g. cuda:0,cuda:1; with --subdomains, several "
                                          "on one device")
    parser.add_argument("--subdomains", type=int, help="subdomains (default one per --devices entry)")
    parser.add_argument("--out", help="JSON file to write")


def check_scene(scene):
    if not Path(scene).is_file():
        raise SceneError(scene, "--scene", "no such scene file")


def check_out(out):
    if out is not None and (not str(out) or Path(out).is_dir()):
        raise SceneError(out, "--out", "is a directory; --out names the file to write")


def check_arguments(args):
    """SceneError naming the option for a value the benchmark cannot run with."""
    check_scene(args.scene)
    check_out(args.out)
    for option, value, low in (("--warmup", args.warmup, 0), ("--steps", args.steps, 1)):
        if value < low:
            raise SceneError("", option, f"expected an integer >= {low}, got {value}")
    if any(not 0 < p < math.inf for p in args.particles):
        raise SceneError("", "--particles", "expected finite particle counts > 0")
    if args.density_error is not None and not 0 < args.density_error < math.inf:
        raise SceneError("", "--density-error", f"expected a percentage > 0, got {args.density_error}")
    if getattr(args, "subdomains", None) is not None and args.subdomains < 1:
        raise SceneError("", "--subdomains", f"expected an integer >= 1, got {args.subdomains}")
    if args.sort_interval is not None and args.sort_interval < 0:
        raise SceneError("", "--sort-interval", f"expected an integer >= 0, got {args.sort_interval}")


def main(argv=None):
    return study_main(__doc__, add_arguments, command, argv)


def command(args):
    """Runs the benchmark for the parsed options; prints each size's result, writes ``--out``."""
    import warp as wp

    check_arguments(args)
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    load_modules(args, wp.get_device(args.device))
    results = []
    for particles in args.particles:
        results.append(run(args, particles))
        print(json.dumps(results[-1], indent=2), flush=True)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results[0] if len(results) == 1 else results, indent=2) + "\n")
        if len(results) > 1:
            Path(args.out).with_suffix(".md").write_text(markdown_table(results))
    return 0


def neighbour_passes(result, models):
    """k: neighbour passes a step (density+factor 1; DFSPH, each solve: warm start 1 + source 1 + 2 per
    iteration; IISPH: coefficients 1 + 2 per iteration + the pressure acceleration 1; viscosity 1; the models'
    own passes)."""
    extra = sum({"none": 0, "vorticity_refinement": 3, "rankine": 1, "micropolar": 1}[m] for m in models)
    solves = solver_class(result.get("solver_method") or "dfsph").solve_passes(result["mean_divergence_iterations"],
                                                                                result["mean_density_iterations"])
    return 1 + solves + 1 + extra


def markdown_table(results):
    stages = sorted({k for r in results for k in r["ms_per_step_by_stage_synchronised"]})
    head = ("| fluid particles | ms/step | steps/s | k | ms per pass | " + " | ".join(f"{s} %" for s in stages)
            + " | B/particle arrays | B/particle device | B/particle device, marginal |")
    rows = [head, "|" + "---|" * (8 + len(stages))]
    previous = None
    for r in results:
        st = r["ms_per_step_by_stage_synchronised"]
        total = sum(st.values())
        rows.append(f"| {r['fluid_particles']:,} | {r['ms_per_step']:.2f} | {1e3 / r['ms_per_step']:.0f} | {r['k_passes']:.1f} | "
                    f"{r['ms_per_step'] / r['k_passes']:.3f} | " + " | ".join(f"{100 * st.get(s, 0) / total:.0f}" for s in stages)
                    + f" | {r['bytes_per_fluid_particle_arrays']:.0f} | {fmt(r['bytes_per_fluid_particle_device'])} | "
                    f"{fmt(marginal_bytes(previous, r))} |")
        previous = r
    return f"{results[0]['scene']} on {results[0]['device']}, Warp {results[0]['warp']}, commit {results[0]['commit']}\n\n" + "\n".join(rows) + "\n"


def fmt(value):
    return "—" if value is None else f"{value:.0f}"


def marginal_bytes(smaller, larger):
    """Device bytes per added fluid particle between two sizes: the slope of the device memory taken,
    free of what does not grow with N (module code, kernel stacks)."""
    if smaller is None or smaller.get("bytes_per_fluid_particle_device") is None:
        return None
    taken = [r["bytes_per_fluid_particle_device"] * r["fluid_particles"] for r in (smaller, larger)]
    return (taken[1] - taken[0]) / (larger["fluid_particles"] - smaller["fluid_particles"])


def make_scene(args, particles):
    """The benchmark's scene at ~``particles`` fluid particles with the command line's overrides."""
    import dataclasses

    n_base = len(sample_scene(load_scene(args.scene))[0])
    scene = load_scene(args.scene, scale=particles / n_base)
    changes = {}
    if getattr(args, "density_error", None):
        changes["density_max_error"] = args.density_error
    if getattr(args, "sort_interval", None) is not None:
        changes["sort_interval"] = args.sort_interval
    if getattr(args, "method", None):  # the scene's solver's own keys go, the new one's take their defaults
        changes["method"] = args.method
    scene = dataclasses.replace(scene, solver=replace_solver(scene.solver, **changes))
    if args.model is not None:
        types = model_types()
        names = [] if args.model == "none" else list(types) if args.model == "all" else [args.model]
        scene = dataclasses.replace(scene, models=tuple(types[name]() for name in names))
    return scene


def load_modules(args, device):
    """A few steps of the same scene at ~2K particles, once before the sizes, so that loading the
    kernels' modules (code, kernel stacks) is not counted as a large run's memory."""
    import warp as wp

    small = Simulation(make_scene(args, 2e3), device=device)
    for _ in range(3):
        small.step()
    del small
    wp.synchronize_device(device)


def run(args, particles):
    """One size: the result dict (the JSON of a single ``--particles``)."""
    import warp as wp

    scene = make_scene(args, particles)
    if getattr(args, "devices", None) or getattr(args, "subdomains", None):
        return run_decomposed(args, scene)
    device = wp.get_device(args.device)
    pooled = device.is_cuda and wp.is_mempool_enabled(device)
    if pooled:  # freed blocks go back to the device at each synchronisation: free memory shows what is held
        wp.set_mempool_release_threshold(device, 0)
    gc.collect()  # an earlier simulation (the module-loading one, the previous size) must be gone first
    wp.synchronize_device(device)
    free_before = device.free_memory if device.is_cuda else None
    pool_before = wp.get_mempool_used_mem_current(device) if pooled else None
    sim = Simulation(scene, device=device)
    for _ in range(args.warmup):
        sim.step()
    wp.synchronize_device(device)
    free_after = device.free_memory if device.is_cuda else None
    pool_after = wp.get_mempool_used_mem_current(device) if pooled else None

    stages, total_ms, iterations = timed_steps(sim, sim, args.steps)
    result = {
        "benchmark": "scene",
        "scene": scene.name,
        "model": args.model,
        "device": device.name if device.is_cuda else "cpu",
        "warp": wp.__version__,
        **commit_info(),
        "fluid_particles": sim.num_fluid,
        "boundary_particles": sim.num_boundary,
        "particle_radius": scene.particle_radius,
        "solver_method": scene.solver.method,
        "density_max_error_percent": scene.solver.density_max_error,
        "sort_interval": scene.solver.sort_interval,
        "divergence_max_error_percent": getattr(scene.solver, "divergence_max_error", None),  # DFSPH's
        "graph": bool(sim.use_graph),
        "simulated_time_s": sim.time,
        "steps_total": sim.step_count,
        "ms_per_step": total_ms,
        "ms_per_step_by_stage_synchronised": stages,
        **iterations,
        "bytes_per_fluid_particle_device": None if free_before is None else (free_before - free_after) / sim.num_fluid,
        "bytes_per_fluid_particle_mempool": None if pool_before is None else (pool_after - pool_before) / sim.num_fluid,
        "mempool_release_threshold": 0 if pooled else None,
        "bytes_per_fluid_particle_arrays": sum(sim.allocations.values()) / sim.num_fluid,
        "allocations_bytes": dict(sim.allocations),
        "dt_last": float(sim.dt.numpy()[0]),
        "moving_bodies": [] if sim.moving_bodies is None else [b.name for b in sim.moving_bodies.bodies],
    }

    names = [type(m).plugin_name for m in scene.models] or ["none"]
    result["model"] = "+".join(names)
    result["k_passes"] = neighbour_passes(result, names)
    del sim
    return result


def timed_steps(sim, timed, steps, synchronize=None):
    """``steps`` steps with ``timed``'s stage timer (synchronised around every stage; no graph), then ``steps``
    as production steps them (graph where available), ``synchronize()`` at both ends (default ``wp.synchronize``;
    several processes: their barrier too): (ms per stage, ms per step, mean solver iterations)."""
    import warp as wp

    synchronize = synchronize or wp.synchronize
    timed.timer.enabled = True
    timed.timer.seconds.clear()
    it0 = timed.pressure_solver.iteration_totals()
    for _ in range(steps):
        sim.step()
    stages = {k: 1e3 * v / steps for k, v in timed.timer.seconds.items()}
    timed.timer.enabled = False
    synchronize()
    start = time.perf_counter()
    for _ in range(steps):
        sim.step()
    synchronize()
    total_ms = 1e3 * (time.perf_counter() - start) / steps
    it1 = timed.pressure_solver.iteration_totals()
    solves = max(it1[1] - it0[1], 1), max(it1[3] - it0[3], 1)
    return stages, total_ms, {"mean_divergence_iterations": (it1[0] - it0[0]) / solves[0],
                              "mean_density_iterations": (it1[2] - it0[2]) / solves[1]}


def run_decomposed(args, scene):
    """One size over several subdomains: ms per step (threads in lockstep, no graph) and the share of the
    synchronised step that subdomain 0 spends in each stage (``halo``: migration and ghost rows)."""
    import warp as wp

    devices = device_names(args.devices or args.device)
    start = time.perf_counter()
    sim = DecomposedSimulation(scene, devices, subdomains=args.subdomains)
    setup_s = time.perf_counter() - start
    for _ in range(args.warmup):
        sim.step()
    stages, total_ms, iterations = timed_steps(sim, sim.sims[0], args.steps)
    return {
        "benchmark": "scene, decomposed",
        "scene": scene.name,
        "model": "+".join(type(m).plugin_name for m in scene.models) or "none",
        "devices": [s.device.name if s.device.is_cuda else "cpu" for s in sim.sims],
        "device_aliases": [s.device.alias for s in sim.sims],
        "warp": wp.__version__,
        **commit_info(),
        "fluid_particles": sim.num_fluid,
        "subdomains": sim.count,
        "axis": sim.axis,
        "particles_per_subdomain": sim.owned_counts(),
        "ghosts_per_subdomain": [s.ghosts for s in sim.subdomains],
        "peer_access": sim.peer_access,
        "rows_per_subdomain": [s.capacity for s in sim.subdomains],
        "particle_radius": scene.particle_radius,
        "setup_s": setup_s,
        "simulated_time_s": sim.time,
        "steps_total": sim.step_count,
        "ms_per_step": total_ms,
        "ms_per_step_by_stage_synchronised_subdomain0": stages,
        **iterations,
    }


def scaling_plot(runs, out):
    """Step time against particle count of a multi-size result (a list, one per size) as the PNG ``out``."""
    n = [r["fluid_particles"] for r in runs]
    ms = [r["ms_per_step"] for r in runs]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.loglog(n, ms, "o-", label="ms per step")
    if len(n) > 1:
        ax.loglog(n, [ms[1] * k / n[1] for k in n], "--", color="gray", label="linear through 1M")
    ax.set_xlabel("fluid particles")
    ax.set_ylabel("ms per step")
    ax.set_title(f"{runs[0]['scene']} on {runs[0]['device']}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


if __name__ == "__main__":
    main()
