"""Benchmarks of warpsph's internals (developer script; not part of the package):

- ``kernels``: the GPU time of every kernel of a step (CUDA events), which neighbour pass costs what;
- ``floor``: the floor of one neighbour pass, a cubic-spline density pass over N particles;
- ``cache-saves``: what the single-file cache's saves cost per frame (#38), CPU only, no simulation;
- ``surface-host``: the main process's cost of ``warpsph run --surface`` per frame (#17), CPU only.

    python tools/bench_internals.py kernels --device cuda --particles 1e6 --model all --out tools/results/profile_kernels_1M_h100.json
    python tools/bench_internals.py floor --device cuda --sizes 1e6 8e6 --out tools/results/probe_floor_h100.json
    python tools/bench_internals.py cache-saves [--particles 1000 --frames 300 --frame-ms 20 100] [--out JSON]
    python tools/bench_internals.py surface-host [--vertices 1.5e6 --triangles 3e6 --particles 1e6 --reps 3] [--out JSON]

``python tools/bench_internals.py COMMAND --help`` describes each. They were tools/profile_kernels.py,
tools/probe_floor.py, tools/bench_cache_saves.py and tools/bench_surface_host.py (same options). Each records
warpsph's commit through ``warpsph.validation.cases.commit_info`` (``WARPSPH_COMMIT`` overrides git's).
"""

import argparse
import ctypes
import json
import os
import pickle
import shutil
import statistics
import sys
import tempfile
import threading
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # the checkout's warpsph, also without an installed one

from warpsph.kernels.sph_kernel import cubic_kernel  # noqa: E402

wp.set_module_options({"enable_backward": False})


# -- kernels (was tools/profile_kernels.py) ----------------------------------------------------------------------
KERNELS_DOC = """GPU time of every kernel of a step: which neighbour pass costs what (CUDA only).

    python tools/bench_internals.py kernels --device cuda --particles 1e6 --model all --out tools/results/profile_kernels_1M_h100.json

Runs the dam break at ~N fluid particles for ``--warmup`` steps, then ``--steps`` steps without the
CUDA graph under Warp's CUDA activity timing (events around every kernel, memcpy and memset) and
reports per kernel the ms per step, launches per step and ms per launch. Compare a kernel with
``compute_density_and_factor`` (one plain neighbour pass) to see what a pass costs.
"""


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


def kernels_main(argv=None, prog=None):
    parser = argparse.ArgumentParser(prog=prog, description=KERNELS_DOC,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "dam_break.json"))
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--particles", type=float, default=1e6)
    parser.add_argument("--model", choices=["none", "vorticity_refinement", "rankine", "micropolar", "all"], default="all")
    parser.add_argument("--density-error", type=float, help="override solver.density_max_error [%%]")
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--steps", type=int, default=10, help="steps timed (no CUDA graph)")
    parser.add_argument("--out")
    args = parser.parse_args(argv)

    from warpsph.simulation import Simulation
    from warpsph.validation.bench import make_scene
    from warpsph.validation.cases import commit_info

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


# -- floor (was tools/probe_floor.py) ----------------------------------------------------------------------------
FLOOR_DOC = """The floor of one neighbour pass: a cubic-spline density pass over N particles.

    python tools/bench_internals.py floor --device cuda --sizes 1e6 8e6 --out tools/results/probe_floor_h100.json

For each size, a jittered lattice of spacing 2r (support 4r, ~33 neighbours) is timed:
- ``grid_sorted_ms`` / ``grid_random_ms``: the density pass querying ``wp.HashGrid`` on the fly, with the
  particles in cell order and in random order (the reference figures: 1.03 / 3.74 ms at 1M on an H100);
- ``list_ms``: the same pass reading a CSR neighbour list (what warpsph's solver passes do);
- ``grid_build_ms`` (the hash grid), ``cell_grid_build_ms`` (warpsph's dense cell grid: count, scan, scatter)
  and ``list_build_ms`` (the list from that cell grid: count + scan + fill).
A DFSPH step costs k neighbour passes; its floor is k x the pass floor.
"""


