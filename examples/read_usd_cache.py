"""Reads a warpsph USD point cache back with pxr (usd-core): per frame the particle count, mean
speed and the fluid's height, plus the stage's metadata. Without a cache, makes a small one first.

    python examples/read_usd_cache.py out/examples/dam_break.usdc
"""

import argparse
import csv
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom


def read_frames(path):
    """(frame, points (N, 3), velocities (N, 3), ids (N,)) for each time code of /World/Fluid."""
    stage = Usd.Stage.Open(str(path))
    fluid = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    start, end = int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode())
    for frame in range(start, end + 1):
        points = np.asarray(fluid.GetPointsAttr().Get(frame))
        velocities = np.asarray(fluid.GetVelocitiesAttr().Get(frame))
        ids = np.asarray(fluid.GetIdsAttr().Get(frame))  # held from the last frame that wrote them
        yield frame, points, velocities, ids


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("cache", nargs="?", help="a .usdc written by warpsph (default: run a small dam break)")
    parser.add_argument("--scale", type=float, default=0.02, help="of the dam break made when no cache is given")
    parser.add_argument("--device", default=None, help="of the dam break made when no cache is given")
    parser.add_argument("--out", default="out/examples/cache_summary.csv")
    args = parser.parse_args(argv)

    cache = args.cache
    if cache is None:
        import dam_break_usd  # the example next to this one

        cache = "out/examples/dam_break_small.usdc"
        dam_break_usd.main(["--scale", str(args.scale), "--frames", "10", "--out", cache]
                           + (["--device", args.device] if args.device else []))

    stage = Usd.Stage.Open(str(cache))
    print(f"{cache}: {stage.GetTimeCodesPerSecond():g} fps, up axis {UsdGeom.GetStageUpAxis(stage)}, "
          f"generator {stage.GetRootLayer().customLayerData.get('generator')}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "particles", "mean_speed", "max_height"])
        for frame, x, v, ids in read_frames(cache):
            speed = float(np.linalg.norm(v, axis=1).mean()) if len(v) else 0.0
            height = float(x[:, 1].max()) if len(x) else 0.0
            w.writerow([frame, len(x), f"{speed:.6g}", f"{height:.6g}"])
            print(f"frame {frame:3d}  particles {len(x):6d}  mean speed {speed:.3f} m/s  height {height:.3f} m")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
