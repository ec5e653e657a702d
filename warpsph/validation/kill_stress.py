"""SIGKILLs of `warpsph run` and its resumes at random moments of their whole life (#38), outside CI: whether a
killed run always leaves a cache that opens and a checkpoint that resumes to the uninterrupted run's result.

    python -m warpsph.validation.kill_stress [--seed 11] [--trials 30] [--folder DIR]

Each trial runs the 45-particle tank of tests/test_faults.py (40 frames, --checkpoint-every 3) on the CPU and
SIGKILLs it 0.5-2.6 s after it starts (start-up included), then resumes it and kills the resume the same way,
until a process finishes. After each kill: with a checkpoint at frame F, OUT.usdc or OUT.partial.usdc must open
with pxr and hold frames 0..F (else the trial is bad); without one, the run starts again with --overwrite, which
must be accepted. Each finished trial must hold frames 0..40 and the uninterrupted run's final positions, bit for
bit. Prints a line per trial and the number of bad trials.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FRAMES = 40
SCENE = {"name": "tank", "particle_radius": 0.03, "domain": {"min": [0, 0, 0], "max": [0.6, 0.4, 0.2]},
         "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.3, 0.2]}], "output": {"fps": 50, "frames": FRAMES}}


def cache(path):
    """(frames, final positions or None) of a cache; raises if pxr cannot open it."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr()
    frames = [int(t) for t in points.GetTimeSamples()]
    return frames, np.array(points.Get(FRAMES)) if FRAMES in frames else None


def cli(*argv):
    return [sys.executable, "-m", "warpsph.cli", *map(str, argv), "--device", "cpu", "-q"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--folder", help="work folder (default: a temporary one)")
    args = parser.parse_args(argv)
    import h5py

    rng = np.random.default_rng(args.seed)
    root = Path(args.folder or tempfile.mkdtemp(prefix="kill_stress."))
    root.mkdir(parents=True, exist_ok=True)
    scene = root / "scene.json"
    scene.write_text(json.dumps(SCENE))
    subprocess.run(cli("run", scene, "--out", root / "ref" / "long.usdc", "--overwrite"), check=True)
    final = cache(root / "ref" / "long.usdc")[1]
    bad = kills = 0
    for trial in range(args.trials):
        work = root / "t"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
        out, checkpoint = work / "long.usdc", work / "long.checkpoint.h5"
        command = ["run", scene, "--out", out, "--checkpoint-every", 3]
        while True:
            proc = subprocess.Popen(cli(*command), stderr=subprocess.DEVNULL)
            time.sleep(rng.uniform(0.5, 2.6))
            proc.kill()
            proc.wait()
            if proc.returncode >= 0:  # finished (0) or refused (2)
                break
            kills += 1
            if not checkpoint.exists():
                command = ["run", scene, "--out", out, "--checkpoint-every", 3, "--overwrite"]
                continue
            with h5py.File(checkpoint, "r") as f:
                frame = int(f.attrs["frame"])
            held = []
            for path in (out, work / "long.partial.usdc"):
                try:
                    held.append(cache(path)[0][: frame + 1] == list(range(frame + 1)))
                except Exception:  # missing or unreadable
                    held.append(False)
            if not any(held):
                break
            command = ["resume", checkpoint]
        try:
            frames, last = cache(out)
            ok = proc.returncode == 0 and frames == list(range(FRAMES + 1)) and np.array_equal(last, final)
        except Exception:
            ok = False
        bad += not ok
        print(f"trial {trial}: {'complete and identical' if ok else 'BAD'}; files {sorted(os.listdir(work))}",
              flush=True)
    print(f"{args.trials} trials, {kills} kills, {bad} bad")
    return int(bad > 0)


if __name__ == "__main__":
    sys.exit(main())