@wp.kernel
def density_grid(grid: wp.uint64, x: wp.array(dtype=wp.vec3), H: float, volume: float, rho: wp.array(dtype=float)):
    i = wp.tid()
    xi = x[i]
    s = float(0.0)
    query = wp.hash_grid_query(grid, xi, H)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        s += cubic_kernel(wp.length(xi - x[j]), H)
    rho[i] = volume * s


@wp.kernel
def density_list(x: wp.array(dtype=wp.vec3), offsets: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32),
                 H: float, volume: float, rho: wp.array(dtype=float)):
    i = wp.tid()
    xi = x[i]
    s = cubic_kernel(0.0, H)
    for k in range(offsets[i], offsets[i + 1]):
        s += cubic_kernel(wp.length(xi - x[index[k]]), H)
    rho[i] = volume * s


def timed(fn, device, repeats=20):
    fn()
    wp.synchronize_device(device)
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        samples.append(1e3 * (time.perf_counter() - start))
    return float(np.median(samples))


def probe(n, device, seed=0):
    from warpsph.kernels import neighbours as nk

    r = 0.005
    d, H = 2 * r, 4 * r
    side = int(round(n ** (1 / 3)))
    g = np.arange(side) * d
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pts += np.random.default_rng(seed).uniform(-0.1 * d, 0.1 * d, pts.shape)
    n = len(pts)
    grid = wp.HashGrid(128, 128, 128, device=device)
    result = {"particles": n}
    rho = wp.zeros(n, dtype=float, device=device)
    for order in ("sorted", "random"):
        p = pts if order == "sorted" else pts[np.random.default_rng(seed + 1).permutation(n)]
        x = wp.array(p.astype(np.float32), dtype=wp.vec3, device=device)
        grid.build(x, H)
        result[f"grid_{order}_ms"] = timed(lambda: wp.launch(density_grid, n, [grid.id, x, H, d**3, rho], device=device), device)
        if order == "sorted":
            result["grid_build_ms"] = timed(lambda: grid.build(x, H), device)
            # warpsph's own search: points counting-sorted into a dense grid of cells of the support radius
            # (warpsph.neighbours.PointGrid), then the CSR list (count, scan, fill; NeighbourSearch._build_list)
            lower = pts.min(axis=0) - H
            dims = [int(np.ceil(e / H)) + 1 for e in pts.max(axis=0) + H - lower]
            cells = nk.CellGrid()
            cells.lower = wp.vec3(*lower.astype(np.float32))
            cells.inverse_cell_size = 1.0 / H
            cells.dims = wp.vec3i(*dims)
            cells.cell_end = wp.zeros(int(np.prod(dims)), dtype=wp.int32, device=device)
            cells.ids = wp.zeros(n, dtype=wp.int32, device=device)

            def build_cells():
                cells.cell_end.zero_()
                wp.launch(nk.count_points_in_cells, n, [cells, x], device=device)
                wp.utils.array_scan(cells.cell_end, cells.cell_end, inclusive=False)
                wp.launch(nk.scatter_points_to_cells, n, [cells, x], device=device)

            build_cells()
            result["cell_grid_build_ms"] = timed(build_cells, device)
            offsets = wp.zeros(n + 1, dtype=wp.int32, device=device)
            box = [cells.lower, wp.vec3(0.0)]  # not periodic
            no_list = wp.empty(0, dtype=wp.int32, device=device)

            def build_list():
                offsets[n:].zero_()
                wp.launch(nk.find_neighbours, n, [cells, x, x, H, 1, *box, 0, offsets, no_list], device=device)
                wp.utils.array_scan(offsets, offsets, inclusive=False)
                return offsets

            build_list()
            total = int(offsets.numpy()[n])
            index = wp.zeros(total, dtype=wp.int32, device=device)

            def fill():
                build_list()
                wp.launch(nk.find_neighbours, n, [cells, x, x, H, 1, *box, 1, offsets, index], device=device)

            result["list_build_ms"] = timed(fill, device)
            result["mean_neighbours"] = total / n
            result["list_ms"] = timed(lambda: wp.launch(density_list, n, [x, offsets, index, H, d**3, rho], device=device), device)
    return result


