"""Surface meshes of the fluid (``warpsph run --surface``, ``warpsph surface``), with splashsurf.

Reconstruction runs `pysplashsurf <https://github.com/InteractiveComputerGraphics/splashsurf>`_
(pinned 0.14.1.0, the optional extra ``warpsph[surface]``) on one frame's particles on the host:
an SPH "colour field" (cubic spline kernel) sampled on a marching-cubes grid, the iso surface at
``iso``, then splashsurf's post-processing. The defaults are splashsurf's recommendations for
particles of radius r sampled 2 r apart with a cubic kernel of support 4 r:

- ``smoothing`` 2.0: smoothing length 2 r (kernel support 4 r), in multiples of the radius;
- ``cube`` 0.75: marching-cubes cell of 0.75 r (0.5 r is finer and about 2x slower, 3x the triangles);
- ``iso`` 0.6: the colour-field threshold;
- mesh cleanup (Moore & Warren), 25 iterations of weighted Laplacian smoothing (Löschner et al.
  2023) and vertex normals smoothed 10 times.

pysplashsurf 0.14.1.0 reads ``smoothing_length`` and ``cube_size`` as *multiples of the particle
radius* (its ``reconstruct_surface`` docstring says absolute units); warpsph passes multiples and
tests it (a sphere's mesh keeps the sphere's radius, its edges are about ``cube`` r long).

Per vertex the mesh carries the particles' velocity interpolated with the SPH kernel (for motion
blur: USD ``velocities``) and, when the frame has a vorticity field (a turbulence model runs),
the vorticity magnitude (a primvar for shading foam and detail).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .errors import SceneError

PYSPLASHSURF = "0.14.1.0"
INSTALL_HINT = f"pip install 'warpsph[surface]' (pysplashsurf=={PYSPLASHSURF})"


@dataclass(frozen=True)
class SurfaceOptions:
    """Reconstruction parameters; ``smoothing`` and ``cube`` in multiples of the particle radius."""

    cube: float = 0.75
    smoothing: float = 2.0
    iso: float = 0.6
    smoothing_iters: int = 25
    normals_iters: int = 10
    cleanup: bool = True

    def check(self, prefix="--"):
        """Raises :class:`SceneError` naming the option when a value is out of range."""
        if not (np.isfinite(self.cube) and self.cube > 0):
            raise SceneError("", f"{prefix}cube", f"expected a marching-cubes cell size > 0 (in particle radii, "
                                                  f"e.g. 0.5 to 0.75), got {self.cube}")
        if not (np.isfinite(self.smoothing) and self.smoothing > 0):
            raise SceneError("", f"{prefix}smoothing", f"expected a smoothing length > 0 (in particle radii, "
                                                       f"e.g. 2.0), got {self.smoothing}")
        if not (np.isfinite(self.iso) and self.iso > 0):
            raise SceneError("", f"{prefix}iso", f"expected an iso threshold > 0 (e.g. 0.6), got {self.iso}")
        return self


@dataclass
class SurfaceMesh:
    """A triangle mesh: ``points`` (V, 3) float32, ``faces`` (F, 3) int32, ``normals`` and
    ``velocities`` (V, 3) float32 (velocities None when not asked), ``primvars`` {name: (V,) or
    (V, 3) float32}; ``seconds`` the reconstruction's wall time."""

    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    velocities: np.ndarray | None = None
    primvars: dict = field(default_factory=dict)
    seconds: float = 0.0

    @staticmethod
    def empty(velocities=True):
        z = np.zeros((0, 3), np.float32)
        return SurfaceMesh(z, np.zeros((0, 3), np.int32), z.copy(), z.copy() if velocities else None)


def require_pysplashsurf(option="--surface"):
    """The pysplashsurf module, or a :class:`SceneError` naming ``option`` that says how to install it."""
    try:
        import pysplashsurf
    except ImportError:
        raise SceneError("", option, f"surface meshes need pysplashsurf, which is not installed: {INSTALL_HINT}") from None
    return pysplashsurf


