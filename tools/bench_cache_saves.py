"""What the single-file cache's saves cost per frame (#38), on the CPU, without a simulation.

    python tools/bench_cache_saves.py [--particles 1000 --frames 300 --frame-ms 20 100] [--out JSON]

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

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def run(kind, particles, frames, frame_ms, folder):
    from warpsph.io import usd

    path = Path(folder) / f"{kind}.usdc"
    cache = usd.UsdPointCache(path, 25, boundary_points=np.zeros((10, 3), np.float32), boundary_radius=0.01)
    if kind == "in_place":
        def save():
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


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--frame-ms", type=float, nargs="*", default=[20.0, 100.0])
    parser.add_argument("--out", help="write the rows as JSON")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_DIR")) as folder:
        for kind, frame_ms in [("in_place", 0.0), ("every_frame", 0.0), *[(f"share_{f:g}ms", f) for f in args.frame_ms]]:
            row = run(kind, args.particles, args.frames, frame_ms, folder)
            print(json.dumps(row), flush=True)
            rows.append(row)
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows, "python": sys.version.split()[0]}, indent=1) + "\n")


if __name__ == "__main__":
    main()
