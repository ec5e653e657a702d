"""A shaded picture of one frame's surface mesh (/World/FluidSurface) with matplotlib (#17): a look at what
``warpsph run --surface`` or ``warpsph surface`` meshed, without a renderer (needs matplotlib and usd-core).

    warpsph run scenes/dam_break.json --scale 0.5 --frames 12 --device cpu --out out/db.usdc --surface --surface-cube 0.5
    python -m warpsph.validation.render_surface out/db.usdc --frame 12 --out docs/img/dam_break_surface.png

Flat-shaded triangles (Lambert with one light and some ambient, depth-sorted by matplotlib), coloured
by the vertices' speed (the mesh's interpolated ``velocities``), the domain box as thin lines. No
renderer is needed; for a real render import the cache in Blender or any USD viewer.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("cache", help="a USD cache with /World/FluidSurface (warpsph run --surface, warpsph surface)")
    parser.add_argument("--frame", type=int, default=None, help="default: the last frame")
    parser.add_argument("--out", default="surface.png")
    parser.add_argument("--dpi", type=int, default=110)
    parser.add_argument("--elev", type=float, default=24.0)
    parser.add_argument("--azim", type=float, default=-62.0)
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(args.cache)
    prim = stage.GetPrimAtPath("/World/FluidSurface")
    if not prim:
        sys.exit(f"{args.cache}: no /World/FluidSurface (run with --surface, or warpsph surface {args.cache})")
    mesh = UsdGeom.Mesh(prim)
    times = mesh.GetPointsAttr().GetTimeSamples()
    frame = times[-1] if args.frame is None else args.frame
    points = np.array(mesh.GetPointsAttr().Get(frame), np.float64)
    faces = np.array(mesh.GetFaceVertexIndicesAttr().Get(frame), np.int64).reshape(-1, 3)
    velocities = mesh.GetVelocitiesAttr().Get(frame)
    speed = np.linalg.norm(np.array(velocities), axis=1) if velocities else np.zeros(len(points))
    z_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    show = points if z_up else points[:, [0, 2, 1]]  # matplotlib's z is up
    tri = show[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    light = np.array([0.1, -0.8, 0.6])  # from about the camera, above
    light /= np.linalg.norm(light)
    lambert = np.clip(normals @ light, 0.0, 1.0)
    face_speed = speed[faces].mean(axis=1)
    colour = plt.get_cmap("Blues")(0.3 + 0.35 * np.clip(face_speed / max(face_speed.max(), 1e-9), 0, 1))[:, :3]
    specular = np.clip(normals @ ((light + np.array([0.43, -0.81, 0.41])) / 2), 0, 1) ** 40
    shaded = np.clip(colour * (0.45 + 0.7 * lambert[:, None]) + 0.5 * specular[:, None], 0, 1)

    fig = plt.figure(figsize=(6.4, 3.2))
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(tri, facecolors=shaded, edgecolors="none", linewidths=0))
    boundary = stage.GetPrimAtPath("/World/Boundary")
    lo, hi = show.min(axis=0), show.max(axis=0)
    if boundary:
        b = np.array(UsdGeom.Points(boundary).GetPointsAttr().Get(), np.float64)
        b = b if z_up else b[:, [0, 2, 1]]
        lo, hi = b.min(axis=0), b.max(axis=0)
        hi[2] = max(show[:, 2].max(), 0.5 * hi[2])
        for x in (lo[0], hi[0]):
            for y in (lo[1], hi[1]):
                ax.plot([x, x], [y, y], [lo[2], hi[2]], color="0.6", lw=0.6)
        for z in (lo[2],):
            ax.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[1], lo[1], hi[1], hi[1], lo[1]], [z] * 5, color="0.6", lw=0.6)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo, zoom=1.15)
    ax.view_init(elev=args.elev, azim=args.azim)
    ax.set_axis_off()
    fps = stage.GetTimeCodesPerSecond()
    ax.set_title(f"{Path(args.cache).stem}: frame {int(frame)} (t = {frame / fps:.2f} s), {len(faces)} triangles",
                 fontsize=9)
    fig.subplots_adjust(-0.05, -0.1, 1.05, 1.08)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=args.dpi)
    print(f"wrote {args.out} ({Path(args.out).stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    sys.exit(main())