def reconstruct(points, radius, velocities=None, vorticity=None, options=SurfaceOptions(), threads=True):
    """The surface mesh of particles at ``points`` (N, 3) of radius ``radius`` [m].

    ``velocities`` (N, 3): interpolated to the vertices; ``vorticity`` (N, 3) or its magnitude (N,):
    its magnitude interpolated as the primvar ``vorticity_magnitude``. ``threads``: splashsurf's
    own multi-threading (rayon; it releases the GIL)."""
    ps = require_pysplashsurf()
    start = time.perf_counter()
    points = np.ascontiguousarray(points, np.float32)
    if len(points) == 0:
        mesh = SurfaceMesh.empty(velocities is not None)
        if vorticity is not None:
            mesh.primvars["vorticity_magnitude"] = np.zeros(0, np.float32)
        return mesh
    attributes = {}
    if velocities is not None:
        attributes["velocity"] = np.ascontiguousarray(velocities, np.float32)
    if vorticity is not None:
        vorticity = np.asarray(vorticity, np.float32)
        magnitude = np.linalg.norm(vorticity, axis=1) if vorticity.ndim == 2 else vorticity
        attributes["vorticity_magnitude"] = np.ascontiguousarray(magnitude, np.float32)
    result, _ = ps.reconstruction_pipeline(
        points, attributes_to_interpolate=attributes or None, particle_radius=float(radius),
        smoothing_length=float(options.smoothing), cube_size=float(options.cube),  # multiples of the radius in 0.14.1
        iso_surface_threshold=float(options.iso), multi_threading=threads, subdomain_grid=True,
        mesh_cleanup=options.cleanup, mesh_smoothing_weights=True, mesh_smoothing_iters=options.smoothing_iters or None,
        compute_normals=True, normals_smoothing_iters=options.normals_iters or None)
    tri = result.mesh
    data = result.point_attributes
    vertices = np.ascontiguousarray(tri.vertices, np.float32)
    normals = data.get("normals")
    normals = (np.ascontiguousarray(normals, np.float32) if normals is not None
               else np.zeros_like(vertices))
    mesh = SurfaceMesh(vertices, np.ascontiguousarray(tri.triangles, np.int32), normals)
    if velocities is not None:
        mesh.velocities = np.ascontiguousarray(data["velocity"], np.float32)
    if vorticity is not None:
        mesh.primvars["vorticity_magnitude"] = np.ascontiguousarray(data["vorticity_magnitude"], np.float32).ravel()
    mesh.seconds = time.perf_counter() - start
    return mesh


