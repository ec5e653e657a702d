"""A real client: Blender (bpy 5.0) imports both cache modes with the right points and attributes."""

import importlib.util
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warpsph.cli import main
from conftest import tank_scene

TOOL = Path(__file__).resolve().parent.parent / "tools" / "check_blender.py"


def blender_python():
    """A Python that imports bpy: $WARPSPH_BLENDER_PYTHON, else none."""
    candidate = os.environ.get("WARPSPH_BLENDER_PYTHON")
    if candidate and shutil.which(candidate):
        probe = subprocess.run([candidate, "-c", "import bpy"], capture_output=True)
        if probe.returncode == 0:
            return candidate
    return None


@pytest.mark.skipif(blender_python() is None,
                    reason="Blender as a Python module is absent: pip install bpy==5.0.1 in a Python 3.11 "
                           "environment and set WARPSPH_BLENDER_PYTHON to its python")
@pytest.mark.parametrize("mode", ["single", "clips"])
def test_blender_imports_the_cache(tmp_path, mode):
    scene = tmp_path / "tank.json"
    scene.write_text(json.dumps(tank_scene(radius=0.04, output={"fps": 20, "frames": 2})))
    out = tmp_path / ("tank.usdc" if mode == "single" else "tank.usda")
    extra = ["--clips"] if mode == "clips" else []
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet"] + extra) == 0
    result = subprocess.run([blender_python(), str(TOOL), str(out), "--frames", "0", "2"], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout[result.stdout.index("{"):])
    stage = Usd.Stage.Open(str(out))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    for frame in (0, 2):
        seen = report["frames"][str(frame)]
        assert seen["points"] == len(points.GetPointsAttr().Get(frame))
        assert {"velocity", "radius", "density"} <= set(seen["attributes"])
        np.testing.assert_allclose(seen["velocity0"], points.GetVelocitiesAttr().Get(frame)[0], rtol=1e-5, atol=1e-7)
        assert seen["radius0"] == pytest.approx(0.04)
        density = np.array(points.GetPrim().GetAttribute("primvars:density").Get(frame))
        assert seen["density_mean"] == pytest.approx(density.mean(), rel=1e-5)
    assert "Boundary" not in report["objects"]  # purpose guide: not rendered, not imported


@pytest.mark.skipif(blender_python() is None or importlib.util.find_spec("pysplashsurf") is None,
                    reason="needs Blender as a Python module ($WARPSPH_BLENDER_PYTHON) and pysplashsurf")
