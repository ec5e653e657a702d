"""Benchmark of the whole job (#24): `warpsph run` with its USD output against the solver alone.

    warpsph bench job --device cuda --particles 1e6 --frames 25 --out tools/results/bench_job_h100.json
    warpsph bench job --device cpu --particles 2e4 --frames 5          # a CPU-sized check

For a scene (default the dam break) scaled to ~N fluid particles it measures

- start-up: the time to the first step, and where it goes (imports and wp.init, scene loading,
  host sampling of the fluid blocks and the walls, Z-ordering, the boundary volumes, the initial
  neighbour lists and densities, the first step with its kernel loading), each stage timed with
  the device synchronised around it;
- the solver alone: ``Simulation.run(frames=F)`` without output (a fresh simulation, kernels loaded);
- the job: ``warpsph run SCENE --frames F`` through the CLI (its loop wall: steps, diagnostics,
  frame copies and the USD writer), once per ``--modes`` (``background``: the writer thread,
  ``sync``: ``--sync-output``), with the payload and disk bytes per particle per frame;

and writes JSON with the device, Warp version and commit (``WARPSPH_COMMIT`` overrides git's: set it where the
tree is a copy whose .git is absent or stale). Goal of #24: loop wall <= 1.2 x solver
alone, time to first step <= 2 s with a warm kernel cache, at 1M particles on an H100. The start-up of a
first run on a fresh copy of the tree also compiles the Python bytecode of warpsph and of wheels installed
with --no-compile (``bytecode_cached`` in the JSON says whether it was there): measure it on a second run,
or after ``python -m compileall -q warpsph kernels SITE-PACKAGES``. Through ``warpsph bench job`` the clock
of the time to the first step starts when the command line builds its parser (``import warpsph`` and the CLI's
imports before that are not counted); ``main(t0=...)`` with a clock taken before ``import warpsph`` counts them
(the first stage, "python start and imports before warp").
"""

from __future__ import annotations

import time

T0 = time.perf_counter()  # before the imports: the time to the first step counts them (main's t0 overrides it)

import argparse  # noqa: E402
import contextlib  # noqa: E402
import functools  # noqa: E402
import gc  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

from warpsph.errors import SceneError  # noqa: E402
from warpsph.validation.bench import DEFAULT_SCENE, check_out, check_scene  # noqa: E402


class Stages:
    """Wall time of wrapped functions (device synchronised before and after), by stage name."""

    def __init__(self, wp):
        self.wp = wp
        self.seconds = defaultdict(float)
        self._depth = 0

    @contextlib.contextmanager
    def __call__(self, name):
        self.wp.synchronize()
        start = time.perf_counter()
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
            self.wp.synchronize()
            self.seconds[name] += time.perf_counter() - start

    def wrap(self, owner, attribute, name):
        original = getattr(owner, attribute)

        @functools.wraps(original)
        def timed(*args, **kwargs):
            with self(name):
                return original(*args, **kwargs)

        setattr(owner, attribute, timed)
        return original


def bytecode_cached(packages):
    """Whether each package's compiled bytecode (.pyc of the file named) was there before the imports: on a
    fresh copy of the tree, or wheels installed with --no-compile, every module compiles on its first import,
    which adds seconds to the time to the first step. Looks at files only: imports nothing."""
    import importlib.util

    out = {}
    for name, module in packages:
        try:
            spec = importlib.util.find_spec(name)
            source = Path(spec.submodule_search_locations[0]) / module
            out[name] = Path(importlib.util.cache_from_source(str(source))).exists()
        except (ImportError, ValueError, TypeError, AttributeError, IndexError):
            out[name] = None
    return out


def startup(args, t0=None):
    """The time to the first step (from ``t0``, default this module's import), by stage (the simulation's set-up
    through its ``setup_timer``, the host sampling's functions wrapped from the outside); returns the result and the
    --scale that gives ~args.particles."""
    t0 = T0 if t0 is None else t0
    bytecode = bytecode_cached((("warp", "_src/context.py"), ("warpsph", "simulation.py"), ("pxr", "__init__.py")))
    t_import = time.perf_counter()
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    if args.device.startswith("cuda") and not wp.is_cuda_available():
        raise SceneError("", "--device", f"'{args.device}' was asked for but this machine has no CUDA device; "
                                         "use --device cpu")
    t_init = time.perf_counter()
    from warpsph import sampling, simulation
    from warpsph.scene import load_scene

    t_warpsph = time.perf_counter()
    stages = Stages(wp)
    with stages("CUDA context (first use of the device)"):  # lazy in Warp: else it lands in Simulation()
        wp.get_device(args.device).context
    base = simulation.count_particles(load_scene(args.scene))[0]
    scale = args.particles / base
    scene = load_scene(args.scene, scale=scale)
    t_scene = time.perf_counter()
    # the host sampling's parts: functions of warpsph.sampling, wrapped for the set-up only; the simulation's
    # own stages through its setup_timer hook
    restore = [(sampling, "fill_block", stages.wrap(sampling, "fill_block", "sampling: fluid blocks")),
               (sampling, "sample_box_walls", stages.wrap(sampling, "sample_box_walls", "sampling: box walls")),
               (sampling, "morton_order", stages.wrap(sampling, "morton_order", "sampling: Z-order of the walls"))]
    try:
        start = time.perf_counter()
        sim = simulation.Simulation(scene, device=args.device, setup_timer=stages)
        wp.synchronize()
        t_sim = time.perf_counter()
    finally:
        for owner, attribute, original in restore:
            setattr(owner, attribute, original)
    with stages("first step (kernel loading)"):
        sim.step()
    t_first = time.perf_counter()
    result = {
        "particles": sim.num_fluid, "boundary": sim.num_boundary,
        "time_to_first_step_s": t_first - t0, "bytecode_cached": bytecode,
        "stages_s": {"python start and imports before warp": t_import - t0, "import warp + wp.init": t_init - t_import,
                     "import warpsph": t_warpsph - t_init, "load_scene": t_scene - t_warpsph,
                     "Simulation() in all": t_sim - start, **dict(stages.seconds)},
    }
    del sim
    gc.collect()
    return result, scale