def floor_main(argv=None, prog=None):
    parser = argparse.ArgumentParser(prog=prog, description=FLOOR_DOC,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e6])
    parser.add_argument("--out")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(args.device)
    from warpsph.validation.cases import commit_info

    report = {"device": device.name if device.is_cuda else "cpu", "warp": wp.__version__, **commit_info(),
              "probes": [probe(int(n), device) for n in args.sizes]}
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


# -- cache-saves (was tools/bench_cache_saves.py) ----------------------------------------------------------------
CACHE_SAVES_DOC = """What the single-file cache's saves cost per frame (#38), on the CPU, without a simulation.

    python tools/bench_internals.py cache-saves [--particles 1000 --frames 300 --frame-ms 20 100] [--out JSON]

Writes ``--frames`` frames of ``--particles`` particles (random float32 points, velocities and density, ids and
widths once: what ``warpsph run`` writes of a plain scene) through :class:`warpsph.io.usd.UsdPointCache` and times
each ``write_frame`` (arrays set and, when due, the save), for:

- ``in_place``: ``layer.Save()`` after every frame (warpsph before #38: the crate file is rewritten from its old
  table of contents on, then its header; a kill in between leaves a file USD cannot open);
- ``every_frame``: a crash-consistent save after every frame (``flush_share=None``: the whole file to
  NAME.tmp.usdc, fsync, rename, fsync of the folder), which grows with the cache;
- ``share_F`` for each ``--frame-ms`` F: ``flush_share=FLUSH_SHARE`` (what the CLI uses) with F ms of simulation
  between frames (a sleep): saves when the last one took at most that share of the time since it began.
  ``most_unsaved`` is the most frames written and not yet saved (what a kill could lose; a checkpoint saves).

Each row: ms a frame (first 10, last 10, mean), saves, most frames between saves, the file's size.
"""


def cache_saves_run(kind, particles, frames, frame_ms, folder):
    from warpsph.io import usd

    path = Path(folder) / f"{kind}.usdc"
    cache = usd.UsdPointCache(path, 25, boundary_points=np.zeros((10, 3), np.float32), boundary_radius=0.01)
    if kind == "in_place":
        def save(again=True):
            layer = cache.stage.GetRootLayer()
            if not layer.Save():
                raise OSError("save failed")
            cache.flushes += 1

        cache.flush = save
    elif kind.startswith("share"):
        cache.flush_share = usd.FLUSH_SHARE
    rng = np.random.default_rng(0)
    ids = np.arange(particles)
    times, saved_at = [], []
    for frame in range(frames):
        x, v = rng.random((particles, 3), dtype=np.float32), rng.random((particles, 3), dtype=np.float32)
        density = rng.random(particles, dtype=np.float32)
        if frame_ms:
            time.sleep(frame_ms / 1000)
        before = cache.flushes
        start = time.perf_counter()
        cache.write_frame(frame, x, v, ids, 0.01, {"density": density})
        times.append(time.perf_counter() - start)
        if cache.flushes > before:
            saved_at.append(frame)
    cache.finish(path)
    gaps = np.diff([-1, *saved_at, frames - 1])
    t = np.array(times) * 1e3
    return {"kind": kind, "particles": particles, "frames": frames, "frame_ms": frame_ms,
            "ms_first10": round(float(t[:10].mean()), 3), "ms_last10": round(float(t[-10:].mean()), 3),
            "ms_mean": round(float(t.mean()), 3), "saves": len(saved_at), "most_unsaved": int(gaps.max()) - 1,
            "bytes": path.stat().st_size}


