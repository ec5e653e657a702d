"""USD point caches (usd-core): one ``UsdGeom.Points`` prim with time-sampled particles.

Layout of the stage (``metersPerUnit`` = 1, ``upAxis`` from the scene,
``timeCodesPerSecond`` = output fps, frame k at time code k):

- ``/World/Fluid`` (Points): time-sampled ``points``, ``velocities`` [m/s], ``ids``
  (int64, stable across re-sorting), ``widths`` (diameter), ``extent``, and one primvar
  per published field (``density``; with a turbulence model ``vorticity`` (float3) and
  ``vorticity_magnitude``; micropolar ``angular_velocity``);
- ``/World/Boundary`` (Points, purpose ``guide``): the static boundary samples, written
  once without time samples.

The layer is saved after every frame, so a run that stops early leaves a readable file
holding the frames done.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

_PRIMVAR_TYPES = {1: Sdf.ValueTypeNames.FloatArray, 3: Sdf.ValueTypeNames.Float3Array}


class UsdPointCache:
    """Writes frames into ``path``; ``append=True`` reopens an existing cache to continue it."""

    def __init__(self, path, fps, up_axis="Y", boundary_points=None, boundary_radius=None, append=False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._primvars = {}
        self.frames = 0
        if append:
            self.stage = Usd.Stage.Open(str(self.path))
            self.points = UsdGeom.Points(self.stage.GetPrimAtPath("/World/Fluid"))
            api = UsdGeom.PrimvarsAPI(self.points.GetPrim())
            self._primvars = {pv.GetPrimvarName(): pv for pv in api.GetPrimvars()}
            return
        if self.path.exists():
            self.path.unlink()
        self.stage = Usd.Stage.CreateNew(str(self.path))
        stage = self.stage
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(0)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        self.points = UsdGeom.Points.Define(stage, "/World/Fluid")
        if boundary_points is not None and len(boundary_points):
            boundary = UsdGeom.Points.Define(stage, "/World/Boundary")
            boundary.CreatePurposeAttr(UsdGeom.Tokens.guide)
            boundary.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(boundary_points, np.float32)))
            boundary.CreateWidthsAttr(Vt.FloatArray.FromNumpy(
                np.full(len(boundary_points), 2.0 * boundary_radius, np.float32)))
            boundary.CreateExtentAttr(_extent(boundary_points))

    def write_frame(self, frame, points, velocities, ids, radius, fields=None):
        """Writes one frame at time code ``frame`` and saves the layer."""
        p = self.points
        t = Usd.TimeCode(frame)
        points = np.ascontiguousarray(points, np.float32)
        p.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points), t)
        p.GetVelocitiesAttr().Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(velocities, np.float32)), t)
        p.GetIdsAttr().Set(Vt.Int64Array.FromNumpy(np.ascontiguousarray(ids, np.int64)), t)
        p.GetWidthsAttr().Set(Vt.FloatArray.FromNumpy(np.full(len(points), 2.0 * radius, np.float32)), t)
        p.GetExtentAttr().Set(_extent(points, radius), t)
        for name, values in (fields or {}).items():
            values = np.ascontiguousarray(values, np.float32)
            width = 1 if values.ndim == 1 else values.shape[1]
            if name not in self._primvars:
                api = UsdGeom.PrimvarsAPI(p.GetPrim())
                self._primvars[name] = api.CreatePrimvar(name, _PRIMVAR_TYPES[width], UsdGeom.Tokens.vertex)
            array = Vt.FloatArray.FromNumpy(values) if width == 1 else Vt.Vec3fArray.FromNumpy(values)
            self._primvars[name].Set(array, t)
        self.stage.SetEndTimeCode(max(frame, self.stage.GetEndTimeCode()))
        self.stage.GetRootLayer().Save()
        self.frames += 1


def _extent(points, pad=0.0):
    if len(points) == 0:
        return Vt.Vec3fArray([Gf.Vec3f(0.0), Gf.Vec3f(0.0)])
    lo = np.asarray(points).min(axis=0) - pad
    hi = np.asarray(points).max(axis=0) + pad
    return Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])


def frame_writer(cache: UsdPointCache):
    """An ``on_frame`` callback for :meth:`Simulation.run` that writes every frame to ``cache``."""

    def on_frame(sim, frame):
        f = sim.fluid
        fields = {name: a.numpy() for name, a in sim.fields().items()}
        if "vorticity" in fields:
            fields["vorticity_magnitude"] = np.linalg.norm(fields["vorticity"], axis=1)
        cache.write_frame(frame, f.x.numpy(), f.v.numpy(), f.ids.numpy(), sim.scene.particle_radius, fields)

    return on_frame
