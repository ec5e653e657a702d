"""Imports a warpsph USD cache into Blender (headless) and reports what Blender sees.

Run it with a Python that has Blender as a module (``pip install bpy==5.0.1``, Python 3.11):

    python tools/check_blender.py out/dam_break.usdc --frames 0 10 [--json report.json]

Prints (and writes) JSON: Blender's version, and per frame the point count, the attributes of
the imported point cloud, and the first point's velocity, radius and density; for a cache with a
surface mesh (``warpsph run --surface``, ``/World/FluidSurface``) also the mesh's vertex and
triangle counts per frame as Blender evaluates them (they change from frame to frame), its
attributes (velocity, vorticity_magnitude) and the modifiers Blender animates it with. ``tests/test_blender.py``
compares that with what pxr reads from the same file, for the single-file and value-clip modes.
"""

import argparse
import json
import sys


def inspect(path, frames):
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    if "FINISHED" not in bpy.ops.wm.usd_import(filepath=str(path)):
        raise SystemExit(f"check_blender: Blender could not import {path}")
    clouds = [o for o in bpy.data.objects if o.type == "POINTCLOUD"]
    meshes = [o for o in bpy.data.objects if o.type == "MESH" and o.name.startswith("FluidSurface")]
    report = {"blender": bpy.app.version_string, "objects": {o.name: o.type for o in bpy.data.objects}, "frames": {}}
    scene = bpy.context.scene
    for frame in frames:
        scene.frame_set(frame)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        for obj in clouds:
            data = obj.evaluated_get(depsgraph).data
            attrs = data.attributes
            entry = {"object": obj.name, "points": len(data.points), "attributes": sorted(a.name for a in attrs)}
            if len(data.points):
                if "velocity" in attrs:
                    entry["velocity0"] = list(attrs["velocity"].data[0].vector)
                if "radius" in attrs:
                    entry["radius0"] = attrs["radius"].data[0].value
                if "density" in attrs:
                    values = [d.value for d in attrs["density"].data]
                    entry["density_mean"] = sum(values) / len(values)
            report["frames"][str(frame)] = entry
        for obj in meshes:
            data = obj.evaluated_get(depsgraph).data
            report["frames"][str(frame)]["surface"] = {
                "object": obj.name, "vertices": len(data.vertices), "polygons": len(data.polygons),
                "triangles": sum(1 for p in data.polygons if p.loop_total == 3),
                "attributes": sorted(a.name for a in data.attributes if not a.name.startswith(".")),
                "modifiers": [m.type for m in obj.modifiers]}
    return report


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("cache", help="a .usdc/.usda cache written by warpsph")
    parser.add_argument("--frames", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--json", help="also write the report here")
    args = parser.parse_args(argv)
    try:
        import bpy  # noqa: F401
    except ImportError:
        sys.exit("check_blender: needs Blender as a Python module: pip install bpy==5.0.1 (Python 3.11)")
    report = inspect(args.cache, args.frames)
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