def cache_saves_main(argv=None, prog=None):
    parser = argparse.ArgumentParser(prog=prog, description=CACHE_SAVES_DOC,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--frame-ms", type=float, nargs="*", default=[20.0, 100.0])
    parser.add_argument("--out", help="write the rows as JSON")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_DIR")) as folder:
        for kind, frame_ms in [("in_place", 0.0), ("every_frame", 0.0), *[(f"share_{f:g}ms", f) for f in args.frame_ms]]:
            row = cache_saves_run(kind, args.particles, args.frames, frame_ms, folder)
            print(json.dumps(row), flush=True)
            rows.append(row)
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows, "python": sys.version.split()[0]}, indent=1) + "\n")


# -- surface-host (was tools/bench_surface_host.py) --------------------------------------------------------------
SURFACE_HOST_DOC = """Main-process cost of ``warpsph run --surface`` per frame, on the CPU (no GPU, no simulation).

    python tools/bench_internals.py surface-host [--vertices 1.5e6 --triangles 3e6 --particles 1e6 --reps 3] [--out JSON]

A 1M-particle frame: x, v and vorticity (N, 3) float32 go to a mesher worker, a mesh of about 1.5M
vertices and 3M triangles (a synthetic, smooth height field: splashsurf's meshes of a 1M dam break have
1-2M vertices and 2-4M triangles) comes back and is written into the USD cache. Each item is timed on
the calling thread (``wall``) while a second thread stands in for the simulation's host thread (10 us
of Python, then a ctypes call that releases the GIL, as ``wp.launch`` does): ``held`` is the time that
thread could not run, i.e. what the item costs the simulation on a machine with free cores. Items:

- ``pickle_out``/``pickle_in``: pickling the worker's arguments and unpickling its mesh (what
  ProcessPoolExecutor does in the main process); ``pool_pickled``: the whole hand-over by pickle
  through a spawned pool, pipe included (the worker's side runs on another core);
- ``files_out``/``files_in`` and ``pool_exchange``: the same through the files of the exchange folder
  of :class:`warpsph.surface.ProcessMesher` (``warpsph.io.processes``; where this version has one);
- ``write_surface_single`` (``cache.write_surface(frame, mesh, save=False)`` of a single file) and
  ``save_single`` (the layer's save that follows, the mesh's share), ``write_surface_clips``
  (the frame layer opened, the mesh written, saved, in this process); ``write_frame_*`` (the
  particles, for scale); ``pool_clips_worker_writes``: the hand-over of a --clips frame whose
  worker writes the mesh into the frame's layer itself (where this version does).

Medians over ``--reps`` frames (and the least ``held``), in ms per frame. The pool's worker runs at
the mesher workers' lower priority (niceness 10); on a machine of few cores its work still takes some
of the stand-in's CPU, which counts as ``held``. This machine's page faults and pickling speed differ
from a GPU host's: compare before/after on one machine.
"""


_libc = ctypes.CDLL(None)


class HostThread:
    """Stands in for the simulation's host thread: ~10 us of Python, then a ctypes call (releases the GIL)."""

    def __init__(self):
        self.count, self.stop = 0, False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        time.sleep(0.2)
        c0, start = self.count, time.perf_counter()
        time.sleep(0.5)
        self.rate = (self.count - c0) / (time.perf_counter() - start)

    def _run(self):
        getpid = _libc.getpid
        while not self.stop:
            for _ in range(200):
                pass
            getpid()
            self.count += 1

    def time(self, f):
        """(wall ms, ms the host thread lost, f's result)."""
        c0, start = self.count, time.perf_counter()
        result = f()
        wall = time.perf_counter() - start
        return 1e3 * wall, 1e3 * max(0.0, wall - (self.count - c0) / self.rate), result