def solver_only(args, scale):
    import warp as wp

    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation

    sim = Simulation(load_scene(args.scene, scale=scale), device=args.device)
    wp.synchronize()
    start = time.perf_counter()
    sim.run(frames=args.frames)
    wp.synchronize()
    wall = time.perf_counter() - start
    out = {"wall_s": wall, "steps": sim.step_count, "ms_per_step": 1e3 * wall / max(sim.step_count, 1)}
    del sim
    gc.collect()
    return out


def job(args, scale, mode, folder):
    out = Path(folder) / f"job_{mode}.usdc"
    argv = ["run", args.scene, "--device", args.device, "--scale", repr(scale), "--frames", str(args.frames),
            "--out", str(out), "--overwrite", "--quiet"]
    argv += ["--sync-output"] if mode == "sync" else []
    argv += ["--clips"] if args.clips else []
    argv += ["--fields", args.fields] if args.fields else []
    start = time.perf_counter()
    code = args.run_cli(argv)  # the CLI's main, handed over by it (warpsph bench job): no import of the CLI here
    process = time.perf_counter() - start
    if code != 0:
        raise SystemExit(f"warpsph run failed ({code}): {' '.join(argv)}")
    r = dict(args.last_run)
    gc.collect()
    return {"mode": mode, "loop_wall_s": r["wall"], "run_command_s": process, "steps": r["steps"], "frames": r["frames"],
            "writer_busy_s": r["writer_seconds"], "simulation_waited_for_writer_s": r["writer_waited"],
            "bytes_per_particle_frame": r["payload_bytes"] / max(r["particle_frames"], 1),
            "disk_bytes": r["disk_bytes"], "disk_bytes_per_particle_frame": r["disk_bytes"] / max(r["particle_frames"], 1),
            "fields": r["fields"]}


def add_arguments(parser):
    """The benchmark's options (``warpsph bench job`` and ``main``)."""
    parser.add_argument("--scene", default=str(DEFAULT_SCENE), help="scene file (default the dam break)")
    parser.add_argument("--device", default="cuda", help="cpu, cuda or cuda:N (default cuda)")
    parser.add_argument("--particles", type=float, default=1e6, help="target fluid particle count")
    parser.add_argument("--frames", type=int, default=25, help="output frames (at the scene's fps: 25 = 1 s for the dam break)")
    parser.add_argument("--modes", nargs="+", choices=["background", "sync"], default=["background", "sync"])
    parser.add_argument("--clips", action="store_true", help="write the cache as value clips (--clips)")
    parser.add_argument("--fields", help="--fields of warpsph run (default: all)")
    parser.add_argument("--startup-only", action="store_true", help="measure the start-up only")
    parser.add_argument("--keep", help="write the caches into this folder (default: a temporary one, removed)")
    parser.add_argument("--out", help="JSON file to write")


def check_arguments(args):
    """SceneError naming the option for a value the benchmark cannot run with."""
    check_scene(args.scene)
    check_out(args.out)
    if not re.fullmatch(r"cpu|cuda(:\d+)?", args.device):
        raise SceneError("", "--device", f"expected cpu, cuda or cuda:N, got '{args.device}'")
    if not 0 < args.particles < math.inf:
        raise SceneError("", "--particles", f"expected a finite particle count > 0, got {args.particles:g}")
    if args.frames < 1:
        raise SceneError("", "--frames", f"expected an integer >= 1, got {args.frames}")
    if args.keep and Path(args.keep).exists() and not Path(args.keep).is_dir():
        raise SceneError(args.keep, "--keep", "is a file; --keep names a folder")


def main(argv=None, t0=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return command(args, t0)
    except SceneError as exc:
        parser.error(str(exc))


def command(args, t0=None):
    """Runs the benchmark for the parsed options (``t0``: the clock start of the time to the first step)."""
    check_arguments(args)
    result = {"scene": args.scene, "device": args.device, "target_particles": args.particles, "frames": args.frames,
              "argv": sys.argv[1:]}
    result["startup"], scale = startup(args, t0)
    import warp as wp

    from warpsph.validation.cases import commit_info  # after the start-up: its imports and git are not timed

    result.update(device_name=str(wp.get_device(args.device).name), warp=wp.__version__, **commit_info())
    print(json.dumps(result["startup"], indent=2), flush=True)
    if args.startup_only:
        args.modes = []
    result["solver_only"] = solver_only(args, scale) if args.modes else None
    print(json.dumps(result["solver_only"]), flush=True)
    with (contextlib.nullcontext(args.keep) if args.keep else tempfile.TemporaryDirectory()) as folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        result["jobs"] = []
        for mode in args.modes:
            r = job(args, scale, mode, folder)
            r["loop_over_solver"] = r["loop_wall_s"] / result["solver_only"]["wall_s"]
            result["jobs"].append(r)
            print(json.dumps(r), flush=True)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    main()
