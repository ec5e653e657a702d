"""Main-process cost of ``warpsph run --surface`` per frame, on the CPU (no GPU, no simulation).

    python tools/bench_surface_host.py [--vertices 1.5e6 --triangles 3e6 --particles 1e6 --reps 3] [--out JSON]

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
  of :class:`warpsph.surface.ProcessMesher` (where this version has one);
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

from __future__ import annotations

import argparse
import ctypes
import json
import os
import pickle
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

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

    for item in (x, v, w):
        surface._load(item)
    if size not in _worker_mesh:
        _worker_mesh[size] = grid_mesh(*size)
    return surface._store_mesh(_worker_mesh[size], folder)


def _pool_clip_layer(size, x, v, w, layer):  # --clips: the worker writes the mesh into the frame's layer
    from warpsph import surface
    from warpsph.io.usd import write_surface_layer

    for item in (x, v, w):
        surface._load(item)
    if size not in _worker_mesh:
        _worker_mesh[size] = grid_mesh(*size)
    write_surface_layer(*layer, _worker_mesh[size])
    written = surface.SurfaceMesh.empty()
    written.layer = layer[0]
    return written


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vertices", type=float, default=1.5e6)
    parser.add_argument("--triangles", type=float, default=3e6)
    parser.add_argument("--particles", type=float, default=1e6)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--no-pool", action="store_true", help="skip the hand-over through a spawned pool")
    parser.add_argument("--out", help="JSON file")
    args = parser.parse_args(argv)

    from warpsph import surface
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
                folder = tempfile.mkdtemp(dir=surface._exchange_root())
                try:
                    stored = record("files_out", host.time(lambda: [surface._store(os.path.join(folder, k), a)
                                                                   for k, a in zip("xvw", (x, v, w))]))
                    sent = surface._store_mesh(mesh, folder)
                    record("files_in", host.time(lambda: surface._load_mesh(sent)))
                    del stored
                finally:
                    shutil.rmtree(folder, ignore_errors=True)
        if not args.no_pool:
            import multiprocessing

            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=surface._init_worker, initargs=(1,)) as pool:
                pool.submit(_pool_pickled, size, x[:1], v[:1], w[:1]).result()  # starts the worker, makes its mesh
                for _ in range(args.reps):
                    record("pool_pickled", host.time(lambda: pool.submit(_pool_pickled, size, x, v, w).result()))
                if exchange:
                    for _ in range(args.reps):
                        folder = tempfile.mkdtemp(dir=surface._exchange_root())
                        def hand_over():
                            inputs = [surface._store(os.path.join(folder, k), a) for k, a in zip("xvw", (x, v, w))]
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
                                     initializer=surface._init_worker, initargs=(1,)) as pool:
                pool.submit(_pool_pickled, size, x[:1], v[:1], w[:1]).result()
                worker_clips = UsdClipCache(tmp / "worker_clips.usda", 25)
                for frame in range(args.reps):
                    worker_clips.write_frame(frame, x, v, ids, 0.01, {"vorticity_magnitude": w[:, 0]})
                    folder = tempfile.mkdtemp(dir=surface._exchange_root())

                    def hand_over():
                        inputs = [surface._store(os.path.join(folder, k), a) for k, a in zip("xvw", (x, v, w))]
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
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
    except OSError:
        commit = ""
    report = {"vertices": len(mesh.points), "triangles": len(mesh.faces), "particles": count, "reps": args.reps,
              "cpus": os.cpu_count(), "commit": commit, "items": rows}
    for name, row in rows.items():
        print(f"{name:24s} wall {row['wall_ms']:7.1f} ms   held {row['held_ms']:7.1f} ms "
              f"(least {row['held_min_ms']:.1f})")
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