def grid_mesh(vertices, triangles, seed=0):
    """A smooth height field of about ``vertices`` vertices (its triangles: about 2 per vertex; ``triangles``
    more than that repeat faces) with normals, velocities and a vorticity magnitude, like splashsurf's."""
    from warpsph.surface import SurfaceMesh

    n = int(np.sqrt(vertices))
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    height = 0.1 * np.sin(i / 50.0) * np.cos(j / 70.0)
    points = np.stack([i * 0.005, height, j * 0.005], -1).reshape(-1, 3).astype(np.float32)
    a = (i[:-1, :-1] * n + j[:-1, :-1]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + n], 1), np.stack([a + 1, a + n + 1, a + n], 1)]).astype(np.int32)
    if triangles > len(faces):
        faces = np.concatenate([faces, faces[: int(triangles) - len(faces)]])
    normals = np.tile(np.float32([0, 1, 0]), (len(points), 1))
    velocities = np.random.default_rng(seed).normal(size=points.shape).astype(np.float32)
    return SurfaceMesh(points, np.ascontiguousarray(faces), normals, velocities,
                       {"vorticity_magnitude": np.linalg.norm(velocities, axis=1)})


_worker_mesh = {}


def _pool_pickled(size, x, v, w):  # the old hand-over: arguments and the mesh by pickle
    if size not in _worker_mesh:
        _worker_mesh[size] = grid_mesh(*size)
    return _worker_mesh[size]


def _pool_exchange(size, x, v, w, folder):  # through the exchange folder
    from warpsph import surface
    from warpsph.io import processes

    for item in (x, v, w):
        processes.load(item)
    if size not in _worker_mesh:
        _worker_mesh[size] = grid_mesh(*size)
    return surface._store_mesh(_worker_mesh[size], folder)


def _pool_clip_layer(size, x, v, w, layer):  # --clips: the worker writes the mesh into the frame's layer
    from warpsph import surface
    from warpsph.io import processes
    from warpsph.io.usd import write_surface_layer

    for item in (x, v, w):
        processes.load(item)
    if size not in _worker_mesh:
        _worker_mesh[size] = grid_mesh(*size)
    write_surface_layer(*layer, _worker_mesh[size])
    written = surface.SurfaceMesh.empty()
    written.layer = layer[0]
    return written


