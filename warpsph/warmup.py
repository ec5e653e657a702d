"""Compile the Warp kernels into Warp's kernel cache ahead of a first run, in one parallel pass.

    warpsph warmup                                   # every warpsph kernel module, on the default device
    warpsph warmup --device cpu --scene scenes/dam_break.json scenes/propeller.json
    warpsph warmup --arch 90 80                      # for H100/H200 and A100 GPUs, on a machine without one

Warp compiles a module (the kernels of one ``kernels/*.py`` file) the first time one of its kernels is
launched on a device, and keeps the binary in its kernel cache: ``WARP_CACHE_PATH`` when set, else a
per-user folder (Warp's ``wp.config.kernel_cache_dir``, printed below). Later runs load it from there.

A :class:`~warpsph.simulation.Simulation` compiles the modules its scene launches together, before its
set-up launches anything (:func:`preload`, one thread per idle core; ``Simulation(..., preload=False)`` or
``WARPSPH_PRELOAD=0`` leaves each to its first launch). ``warpsph warmup`` does the same ahead of time for
every kernel module (or those of ``--scene`` files, as ``warpsph run`` would launch them) and prints what it
compiled and how long it took, so that the first run finds them cached.

``--arch`` compiles for CUDA architectures instead of a device (:func:`compile_for_archs`): Warp's NVRTC needs no
GPU, so a login node, a container build or a CI machine can fill the kernel cache that the GPU machines' runs read
(the same ``WARP_CACHE_PATH``, the same Warp version). Each module is written in both forms Warp may load on a GPU of
that architecture: CUBIN (what Warp loads where the driver is older than its CUDA toolkit) and PTX (where it is not).

On a GPU (and for ``--arch``) both first copy warpsph's precompiled kernels into the cache where they are the ones
built from the source now (:mod:`warpsph.precompiled`; ``WARPSPH_PRECOMPILED=0`` turns that off): those load, the
rest compiles.

Which modules a scene launches is :func:`scene_modules`: the stepper's own always, each feature's only when
the scene has it (the solver's, bodies, inflow, viscosity, the models' and the shared vorticity pass).
A model plug-in's modules are those of the kernels its Python module defines or imports (its class may
name them instead: ``kernel_modules``).
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from warpsph import precompiled
from warpsph.errors import SceneError
from warpsph.models import REGISTRY, plugin_of
from warpsph.scene import load_scene
from warpsph.scene_setup import imported_volume_maps
from warpsph.solvers import solver_class

KERNELS = "warpsph.kernels"


def _k(*names):
    return [f"{KERNELS}.{n}" for n in names]


def enabled() -> bool:
    """Whether a Simulation preloads by default (the environment variable ``WARPSPH_PRELOAD=0`` turns it off)."""
    return os.environ.get("WARPSPH_PRELOAD", "1").strip().lower() not in ("0", "false", "no", "off")


def plugin_modules(cls) -> list[str]:
    """The Warp modules a model plug-in launches: its ``kernel_modules`` when it names them, else the modules of
    the kernels its Python module defines or imports."""
    import warp as wp

    named = getattr(cls, "kernel_modules", None)
    if named is not None:
        return list(named)
    namespace = vars(sys.modules[cls.__module__])
    return sorted({v.module.name for v in namespace.values() if isinstance(v, wp.Kernel)})


def scene_modules(scene, bodies=None, fluid=None, decomposed=False, frames=False) -> list[str]:
    """The names of the Warp modules whose kernels a :class:`~warpsph.simulation.Simulation` of ``scene``
    launches in its set-up and its steps. ``bodies``: the scene's obstacles as loaded
    (:class:`~warpsph.bodies.RigidBody`) and ``fluid``: the fluid particles sampled at t = 0, which tell whether
    the bodies launch kernels; ``decomposed``: as a
    subdomain of a :class:`~warpsph.decomposition.DecomposedSimulation`; ``frames``: with the frame
    diagnostics of ``warpsph run`` (:class:`~warpsph.diagnostics.Diagnostics`).

    The stepper's own always (neighbour lists and re-sorting, densities, pressure, integration, the health
    check); the boundary volumes when there are walls or bodies; DFSPH's free surface and density solve, its
    divergence solve and shifting when on, or IISPH's solve; viscosity when the fluid has one; each model's;
    the shared vorticity pass when a model reads it and no viscosity pass fills it; bodies when one moves, or
    is closed and fluid was sampled (the fluid inside it is removed): without ``bodies``, whenever the scene has
    obstacles (an open static mesh launches none); inflow with emitters, sinks or an open domain."""
    domain, solver = scene.domain, scene.solver
    names = _k("neighbours", "density", "pressure", "integration", "stability")
    if (domain.walls and len(domain.periodic) < 3) or scene.obstacles:
        names += _k("boundary")
    names += solver_class(solver.method).kernel_modules(scene)
    viscous = scene.fluid.viscous
    models = ([REGISTRY["viscosity"]] if viscous else []) + [plugin_of(p) for p in scene.models]
    for cls in models:
        names += plugin_modules(cls)
    if any(m.needs_vorticity for m in models) and not any(m.computes_vorticity for m in models):
        names += _k("vorticity")
    if bodies is None:
        bodies_launch = bool(scene.obstacles)
    else:
        bodies_launch = any(b.kind != "static" or (b.closed and fluid != 0) for b in bodies)
    if bodies_launch:
        names += _k("bodies")
    if not decomposed and _volume_mapped(scene, bodies):
        names += _k("volume_map")
    if scene.emitters or scene.sinks or domain.is_open:
        names += _k("inflow")
    if decomposed:
        names += _k("decomposition")
    if frames:
        names += frame_modules(scene)
    return list(dict.fromkeys(names))


def _volume_mapped(scene, bodies) -> bool:
    """Whether a dynamic body holds the fluid by a volume map (an imported SPlisHSPlasH scene with
    boundaryHandlingMethod 2: ``RigidBody.volume_map``, or without ``bodies`` the conversion's ``volume_maps``)."""
    if bodies is not None:
        return any(b.kind == "dynamic" and b.volume_map is not None for b in bodies)
    return any(m is not None and o.dynamics is not None for m, o in zip(imported_volume_maps(scene), scene.obstacles))


def frame_modules(scene) -> list[str]:
    """The Warp modules of ``warpsph run``'s frame diagnostics (:class:`~warpsph.diagnostics.Diagnostics`): its
    reductions, and the curl of v where no model keeps the vorticity."""
    keeps_vorticity = any(plugin_of(p).needs_vorticity for p in scene.models)
    return _k("diagnostics") + ([] if keeps_vorticity else _k("vorticity"))


def surface_modules() -> list[str]:
    """The Warp modules of the preview mesher (``warpsph run --surface`` on a GPU; :mod:`warpsph.surface`): its
    kernels and Warp's sparse marching cubes, which a first run compiled at its first mesh (~3 s on an H100)."""
    import inspect

    from warp.geometry import sparse_marching_cubes_from_cells

    return _k("surface_preview") + [inspect.getmodule(sparse_marching_cubes_from_cells).__name__]


def all_modules() -> list[str]:
    """Every module of ``warpsph.kernels`` that holds kernels (imported here), and Warp's own that the preview
    mesher launches (:func:`surface_modules`)."""
    import warp as wp

    package = importlib.import_module(KERNELS)
    names = []
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        module = importlib.import_module(f"{KERNELS}.{info.name}")
        if any(isinstance(v, wp.Kernel) for v in vars(module).values()):
            names.append(module.__name__)
    return list(dict.fromkeys(names + surface_modules()))


@dataclass
class Loaded:
    """One module of a :func:`preload`: its name, the seconds its load took, and whether it was compiled
    (False: Warp's kernel cache had it, or it was loaded already)."""

    name: str
    seconds: float
    compiled: bool


def cache_folders(name, root=None):
    """The folders of Warp module ``name`` in the kernel cache ``root`` (default Warp's): ``wp_<name>_<hash>``, one
    per variant of the module (``warpsph.kernels.density``'s, not ``density_solver``'s)."""
    import warp as wp

    root = Path(root if root is not None else wp.config.kernel_cache_dir or "")
    if not root.is_dir():
        return []
    return [d for d in root.glob(f"wp_{name}_*") if d.name[len(f"wp_{name}_"):].isalnum()]


def _cache_files(name):
    return {p for d in cache_folders(name) for p in d.rglob("*")}


def idle_cores() -> int:
    """The default number of compile threads: the cores this process may use less those busy with other work
    now (:func:`busy_cores`), at least 1. Each thread that compiles for the CPU builds Warp's precompiled
    header first (~1.7 s of a core), so threads help only where cores are idle: on 2 idle cores the dam
    break's first step ended 4.5-5.3 s after the start instead of 6.9-8.2 s, on 2 cores kept busy by other
    work two threads compiled its modules in 8.0 s where one took 6.3 s (docs/notes/performance-history.md)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    return max(1, min(cores, round(cores - busy_cores())))


def busy_cores() -> float:
    """Cores busy with other work now: the tasks runnable at this moment besides this one (Linux's
    /proc/loadavg), else the one-minute load average, else 0."""
    try:
        with open("/proc/loadavg") as f:
            return max(0.0, float(f.read().split()[3].split("/")[0]) - 1.0)
    except (OSError, IndexError, ValueError):
        pass
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return 0.0


def _size(name):
    """A module's Python source size: its compile time's rough measure (the longest first)."""
    path = getattr(sys.modules.get(name), "__file__", None)
    try:
        return os.path.getsize(path)
    except (OSError, TypeError):
        return 0


def _in_parallel(tasks, max_workers):
    """Runs the callables ``tasks`` (the longest first) on ``max_workers`` threads, the calling thread one of
    them, and returns what each returned, in the order given."""
    workers = max(1, min(len(tasks), max_workers))
    queue, lock, done = list(enumerate(tasks)), threading.Lock(), {}

    def work():
        while True:
            with lock:
                if not queue:
                    return
                k, task = queue.pop(0)
            done[k] = task()

    if workers == 1:
        work()
    else:
        with ThreadPoolExecutor(max_workers=workers - 1, thread_name_prefix="warpsph-preload") as pool:
            helpers = [pool.submit(work) for _ in range(workers - 1)]
            try:
                work()
            except BaseException:  # a failed build, Ctrl-C: the helpers stop after the module each has begun
                with lock:
                    queue.clear()
                raise
            for helper in helpers:
                helper.result()
    return [done[k] for k in range(len(tasks))]


def _modules(names):
    """The Warp modules ``names`` (imported), the largest Python source first."""
    import warp as wp

    modules = []
    for name in dict.fromkeys(names):
        importlib.import_module(name)
        modules.append(wp.get_module(name))
    return sorted(modules, key=lambda m: -_size(m.name))


def preload(names, device=None, max_workers=None) -> list[Loaded]:
    """Compiles (or loads from Warp's kernel cache) the Warp modules ``names`` on ``device`` in one pass of
    ``max_workers`` threads (default :func:`idle_cores`), the largest first, and returns what each took (its
    load's wall time, beside the others). The calling thread is one of them: a module that a program compiles
    later, lazily, finds its precompiled header built. Loading a module is what its first launch would do (the
    same variant: results do not change); a module already loaded costs nothing. On a GPU, warpsph's precompiled
    kernels are copied into the cache first where they fit (:func:`warpsph.precompiled.seed`): those load."""
    import warp as wp

    device = wp.get_device(device)
    precompiled.seed(names, device)

    def load(module):
        before = _cache_files(module.name)
        start = time.perf_counter()
        try:
            wp.force_load(device=device, modules=[module], max_workers=0)
        except OSError as exc:  # a full disk or a quota: one line naming the cache, not Warp's traceback
            raise SceneError(wp.config.kernel_cache_dir, "", f"Warp could not write the kernels of {module.name} "
                             f"into its kernel cache: {exc.strerror or exc} (free space there, or set "
                             "WARP_CACHE_PATH to a folder with room)") from None
        return Loaded(module.name, time.perf_counter() - start, bool(_cache_files(module.name) - before))

    modules = _modules(names)
    return _in_parallel([lambda m=m: load(m) for m in modules], max_workers or idle_cores())


def compile_for_archs(names, archs, max_workers=None) -> list[Loaded]:
    """Compiles the Warp modules ``names`` for the CUDA architectures ``archs`` (e.g. 90 for H100/H200) into Warp's
    kernel cache without a GPU (Warp's NVRTC), as CUBIN and as PTX, each of the two that Warp loads on such a GPU
    depending on its driver; files already there are kept, and warpsph's precompiled kernels are copied there first
    where they fit (:func:`warpsph.precompiled.seed`). One :class:`Loaded` per module and architecture (its name
    ``module@sm_90``; ``compiled`` False where both files were in the cache or shipped)."""
    import warp as wp

    supported = set(wp.get_cuda_supported_archs())
    for arch in archs:
        if arch not in supported:
            raise SceneError("", "--arch", f"Warp {wp.__version__}'s NVRTC does not compile for sm_{arch}; it "
                                           f"compiles for {', '.join(str(a) for a in sorted(supported))}")

    def build(module):  # one thread a module: its architectures one after the other (a module is not thread-safe)
        out = []
        for arch in archs:
            for use_ptx in (False, True):
                precompiled.seed([module], arch=arch, use_ptx=use_ptx)
            before = _cache_files(module.name)
            start = time.perf_counter()
            for use_ptx in (False, True):
                wp.compile_aot_module(module, arch=arch, use_ptx=use_ptx)
            out.append(Loaded(f"{module.name}@sm_{arch}", time.perf_counter() - start,
                              bool(_cache_files(module.name) - before)))
        return out

    modules = _modules(names)
    return [m for built in _in_parallel([lambda m=m: build(m) for m in modules], max_workers or idle_cores())
            for m in built]


# -- warpsph warmup -------------------------------------------------------------------------------------------
def add_arguments(parser):
    parser.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto (CUDA when present; default)")
    parser.add_argument("--scene", nargs="+", metavar="FILE",
                        help="only the modules these scene files launch (as warpsph run does); default: every "
                             "warpsph kernel module")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="compile threads (default: one per idle CPU core, at least 1)")
    parser.add_argument("--arch", type=int, nargs="+", metavar="SM",
                        help="compile for these CUDA architectures (90: H100/H200, 80: A100, 89: L40/RTX 40xx, "
                             "86: RTX 30xx) instead of a device: no GPU needed; the runs on such GPUs find them "
                             "in the same kernel cache")


def command(args):
    """``warpsph warmup``: the modules compiled into Warp's kernel cache; a table on stdout."""
    import warp as wp

    if args.workers is not None and args.workers < 1:
        raise SceneError("", "--workers", f"expected an integer >= 1, got {args.workers}")
    if args.scene:
        names = []
        for path in args.scene:
            names += scene_modules(load_scene(path), frames=True)  # a bad file: SceneError naming it
        names = list(dict.fromkeys(names))
    else:
        names = all_modules()
    if args.arch:
        workers = max(1, min(len(names), args.workers or idle_cores()))
        start = time.perf_counter()
        loaded = compile_for_archs(names, list(dict.fromkeys(args.arch)), max_workers=workers)
        target = "sm_" + ", sm_".join(str(a) for a in dict.fromkeys(args.arch))
    else:
        workers = max(1, min(len(names), args.workers or idle_cores()))
        start = time.perf_counter()
        loaded = preload(names, args.device, max_workers=workers)
        target = args.device
    wall = time.perf_counter() - start
    compiled = [m for m in loaded if m.compiled]
    width = max(len(m.name) for m in loaded)
    for m in sorted(loaded, key=lambda m: -m.seconds):
        print(f"  {m.name:<{width}}  {'compiled' if m.compiled else 'cached  '}  {m.seconds:6.2f} s")
    print(f"warpsph warmup: {len(compiled)} of {len(loaded)} modules compiled {'for' if args.arch else 'on'} {target} in {wall:.2f} s "
          f"({workers} thread{'s' if workers > 1 else ''}); kernel cache {wp.config.kernel_cache_dir}")
    return 0
