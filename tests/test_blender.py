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