def surface_host_main(argv=None, prog=None):
    parser = argparse.ArgumentParser(prog=prog, description=SURFACE_HOST_DOC,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vertices", type=float, default=1.5e6)
    parser.add_argument("--triangles", type=float, default=3e6)
    parser.add_argument("--particles", type=float, default=1e6)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--no-pool", action="store_true", help="skip the hand-over through a spawned pool")
    parser.add_argument("--out", help="JSON file")
    args = parser.parse_args(argv)

    from warpsph import surface
    from warpsph.io import processes
    from warpsph.io.usd import UsdClipCache, UsdPointCache

    size = (int(args.vertices), int(args.triangles))
    mesh = grid_mesh(*size)
    count = int(args.particles)
    rng = np.random.default_rng(1)
    x, v, w = (rng.random((count, 3), np.float32) for _ in range(3))
    ids = np.arange(count)
    host = HostThread()
    items = {}

    def record(name, result):
        items.setdefault(name, []).append(result[:2])
        return result[2]

    exchange = hasattr(surface, "_store_mesh")
    tmp = Path(tempfile.mkdtemp(prefix="bench-surface-host-"))
    try:
        for _ in range(args.reps):
            data = record("pickle_out", host.time(lambda: pickle.dumps((x, v, w), pickle.HIGHEST_PROTOCOL)))
            del data
            data = pickle.dumps(mesh, pickle.HIGHEST_PROTOCOL)
            record("pickle_in", host.time(lambda: pickle.loads(data)))
            del data
            if exchange:
                folder = tempfile.mkdtemp(dir=processes.exchange_root())
                try:
                    stored = record("files_out", host.time(lambda: [processes.store(os.path.join(folder, k), a)
                                                                   for k, a in zip("xvw", (x, v, w))]))
                    sent = surface._store_mesh(mesh, folder)
                    record("files_in", host.time(lambda: surface._load_mesh(sent)))
                    del stored
                finally:
                    shutil.rmtree(folder, ignore_errors=True)
        if not args.no_pool:
            import multiprocessing

            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=processes._init_worker, initargs=(1,)) as pool:
                pool.submit(_pool_pickled, size, x[:1], v[:1], w[:1]).result()  # starts the worker, makes its mesh
                for _ in range(args.reps):
                    record("pool_pickled", host.time(lambda: pool.submit(_pool_pickled, size, x, v, w).result()))
                if exchange:
                    for _ in range(args.reps):
                        folder = tempfile.mkdtemp(dir=processes.exchange_root())
                        def hand_over():
                            inputs = [processes.store(os.path.join(folder, k), a) for k, a in zip("xvw", (x, v, w))]
                            return surface._load_mesh(pool.submit(_pool_exchange, size, *inputs, folder).result())

                        try:
                            record("pool_exchange", host.time(hand_over))
                        finally:
                            shutil.rmtree(folder, ignore_errors=True)
        single = UsdPointCache(tmp / "single.usdc", 25)
        clips = UsdClipCache(tmp / "clips.usda", 25)
        if exchange and hasattr(clips, "surface_layer") and not args.no_pool:
            import multiprocessing

            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=processes._init_worker, initargs=(1,)) as pool:
                pool.submit(_pool_pickled, size, x[:1], v[:1], w[:1]).result()
                worker_clips = UsdClipCache(tmp / "worker_clips.usda", 25)
                for frame in range(args.reps):
                    worker_clips.write_frame(frame, x, v, ids, 0.01, {"vorticity_magnitude": w[:, 0]})
                    folder = tempfile.mkdtemp(dir=processes.exchange_root())

                    def hand_over():
                        inputs = [processes.store(os.path.join(folder, k), a) for k, a in zip("xvw", (x, v, w))]
                        layer = (worker_clips.surface_layer(frame), frame)
                        done = surface._load_mesh(pool.submit(_pool_clip_layer, size, *inputs, layer).result())
                        worker_clips.write_surface(frame, done)  # there already

                    try:
                        record("pool_clips_worker_writes", host.time(hand_over))
                    finally:
                        shutil.rmtree(folder, ignore_errors=True)
        for frame in range(args.reps):
            fields = {"vorticity_magnitude": w[:, 0]}
            record("write_frame_single", host.time(lambda: single.write_frame(frame, x, v, ids, 0.01, fields)))
            record("write_surface_single", host.time(lambda: single.write_surface(frame, mesh, save=False)))
            record("save_single", host.time(lambda: single.stage.GetRootLayer().Save()))
            record("write_frame_clips", host.time(lambda: clips.write_frame(frame, x, v, ids, 0.01, fields)))
            record("write_surface_clips", host.time(lambda: clips.write_surface(frame, mesh)))
    finally:
        host.stop = True
        shutil.rmtree(tmp, ignore_errors=True)

    rows = {name: {"wall_ms": round(statistics.median(r[0] for r in rs), 1),
                   "held_ms": round(statistics.median(r[1] for r in rs), 1),
                   "held_min_ms": round(min(r[1] for r in rs), 1)} for name, rs in items.items()}
    from warpsph.validation.cases import commit_info

    report = {"vertices": len(mesh.points), "triangles": len(mesh.faces), "particles": count, "reps": args.reps,
              "cpus": os.cpu_count(), **commit_info(), "items": rows}
    for name, row in rows.items():
        print(f"{name:24s} wall {row['wall_ms']:7.1f} ms   held {row['held_ms']:7.1f} ms "
              f"(least {row['held_min_ms']:.1f})")
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


COMMANDS = {"kernels": kernels_main, "floor": floor_main, "cache-saves": cache_saves_main,
            "surface-host": surface_host_main}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=list(COMMANDS), help="the benchmark")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="its options (COMMAND --help lists them)")
    args = parser.parse_args(argv)
    return COMMANDS[args.command](args.options, prog=f"{Path(parser.prog).name} {args.command}")


if __name__ == "__main__":
    sys.exit(main())