@pytest.mark.parametrize("mode", ["single", "clips"])
def test_blender_imports_the_surface_mesh_with_a_changing_vertex_count(tmp_path, mode):
    """/World/FluidSurface (run --surface --surface-every 2) is a mesh in Blender whose vertex
    count follows the cache's frame by frame, the mesh of frame 2k held at frame 2k + 1."""
    scene = tmp_path / "tank.json"
    scene.write_text(json.dumps(tank_scene(radius=0.03, block=(0.2, 0.3, 0.2), output={"fps": 25, "frames": 4})))
    out = tmp_path / ("tank.usdc" if mode == "single" else "tank.usda")
    extra = ["--clips"] if mode == "clips" else []
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet", "--surface",
                 "--surface-every", "2"] + extra) == 0
    result = subprocess.run([blender_python(), str(TOOL), str(out), "--frames", "0", "1", "2", "3", "4"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout[result.stdout.index("{"):])
    assert report["objects"].get("FluidSurface") == "MESH"
    stage = Usd.Stage.Open(str(out))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/World/FluidSurface")).GetPointsAttr()
    counts = {f: report["frames"][str(f)]["surface"]["vertices"] for f in range(5)}
    assert counts == {f: len(points.Get(f - f % 2)) for f in range(5)}
    assert len({counts[0], counts[2], counts[4]}) > 1  # the topology changes from frame to frame
    assert all(report["frames"][str(f)]["surface"]["triangles"] == report["frames"][str(f)]["surface"]["polygons"]
               for f in range(5))
    assert "velocity" in report["frames"]["0"]["surface"]["attributes"]


# Blender 5.0.1 and the stage's frame rate (#42). Its USD import sets the scene's frame range from the stage's
# start and end time codes and shows time code k at Blender frame k, whatever the rates; it never reads
# timeCodesPerSecond or framesPerSecond (bpy's __init__.so calls neither, and a stage with only one of them, or
# both, at 30 imports at 24 all the same), so the scene keeps the fps it had (24 in the factory settings).
# Nothing warpsph can write changes that: the USD import hook below (bpy.types.USDHook.on_import, the
# add-on examples/blender_usd_frame_rate.py) sets scene.render.fps / fps_base from the stage.
FPS_PROBE = r'''
import json, os, sys
import bpy

try:
    import pxr  # noqa: F401
except ImportError:  # bpy as a Python module: Blender's own USD bindings (the hook's stage) are not on sys.path
    sys.path.append(os.path.join(bpy.utils.resource_path("LOCAL"), "python", "lib",
                                 "python%d.%d" % sys.version_info[:2], "site-packages"))


hook = {"__name__": "warpsph_blender_usd_frame_rate"}  # the shipped add-on (examples/blender_usd_frame_rate.py)
exec(open(sys.argv[2]).read(), hook)
WarpsphSceneRate = hook["WarpsphSceneRate"]


def imported(path, hook):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if hook:
        bpy.utils.register_class(WarpsphSceneRate)
    try:
        if "FINISHED" not in bpy.ops.wm.usd_import(filepath=path):
            raise SystemExit("Blender could not import " + path)
    finally:
        if hook:
            bpy.utils.unregister_class(WarpsphSceneRate)
    scene = bpy.context.scene
    entry = {"fps": scene.render.fps, "fps_base": scene.render.fps_base, "frame_start": scene.frame_start,
             "frame_end": scene.frame_end, "first_point_y": {}}
    cloud = next(o for o in bpy.data.objects if o.type == "POINTCLOUD")
    for frame in (scene.frame_start, (scene.frame_start + scene.frame_end) // 2, scene.frame_end):
        scene.frame_set(frame)
        data = cloud.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        entry["first_point_y"][str(frame)] = data.attributes["position"].data[0].vector[1]
    return entry


path = sys.argv[1]
print(json.dumps({"blender": bpy.app.version_string, "plain": imported(path, False), "hook": imported(path, True)}))
'''


def blender_rates(cache):
    """What Blender makes of ``cache``'s frame rate and range, without and with the import hook."""
    addon = Path(__file__).resolve().parents[1] / "examples" / "blender_usd_frame_rate.py"
    result = subprocess.run([blender_python(), "-c", FPS_PROBE, str(cache), str(addon)], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout[result.stdout.index('{"blender"'):])


@pytest.mark.skipif(blender_python() is None,
                    reason="Blender as a Python module is absent: pip install bpy==5.0.1 in a Python 3.11 "
                           "environment and set WARPSPH_BLENDER_PYTHON to its python")
@pytest.mark.parametrize("fps, mode", [(25, "single"), (30, "clips"), (29.97, "single")])
def test_blender_frame_range_follows_the_cache_and_the_hook_sets_its_fps(tmp_path, fps, mode):
    frames = 4
    scene = tmp_path / "tank.json"
    scene.write_text(json.dumps(tank_scene(radius=0.04, output={"fps": fps, "frames": frames})))
    out = tmp_path / ("tank.usdc" if mode == "single" else "tank.usda")
    extra = ["--clips"] if mode == "clips" else []
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet"] + extra) == 0
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == pytest.approx(fps) and stage.GetFramesPerSecond() == pytest.approx(fps)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, frames)
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr()
    seen = blender_rates(out)
    for how in ("plain", "hook"):
        entry = seen[how]
        assert (entry["frame_start"], entry["frame_end"]) == (0, frames)  # the range follows the cache
        for frame, y in entry["first_point_y"].items():  # Blender frame k shows time code k
            assert y == pytest.approx(points.Get(int(frame))[0][1], rel=1e-6)
        assert len({round(y, 6) for y in entry["first_point_y"].values()}) == 3  # the particles move
    # Blender 5.0.1 leaves the scene's fps alone (its factory 24): if this fails, Blender reads the stage's
    # rate now and docs/output.md and docs/notes/renderers.md should say so.
    assert seen["plain"]["fps"] / seen["plain"]["fps_base"] == 24
    assert seen["hook"]["fps"] / seen["hook"]["fps_base"] == pytest.approx(fps, rel=1e-6)
    assert seen["hook"]["fps"] == round(fps)