def mesh_volume(points, faces):
    """The signed volume a closed, outward-oriented triangle mesh encloses (divergence theorem)."""
    p = np.asarray(points, np.float64)
    a, b, c = (p[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def boundary_edges(faces):
    """The number of edges used by one face only (0 for a closed mesh)."""
    f = np.asarray(faces, np.int64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


# ---------------------------------------------------------------------------------------------
# warpsph surface CACHE: re-mesh a finished run without simulating it again


def _sibling_usd(h5_path):
    """The USD cache beside OUT.particles.h5 (OUT.usdc, .usda or .usd), or None."""
    from pathlib import Path

    h5_path = Path(h5_path)
    stem = h5_path.name[: -len(".particles.h5")] if h5_path.name.endswith(".particles.h5") else h5_path.stem
    for suffix in (".usdc", ".usda", ".usd"):
        candidate = h5_path.with_name(stem + suffix)
        if candidate.is_file():
            return candidate
    return None


class UsdFrames:
    """The particle frames of a USD point cache (single file or the top-level file of --clips)."""

    def __init__(self, path):
        from pxr import Usd

        self.path = path
        try:
            self.stage = Usd.Stage.Open(str(path))
        except Exception:
            self.stage = None
        prim = self.stage.GetPrimAtPath("/World/Fluid") if self.stage is not None else None
        if prim is None or not prim.IsValid() or not prim.GetAttribute("points").GetTimeSamples():
            raise SceneError(path, "", "not a warpsph point cache (no time-sampled /World/Fluid points) "
                                       "nor a --particles-h5 file")
        self.prim = prim
        self.frames = [int(round(t)) for t in prim.GetAttribute("points").GetTimeSamples()]
        self.fps = self.stage.GetTimeCodesPerSecond()
        widths = prim.GetAttribute("widths")
        value = widths.Get(self.frames[0]) if widths else None
        self.radius = float(value[0]) / 2.0 if value is not None and len(value) else None
        self.usd = path

    def read(self, frame):
        """(points, velocities or None, vorticity magnitude or None) of ``frame``."""
        get = lambda name: self.prim.GetAttribute(name).Get(frame) if self.prim.GetAttribute(name) else None  # noqa: E731
        points = np.asarray(get("points"), np.float32)
        velocities, vorticity = get("velocities"), get("primvars:vorticity_magnitude")
        if vorticity is None:
            vorticity = get("primvars:vorticity")
        return (points, None if velocities is None else np.asarray(velocities, np.float32),
                None if vorticity is None else np.asarray(vorticity, np.float32))


class H5Frames:
    """The particle frames of a ``--particles-h5`` file (x, v and vorticity per frame)."""

    def __init__(self, path):
        import h5py

        self.path = path
        self.file = h5py.File(path, "r")
        self.group = self.file["frames"]
        self.frames = sorted(int(name) for name in self.group)
        if not self.frames:
            raise SceneError(path, "", "holds no frames")
        self.usd = _sibling_usd(path)
        self.radius, self.fps = None, None
        if self.usd is not None:
            try:
                cache = UsdFrames(self.usd)
                self.radius, self.fps = cache.radius, cache.fps
            except SceneError:
                self.usd = None
        if self.fps is None:
            last = self.group[f"{self.frames[-1]:06d}"]
            t = float(last.attrs.get("time", 0.0))
            self.fps = self.frames[-1] / t if t > 0 else 25.0

    def read(self, frame):
        g = self.group[f"{frame:06d}"]
        return (g["x"][...], g["v"][...] if "v" in g else None, g["vorticity"][...] if "vorticity" in g else None)


def open_frames(path):
    """The frames of a USD cache or of a ``--particles-h5`` file; :class:`SceneError` otherwise."""
    from pathlib import Path

    from .io.particles_h5 import is_particles_h5

    path = Path(path)
    if not path.is_file():
        raise SceneError(path, "", "no such file (expected a warpsph USD cache or OUT.particles.h5)")
    if is_particles_h5(path):
        return H5Frames(path)
    return UsdFrames(path)


def default_output(path):
    """CACHE.surface.usdc beside the cache (OUT.particles.h5 -> OUT.surface.usdc)."""
    from pathlib import Path

    path = Path(path)
    stem = path.name[: -len(".particles.h5")] if path.name.endswith(".particles.h5") else path.stem
    return path.with_name(stem + ".surface.usdc")


def plan_remesh(cache, frames=None, out=None, radius=None, overwrite=False, options=SurfaceOptions()):
    """Checks everything before anything is written: returns (source, frame list, output path,
    radius). Raises :class:`SceneError` naming the option at fault."""
    import os
    from pathlib import Path

    from .io.usd import written_by_warpsph

    options.check("--")
    require_pysplashsurf("surface")
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise SceneError("", "--radius", f"expected a particle radius > 0 in metres, got {radius}")
    source = open_frames(cache)
    if frames is not None:
        first, last = frames
        known = set(source.frames)
        if first > last or first not in known or last not in known:
            raise SceneError(cache, "--frames", f"unknown frame range {first}..{last}; the cache holds frames "
                                                f"{source.frames[0]}..{source.frames[-1]}")
        chosen = [f for f in source.frames if first <= f <= last]
    else:
        chosen = list(source.frames)
    radius = radius if radius is not None else source.radius
    if radius is None:
        raise SceneError(cache, "--radius", "the particle radius is not in this file (no widths, no OUT.usdc "
                                            "beside it): pass --radius R in metres")
    out = Path(out) if out is not None else default_output(cache)
    if out.suffix.lower() not in (".usdc", ".usda", ".usd"):
        raise SceneError(out, "--out", "expected a file name ending in .usdc, .usda or .usd")
    if out.resolve() == Path(cache).resolve() or (source.usd is not None and out.resolve() == Path(source.usd).resolve()):
        raise SceneError(out, "--out", "is the input cache; the mesh goes into a new file (it sublayers the input)")
    if out.is_dir():
        raise SceneError(out, "--out", "is a directory")
    if out.exists():
        if not written_by_warpsph(out):
            raise SceneError(out, "--out", "exists and was not written by warpsph: refusing to replace it")
        if not overwrite:
            raise SceneError(out, "--out", "exists; pass --overwrite to replace it, or choose another --out")
    parent = out.absolute().parent
    if parent.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise SceneError(out, "--out", f"cannot write in {parent}")
    return source, chosen, out, radius


def remesh(source, frames, out, radius, options=SurfaceOptions(), log=None):
    """Meshes ``frames`` of ``source`` (:func:`open_frames`) into the new layer ``out``: stage
    metadata of the cache, the cache itself as a sublayer (so ``out`` shows the particles and the
    surface), and ``/World/FluidSurface``. Saved after every frame (as OUT.partial, renamed at the
    end or when stopped). Returns {"frames", "seconds" (meshing), "vertices", "triangles"}."""
    import os

    from pxr import Usd, UsdGeom

    from .io.usd import _mark, _set_stage_metadata, write_surface

    partial = out.with_name(out.stem + ".partial" + out.suffix)
    if partial.exists():
        partial.unlink()
    stage = Usd.Stage.CreateNew(str(partial))
    layer = stage.GetRootLayer()
    _mark(layer)
    up = "Y"
    if source.usd is not None:
        base = Usd.Stage.Open(str(source.usd))
        up = "Z" if UsdGeom.GetStageUpAxis(base) == UsdGeom.Tokens.z else "Y"
        layer.subLayerPaths.append(os.path.relpath(os.path.abspath(source.usd), os.path.abspath(out.parent)))
    _set_stage_metadata(stage, source.fps, up)
    stage.SetStartTimeCode(frames[0])
    stage.SetEndTimeCode(frames[-1])
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    done = {"frames": 0, "seconds": 0.0, "vertices": 0, "triangles": 0}
    try:
        for frame in frames:
            points, velocities, vorticity = source.read(frame)
            mesh = reconstruct(points, radius, velocities, vorticity, options)
            write_surface(stage, frame, mesh)
            layer.Save()
            done["frames"] += 1
            done["seconds"] += mesh.seconds
            done["vertices"] += len(mesh.points)
            done["triangles"] += len(mesh.faces)
            if log is not None:
                log(f"frame {frame}: {len(points)} particles -> {len(mesh.points)} vertices, {len(mesh.faces)} triangles "
                    f"in {mesh.seconds:.2f} s")
    finally:
        layer.Save()
        del stage, layer
        if done["frames"]:
            os.replace(partial, out)
        elif partial.exists():
            partial.unlink()
    return done
