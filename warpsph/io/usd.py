"""USD point caches (usd-core): one ``UsdGeom.Points`` prim with time-sampled particles.

Layout of the stage (``metersPerUnit`` = 1, ``upAxis`` from the scene,
``timeCodesPerSecond`` = output fps, frame k at time code k):

- ``/World/Fluid`` (Points): time-sampled ``points``, ``velocities`` [m/s], ``ids``
  (int64, stable across re-sorting), ``widths`` (diameter), ``extent``, and one primvar
  per published field (``density``; with a turbulence model ``vorticity`` (float3) and
  ``vorticity_magnitude``; micropolar ``angular_velocity``), float/float3 only;
- ``/World/FluidSurface`` (Mesh, ``--surface``): the fluid's surface from splashsurf
  (:mod:`warpsph.surface`), time-sampled ``points``, ``faceVertexCounts`` (all 3),
  ``faceVertexIndices``, ``normals`` (vertex), ``extent``, ``velocities`` (interpolated from the
  particles) and, with a turbulence model, the primvar ``vorticity_magnitude``;
  ``subdivisionScheme`` "none"; the vertex count changes from frame to frame. Meshed in the
  background (``--surface-every K``, frames skipped by ``--surface-behind skip``), a frame
  without its own sample holds the last mesh before it (USD holds arrays of a different length;
  value clips interpolate missing values), and the layer's customLayerData ``warpsph:surface``
  says how it was meshed and which frames were skipped; a SPlisHSPlasH scene run anyway has
  ``warpsph:import_dropped`` there, the physics the run leaves out (:func:`run_metadata`), and
  every cache has ``warpsph:domain`` there (min, max, periodic, walls: ``warpsph surface`` clips
  its meshes to the walls);
- ``/World/Boundary`` (Points, purpose ``guide``): the static boundary samples, written
  once without time samples;
- ``/World/Bodies/NAME`` (Mesh), one per obstacle, in metres: a static body in world space; a
  moving one in body space with time-sampled ``xformOp:translate`` and ``xformOp:orient``, so
  a renderer shows the rod, propeller, blocks or boat moving with the fluid.

Two writers with one interface (``write_frame``, ``finish``):

- :class:`UsdPointCache`, a single file, saved crash-consistently (the new frames appended to a working
  copy, synced and renamed over the file: a kill or power cut at any moment leaves the frames of the last
  save, :class:`GrowingLayer`) after every frame, or with ``flush_share`` (the CLI, :class:`UsdWriter`) when
  a save costs at most that share of the time since the last one, at a checkpoint and at the end;
- :class:`UsdClipCache`, one layer per frame stitched with USD value clips
  (``UsdUtils.StitchClips``: a topology layer with the prim and attribute declarations, a
  manifest, and a small top-level file), for large runs: the writer holds one frame at a time.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import time
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdUtils, Vt

from warpsph.io.files import fsync
from .processes import load_tree, start_workers, stop_workers, store_tree
from .splishsplash import dropped

_PRIMVAR_TYPES = {1: Sdf.ValueTypeNames.FloatArray, 3: Sdf.ValueTypeNames.Float3Array}
GENERATOR = "warpsph"  # customLayerData["generator"] of every layer warpsph writes: --overwrite replaces only these
IMPORT_DROPPED = "warpsph:import_dropped"


def run_metadata(scene) -> dict:
    """The customLayerData a run's cache records about its scene: ``warpsph:import_dropped``, each part
    of a SPlisHSPlasH scene run anyway that the run leaves out ("key: what it would have changed"),
    when there is one."""
    items = dropped(scene)
    return {IMPORT_DROPPED: items} if items else {}


def _note_metadata(layer, metadata):
    if metadata:
        values = {k: Vt.StringArray(list(v)) if isinstance(v, (list, tuple)) else v for k, v in metadata.items()}
        layer.customLayerData = {**layer.customLayerData, **values}


def _mark(layer):
    layer.customLayerData = {**layer.customLayerData, "generator": GENERATOR}


DOMAIN = "warpsph:domain"  # the scene's domain box, for clipping surface meshes to its walls (warpsph surface, #42)


def domain_record(domain):
    """The scene's ``domain`` (a ``Box``) as plain values: {"min", "max", "periodic" ("xz"), "walls"}."""
    return {"min": [float(v) for v in domain.min], "max": [float(v) for v in domain.max],
            "periodic": "".join(domain.periodic), "walls": bool(domain.walls)}


def _note_domain(layer, record):
    """``warpsph:domain`` in the layer's customLayerData (``record``: :func:`domain_record`)."""
    if record:
        layer.customLayerData = {**layer.customLayerData, DOMAIN: {
            "min": Vt.DoubleArray(list(record["min"])), "max": Vt.DoubleArray(list(record["max"])),
            "periodic": str(record["periodic"]), "walls": bool(record["walls"])}}


def written_by_warpsph(path):
    """Whether ``path`` is a USD layer that warpsph wrote (marked, or an unmarked point cache of
    earlier versions: default prim World holding the Points prim /World/Fluid)."""
    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
    except Exception:  # pxr raises Tf.ErrorException for files that are not USD
        return False
    if layer is None:
        return False
    if layer.customLayerData.get("generator") == GENERATOR:
        return True
    fluid = layer.GetPrimAtPath("/World/Fluid")
    return layer.defaultPrim == "World" and fluid is not None and fluid.typeName == "Points"


def _set_stage_metadata(stage, fps, up_axis):
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)


def _define_boundary(stage, boundary_points, boundary_radius):
    if boundary_points is None or not len(boundary_points):
        return
    boundary = UsdGeom.Points.Define(stage, "/World/Boundary")
    boundary.CreatePurposeAttr(UsdGeom.Tokens.guide)
    boundary.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(boundary_points, np.float32)))
    boundary.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.full(len(boundary_points), 2.0 * boundary_radius, np.float32)))
    boundary.CreateExtentAttr(_extent(boundary_points))


def _define_bodies(stage, bodies):
    """Mesh prims for the bodies: ``bodies`` is a list of (name, vertices, faces, moving)."""
    for name, vertices, faces, moving in bodies or ():
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Bodies/{name}")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(vertices, np.float32)))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, np.int32).ravel()))
        mesh.CreateExtentAttr(_extent(vertices))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        if moving and not mesh.GetPrim().GetAttribute("xformOp:translate"):  # clips declare their own
            mesh.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble)
            mesh.AddOrientOp(UsdGeom.XformOp.PrecisionFloat)


def _write_body_poses(stage, frame, poses):
    """Time samples of each moving body's transform: {name: (position, rotation matrix)}."""
    for name, (position, rotation) in (poses or {}).items():
        prim = stage.OverridePrim(f"/World/Bodies/{name}")
        xform = UsdGeom.Xformable(prim)
        translate = prim.GetAttribute("xformOp:translate")
        orient = prim.GetAttribute("xformOp:orient")
        if not translate:  # a clip layer: declare the ops it animates
            translate = xform.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).GetAttr()
            orient = xform.AddOrientOp(UsdGeom.XformOp.PrecisionFloat).GetAttr()
        translate.Set(Gf.Vec3d(*map(float, position)), Usd.TimeCode(frame))
        q = Gf.Matrix3d(*np.asarray(rotation, np.float64).T.ravel()).ExtractRotation().GetQuat()
        orient.Set(Gf.Quatf(q), Usd.TimeCode(frame))


SURFACE = "/World/FluidSurface"


def write_surface(stage, frame, mesh):
    """One frame's time samples of the surface mesh ``mesh`` (:class:`warpsph.surface.SurfaceMesh`)
    on ``/World/FluidSurface`` (defined on first use); returns the bytes of the arrays set."""
    prim = UsdGeom.Mesh.Define(stage, SURFACE)
    t = Usd.TimeCode(frame)
    if not prim.GetSubdivisionSchemeAttr().HasAuthoredValue():
        prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        prim.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    points = np.ascontiguousarray(mesh.points, np.float32)
    faces = np.ascontiguousarray(mesh.faces, np.int32)
    normals = np.ascontiguousarray(mesh.normals, np.float32)
    prim.CreatePointsAttr().Set(_vt_array(Vt.Vec3fArray, points), t)
    prim.CreateFaceVertexCountsAttr().Set(Vt.IntArray(len(faces), 3), t)
    prim.CreateFaceVertexIndicesAttr().Set(_vt_array(Vt.IntArray, faces.reshape(-1)), t)
    prim.CreateNormalsAttr().Set(_vt_array(Vt.Vec3fArray, normals), t)
    prim.CreateExtentAttr().Set(_extent(points), t)
    written = points.nbytes + faces.nbytes + 4 * len(faces) + normals.nbytes
    if mesh.velocities is not None:
        velocities = np.ascontiguousarray(mesh.velocities, np.float32)
        prim.CreateVelocitiesAttr().Set(_vt_array(Vt.Vec3fArray, velocities), t)
        written += velocities.nbytes
    api = UsdGeom.PrimvarsAPI(prim.GetPrim())
    for name, values in mesh.primvars.items():
        values = np.ascontiguousarray(values, np.float32)
        width = 1 if values.ndim == 1 else values.shape[1]
        primvar = api.GetPrimvar(name) or api.CreatePrimvar(name, _PRIMVAR_TYPES[width], UsdGeom.Tokens.vertex)
        primvar.Set(_vt_array(Vt.FloatArray if width == 1 else Vt.Vec3fArray, values), t)
        written += values.nbytes
    return written


_VT_ELEMENTS = {"Vec3fArray": (np.float32, 3), "FloatArray": (np.float32, None), "IntArray": (np.int32, None)}


def _vt_array(kind, values):
    """``values`` (C-contiguous, of ``kind``'s element type) as a new ``kind`` (Vt.Vec3fArray, FloatArray or
    IntArray), the same as ``kind.FromNumpy(values)``, which converts element by element holding the GIL
    (about 1.5 GB/s: 20 ms a 1.5M-vertex array of a 1M-particle frame's mesh, 50 ms its faces) while the
    simulation's host thread waits for it. Here numpy copies into the new array's storage with the GIL
    released: a Vt array's buffer is read-only to Python (arrays share storage until written), but a
    new array owns its storage alone. Falls back to FromNumpy where the buffer is not the storage itself."""
    import ctypes

    dtype, width = _VT_ELEMENTS[kind.__name__]
    shape = (len(values),) if width is None else (len(values), width)
    if values.dtype != dtype or values.shape != shape or not values.flags.c_contiguous or not len(values):
        return kind.FromNumpy(values)
    array = kind(len(values))
    view = np.asarray(array)
    address = view.ctypes.data
    if view.dtype != dtype or view.shape != shape or np.asarray(array).ctypes.data != address:
        return kind.FromNumpy(values)  # not a view of the array's own storage
    storage = np.frombuffer((ctypes.c_byte * view.nbytes).from_address(address), dtype).reshape(shape)
    np.copyto(storage, values)
    return array


def write_surface_layer(path, frame, mesh):
    """The surface mesh of frame ``frame`` into the existing frame layer ``path`` of a --clips cache
    (:meth:`UsdClipCache.write_surface`, or a mesher worker: :meth:`UsdClipCache.surface_layer`), saved whole
    through a temporary file and a rename (:func:`save_layer`): ``layer.Save()`` rewrote the frame's crate file in
    place, and a kill or a full disk during it left a frame layer, particles and all, that USD cannot open."""
    path = Path(path)
    _check_directory(path.parent)
    stage = Usd.Stage.Open(str(path))
    write_surface(stage, frame, mesh)
    save_layer(stage.GetRootLayer(), path)


def _write_points(points_prim, frame, points, velocities, ids, radius, fields, widths=True):
    """One frame's time samples on a Points prim; ``velocities`` or ``ids`` None: not written,
    ``widths`` False: not written. Returns the bytes of the arrays set."""
    p, t = points_prim, Usd.TimeCode(frame)
    points = np.ascontiguousarray(points, np.float32)
    written = points.nbytes
    p.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points), t)
    if velocities is not None:
        velocities = np.ascontiguousarray(velocities, np.float32)
        p.GetVelocitiesAttr().Set(Vt.Vec3fArray.FromNumpy(velocities), t)
        written += velocities.nbytes
    if ids is not None:
        ids = np.ascontiguousarray(ids, np.int64)
        p.GetIdsAttr().Set(Vt.Int64Array.FromNumpy(ids), t)
        written += ids.nbytes
    if widths:
        p.GetWidthsAttr().Set(Vt.FloatArray.FromNumpy(np.full(len(points), 2.0 * radius, np.float32)), t)
        written += 4 * len(points)
    p.GetExtentAttr().Set(_extent(points, radius), t)
    api = UsdGeom.PrimvarsAPI(p.GetPrim())
    for name, values in (fields or {}).items():
        values = np.ascontiguousarray(values, np.float32)
        width = 1 if values.ndim == 1 else values.shape[1]
        primvar = api.GetPrimvar(name)
        if not primvar:
            primvar = api.CreatePrimvar(name, _PRIMVAR_TYPES[width], UsdGeom.Tokens.vertex)
        primvar.Set(Vt.FloatArray.FromNumpy(values) if width == 1 else Vt.Vec3fArray.FromNumpy(values), t)
        written += values.nbytes
    return written


def temporary_path(path):
    """Where a save of ``path`` is written before it is renamed over ``path``: NAME.tmp.usdc beside it."""
    path = Path(path)
    return path.with_name(f"{path.stem}.tmp{path.suffix}")


def remove_leftovers(path):
    """Removes what a killed save of ``path`` left: NAME.tmp.usdc and USD's own NAME.tmp.XXXXXX."""
    path = Path(path)
    pattern = re.compile(re.escape(path.stem) + r"\.tmp\.(" + re.escape(path.suffix[1:]) + r"|[A-Za-z0-9]{6})")
    for p in path.parent.glob(f"{path.stem}.tmp.*") if path.parent.is_dir() else ():
        if pattern.fullmatch(p.name) and p.is_file():
            p.unlink()


@contextlib.contextmanager
def replacing(path, tmp):
    """The body writes ``tmp`` whole and synced; then ``tmp`` is renamed over ``path`` and the folder synced. On
    any failure (or a signal's exception) ``tmp`` is removed and ``path`` is as it was."""
    try:
        yield
        os.replace(tmp, path)
    except BaseException:
        if tmp.exists():
            tmp.unlink()
        raise
    fsync(path.parent)


def write_atomically(path, data):
    """``data`` (bytes) to ``path`` through NAME.tmp beside it, synced and renamed: ``path`` holds the old
    contents or the new, whole, at every moment."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with replacing(path, tmp), open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _npz_bytes(**arrays):
    import io

    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _write_failed(exc, path, tmp):
    """The OSError for a pxr ``Tf.ErrorException`` raised writing ``tmp`` (a save of ``path``): the file system's
    error among USD's lines; any other exception as it is."""
    if type(exc).__name__ != "ErrorException":
        return exc
    found = re.findall(r"Error occurred writing file: ([^'\n]*)", str(exc))
    return OSError(f"{path}: USD could not write {Path(tmp).name}"
                   + (f": {found[0]}" if found else f" ({str(exc).strip().splitlines()[0][:200]})"))


def save_layer(layer, path):
    """Saves ``layer`` to ``path`` crash-consistently: the whole layer to NAME.tmp.usdc, synced, renamed over
    ``path``, the folder synced. (``layer.Save()`` of a crate file read from ``path`` writes in place: the new
    values over the old table of contents, then the header; a kill or power cut between the two leaves a file
    USD cannot open.) ``path`` holds the old file or the new one, whole, at every moment."""
    path = Path(path)
    tmp = temporary_path(path)
    with replacing(path, tmp):
        try:
            written = layer.Export(str(tmp))
        except Exception as exc:  # pxr.Tf.ErrorException: the file system's error among USD's lines
            raise _write_failed(exc, path, tmp) from None
        if not written:
            raise OSError(f"{path}: USD could not write {tmp.name}")
        fsync(tmp)


class GrowingLayer:
    """A crate file that grows by saves, each crash-consistent and costing what it adds, not the whole file.

    ``layer.Export`` writes every value again (and re-encodes it: the integer compression of a 1M-face mesh's
    indices is 0.1-1 s), so a single file saved whole after each frame cost the whole run again at each save.
    Here the layer is the working copy NAME.tmp.usdc of ``path``: a save is ``layer.Save()`` in place (new
    values appended, a new table of contents), a sync, and a rename over ``path``; then the file is copied back to
    NAME.tmp.usdc (a copy in the kernel, no encoding) for the next save to grow. Between saves :meth:`append`
    encodes new values into the working copy as they come. ``path`` holds the last save, whole, at every moment:
    a kill during a save or an append damages only the working copy (a leftover the next run removes).
    On disk: ``path`` and its copy."""

    def __init__(self, path):
        self.path = Path(path).absolute()  # a layer's identifier is resolved again at each reload: not against a cwd
        self.tmp = temporary_path(self.path)
        self.failed = None  # the exception of a failed save
        self._appended = False  # the working copy holds values that ``path`` lacks
        self._copy()
        self.layer = Sdf.Layer.FindOrOpen(str(self.tmp))
        self.layer.Reload(True)  # a layer of this name still open in this process: the file anew

    def _copy(self):
        """``path`` copied to the working copy in the kernel (``copy_file_range``: a reflink, no data written, on
        file systems that share blocks, such as XFS and Btrfs), then synced: the next save's sync, often the
        last one at the end of a run, then writes only what that save adds."""
        import shutil

        try:
            with open(self.path, "rb") as src, open(self.tmp, "wb") as dst:
                size, done = os.fstat(src.fileno()).st_size, 0
                while done < size:
                    n = os.copy_file_range(src.fileno(), dst.fileno(), size - done)
                    if n == 0:
                        raise OSError(errno.EIO, f"{self.path}: copy_file_range stopped at {done} of {size} bytes")
                    done += n
                os.fsync(dst.fileno())
        except OSError as exc:
            if exc.errno not in (errno.EXDEV, errno.ENOSYS, errno.EOPNOTSUPP, errno.EINVAL):
                raise
            shutil.copyfile(self.path, self.tmp)  # a file system without copy_file_range
            with open(self.tmp, "rb") as copy:
                os.fsync(copy.fileno())

    def save(self, again=True):
        """Saves what the layer holds beyond ``path`` into ``path`` (``again`` False: the last save; no working
        copy is made for a next one); False when there was nothing to save. After a failed save (a full disk, a
        file-size limit) the working copy is gone and every later save raises: ``path`` keeps the save before."""
        if self.failed is not None:
            raise OSError(f"{self.path}: not saved since an earlier save failed ({self.failed})")
        if not (self.layer.dirty or self._appended):
            return False
        try:
            with replacing(self.path, self.tmp):
                self._save_in_place()
                fsync(self.tmp)
            self._appended = False
            if again:
                self._copy()
        except BaseException as exc:
            self.failed = exc
            if self.tmp.exists():  # half a copy, or a save's half-written values: never saved over ``path``
                self.tmp.unlink()
            raise
        return True

    def append(self):
        """Encodes what the layer holds beyond the working copy into it (``layer.Save()`` in place) and syncs it,
        without a rename: ``path`` is untouched, and the next :meth:`save` has only the last values to encode and
        sync (at the end of a run the final save encoded and synced every frame since the save before)."""
        if self.failed is not None or not self.layer.dirty:
            return
        try:
            self._save_in_place()
            with open(self.tmp, "rb") as copy:  # written to the disk now, beside the run, not at the next save
                os.fsync(copy.fileno())
        except BaseException as exc:
            self.failed = exc
            if self.tmp.exists():
                self.tmp.unlink()
            raise
        self._appended = True

    def _save_in_place(self):
        try:
            written = self.layer.Save()
        except Exception as exc:  # pxr.Tf.ErrorException: the file system's error among USD's lines
            raise _write_failed(exc, self.path, self.tmp) from None
        if not written:
            raise OSError(f"{self.path}: USD could not write {self.tmp.name}")

    def close(self):
        """Removes the working copy (``path`` holds the last save)."""
        if self.tmp.exists():
            self.tmp.unlink()


class DamagedCache(OSError):
    """A cache that USD cannot open (truncated by a full disk or a crash during a save), or one that cannot be
    continued; ``reason`` says why, without the path."""

    def __init__(self, path, cause=None, reason=None):
        if reason is None:
            first = str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__
            reason = (f"USD cannot open this cache ({first[:200]}); its frames cannot be recovered. Start the run "
                      "again (a --clips run keeps every frame's layer on its own)")
        self.path, self.reason = path, reason
        super().__init__(f"{path}: {self.reason}")

    def __reduce__(self):  # raised in the cache's writer process, re-raised in the run's
        return type(self), (self.path, None, self.reason)


def cache_frames(path):
    """The frames (time codes of /World/Fluid's points) of the single-file cache ``path``, the last one read;
    :class:`DamagedCache` when USD cannot open the file or read them."""
    try:
        stage = Usd.Stage.Open(str(path))
        points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr()
        frames = [int(t) for t in points.GetTimeSamples()]
        if frames and points.Get(frames[-1]) is None:
            raise ValueError(f"frame {frames[-1]} has no points")
    except Exception as exc:  # pxr.Tf.ErrorException: a truncated or damaged crate file
        raise DamagedCache(path, exc) from None
    return frames


def _spans(frames):
    """'frames 0..7', 'frames 0..3, 6..7', 'no frames' (``frames`` sorted)."""
    if not frames:
        return "no frames"
    runs, first = [], frames[0]
    for a, b in zip(frames, [*frames[1:], None]):
        if b != a + 1:
            runs.append(f"{first}..{a}" if a != first else f"{a}")
            first = b
    return "frames " + ", ".join(runs)


def recover_cache(out, partial, frame):
    """Before a resumed run continues a single-file cache after checkpoint frame ``frame``: the first of ``out``
    (a finished or stopped run's cache) and ``partial`` (a killed run's) that USD opens and that holds frames
    0..``frame`` is moved to ``partial``, where the run goes on, and a killed save's temporary files are
    removed; returns its frames. Neither: :class:`DamagedCache` saying what each copy lacks, with nothing
    changed (the checkpoint holds frame ``frame``'s state only: the frames before it cannot be computed again)."""
    out, partial = Path(out), Path(partial)
    problems = []
    for path in (out, partial):
        if not path.exists():
            continue
        try:
            frames = cache_frames(path)
        except DamagedCache as exc:
            problems.append(f"{path.name}: {exc.reason.split(';')[0]}")
            continue
        missing = sorted(set(range(frame + 1)) - set(frames))
        if not missing:
            remove_leftovers(partial)
            if path != partial:
                os.replace(path, partial)
                fsync(partial.parent)
            return frames
        problems.append(f"{path.name} holds {_spans(frames)}, not {_spans(missing)}")
    raise DamagedCache(out, reason=f"cannot continue after frame {frame}: {'; '.join(problems) or 'no cache'}; frames "
                                   f"0..{frame} cannot be recovered from the checkpoint (it holds frame {frame}'s state "
                                   "only): start the run again (warpsph run ... --overwrite)")


FLUSH_SHARE = 0.1  # the CLI's single-file cache: saves take at most this share of the writer's time


class UsdPointCache:
    """A single file that grows by crash-consistent saves (:class:`GrowingLayer`: the frames since the last
    save appended to a working copy, synced and renamed over the file): a kill or power cut at any moment leaves
    a cache that opens, with the frames of the last save. ``flush_share`` None saves after every frame; a number
    saves after a frame only when the last save took at most that share of the time since it began;
    :meth:`flush` (at a checkpoint), :meth:`note_surface` and :meth:`finish` save at once.
    ``append=K`` reopens an existing cache to continue it after frame K (later frames, from a run
    resumed before, are dropped: each frame once)."""

    def __init__(self, path, fps, up_axis="Y", boundary_points=None, boundary_radius=None, append=None, bodies=None,
                 metadata=None, domain=None, flush_share=None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        remove_leftovers(self.path)
        self.flush_share = flush_share
        self.flushes = 0  # saves so far
        self._flushed = (0.0, 0.0)  # (start, seconds) of the last save
        self.frames = 0
        self.written_bytes = 0  # of the particle arrays written (write_frame's returns)
        self._ids = None  # the ids and particle count of the last time samples written
        self._count = None
        self._last_written = 0
        if append is not None:
            try:
                self.file = GrowingLayer(self.path)
                self.stage = Usd.Stage.Open(self.file.layer)
            except Exception as exc:  # pxr.Tf.ErrorException: a truncated or damaged crate file
                raise DamagedCache(self.path, exc) from None
            self.points = UsdGeom.Points(self.stage.GetPrimAtPath("/World/Fluid"))
            for prim in self.stage.Traverse():
                for attr in prim.GetAttributes():
                    for t in attr.GetTimeSamples():
                        if t > append:
                            attr.ClearAtTime(t)
            self.stage.SetEndTimeCode(min(append, self.stage.GetEndTimeCode()))
            if domain is not None and DOMAIN not in self.stage.GetRootLayer().customLayerData:
                _note_domain(self.stage.GetRootLayer(), domain_record(domain))
            return
        if self.path.exists():
            self.path.unlink()
        stage = Usd.Stage.CreateInMemory()  # the file appears whole and marked
        _mark(stage.GetRootLayer())
        _note_metadata(stage.GetRootLayer(), metadata)
        _note_domain(stage.GetRootLayer(), domain_record(domain) if domain is not None else None)
        _set_stage_metadata(stage, fps, up_axis)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(0)
        stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
        UsdGeom.Points.Define(stage, "/World/Fluid")
        _define_boundary(stage, boundary_points, boundary_radius)
        _define_bodies(stage, bodies)
        save_layer(stage.GetRootLayer(), self.path)
        self.file = GrowingLayer(self.path)  # later frames are added to its working copy
        self.stage = Usd.Stage.Open(self.file.layer)
        self.points = UsdGeom.Points(self.stage.GetPrimAtPath("/World/Fluid"))

    def write_frame(self, frame, points, velocities, ids, radius, fields=None, body_poses=None, widths=True,
                    surface=None):
        """Writes one frame at time code ``frame`` and saves the layer when a save is due; returns the bytes
        of the arrays written. ``ids`` and widths get a time sample only when they differ from the last
        one (USD holds a sample until the next), so a cache in id order without emitters or sinks
        has them once; the first frame a run writes (or appends) always has them."""
        _check_directory(self.path.parent)
        size = self.path.stat().st_size if self.path.exists() else 0  # a save grows the file, then copies it again
        check_space(self.path.parent, frame, _frame_estimate(points, self._last_written) + size)
        count = len(points)
        if ids is not None:
            ids = np.asarray(ids)
            if self._ids is not None and np.array_equal(ids, self._ids):
                ids = None
            else:
                self._ids = ids.copy()
        widths = widths and count != self._count
        written = _write_points(self.points, frame, points, velocities, ids, radius, fields, widths)
        if surface is not None:
            write_surface(self.stage, frame, surface)  # not in the bytes of particle arrays returned
        _write_body_poses(self.stage, frame, body_poses)
        self.stage.SetEndTimeCode(max(frame, self.stage.GetEndTimeCode()))
        self._count = count
        self._last_written = written
        self.written_bytes += written
        self.frames += 1
        if self._due():
            self.flush()
        else:  # encoded now, beside the simulation, not all at the next save
            self.file.append()
        return written

    def _due(self):
        if self.flush_share is None:
            return True
        start, seconds = self._flushed
        return time.perf_counter() - start >= seconds / self.flush_share

    def flush(self, again=True):
        """Saves what is not on disk yet (:meth:`GrowingLayer.save`: the frames since the last save, appended;
        ``again`` False: the last save, no working copy for a next one)."""
        start = time.perf_counter()
        _check_directory(self.path.parent)
        if self.file.save(again):
            self._flushed = (start, time.perf_counter() - start)
            self.flushes += 1

    def surface_layer(self, frame):
        """None: the mesher's worker cannot write into this cache (see :meth:`UsdClipCache.surface_layer`)."""
        return None

    def write_surface(self, frame, mesh, save=False):
        """The surface mesh of frame ``frame``, meshed after the frame was written (the background
        mesher); saved with the next save, or with ``save`` when a save is due (:meth:`finish` saves the rest)."""
        if getattr(mesh, "layer", None) is not None:
            raise ValueError(f"the mesh of frame {frame} was written into {mesh.layer}, not into {self.path}")
        write_surface(self.stage, frame, mesh)
        if save and self._due():
            self.flush()

    def note_surface(self, info):
        """Records how the surface was meshed (method, every K-th frame, frames skipped) in the
        layer's metadata ``warpsph:surface`` (saved by :meth:`finish`, which follows)."""
        _note_surface(self.stage.GetRootLayer(), info)

    def finish(self, final_path):
        """The cache is complete up to its last frame: saves it and moves it to its final name (a save that fails
        raises after the move: the file holds the frames of the save before)."""
        try:
            self.flush(again=False)
        finally:
            self.file.close()
            if Path(final_path) != self.path and self.path.exists():
                os.replace(self.path, final_path)
                fsync(Path(final_path).parent)


class CacheProcess:
    """A cache (:class:`UsdPointCache`, same calls and attributes) written by a process of its own.

    pxr holds the GIL for the whole of each call: the arrays' conversion, the encoding of a save (a 1M-face mesh's
    indices: 0.1-1 s of integer compression), which the simulation's host thread, launching the GPU's work, needs
    for every step. Here the run's process writes each call's arrays to files (/dev/shm, one system call each,
    outside the GIL: :mod:`warpsph.io.processes`) and waits, outside the GIL too, for the writer process, which
    owns the cache and makes the call. The caller (the run's writer thread) gets what the call returns or raises,
    as from the cache itself; the simulation goes on stepping meanwhile. The writer process ignores SIGINT and
    SIGTERM (the run saves and stops it) and exits when the run's process dies: the file keeps its last save, as
    with a cache in the run's process. :meth:`finish` stops it."""

    def __init__(self, kind, *args, **kwargs):
        from itertools import count

        self.path = Path(args[0] if args else kwargs["path"])
        self._jobs = count()
        self._state = {"frames": 0, "flushes": 0, "written_bytes": 0, "flush_share": kwargs.get("flush_share")}
        self.folder, self._remove, self.pool = start_workers(self, 1, prefix="warpsph-writer")
        try:
            self._call("open", kind, args, kwargs)
        except BaseException:
            self._stop()
            raise

    def __getattr__(self, name):
        state = self.__dict__.get("_state", {})
        if name in state:
            return state[name]
        raise AttributeError(name)

    def _call(self, method, *args):
        import shutil
        from concurrent.futures.process import BrokenProcessPool

        job = os.path.join(self.folder, str(next(self._jobs)))
        os.mkdir(job)
        try:
            result, self._state = self.pool.submit(_cache_call, method, store_tree(args, job)).result()
        except BrokenProcessPool:
            raise OSError(f"{self.path}: the cache's writer process ended during {method} (killed?); the file "
                          "holds the frames of its last save") from None
        finally:
            shutil.rmtree(job, ignore_errors=True)
        return result

    def _stop(self):
        if self.pool is not None:
            stop_workers(self.pool, self._remove)
            self.pool = None

    def write_frame(self, *args, **kwargs):
        return self._call("write_frame", args, kwargs)

    def write_surface(self, frame, mesh, save=False):
        mesh.wait() if hasattr(mesh, "wait") else None  # a Warp event does not cross processes
        return self._call("write_surface", (frame, mesh, save), {})

    def surface_layer(self, frame):
        """None: the mesher writes its meshes through this cache (:meth:`UsdPointCache.surface_layer`)."""
        return None

    def flush(self, again=True):
        return self._call("flush", (again,), {})

    def note_surface(self, info):
        return self._call("note_surface", (info,), {})

    def finish(self, final_path):
        """Saves, moves the file to ``final_path`` (:meth:`UsdPointCache.finish`) and stops the writer process."""
        try:
            return self._call("finish", (final_path,), {})
        finally:
            self._stop()


_worker_cache = None  # the writer process's cache (CacheProcess)


def _cache_call(method, args):
    """In the writer process: ``open`` makes the cache (``args``: its class, arguments, keyword arguments); any
    other ``method`` is called on it with ``args`` (positional, keyword), the arrays read back from their files.
    Returns (the call's result, the cache's counters)."""
    global _worker_cache
    args = load_tree(args)
    if method == "open":
        kind, positional, keywords = args
        _worker_cache, result = kind(*positional, **keywords), None
    else:
        positional, keywords = args
        result = getattr(_worker_cache, method)(*positional, **keywords)
    cache = _worker_cache
    return result, {"frames": cache.frames, "flushes": cache.flushes, "written_bytes": cache.written_bytes,
                    "flush_share": cache.flush_share}


FRAME_LAYER = re.compile(r"frame\.\d{6}\.usdc")
CLIP_LEFTOVER = re.compile(r"frame\.\d{6}\.tmp\.(usdc|[A-Za-z0-9]{6})|(boundary\.npz|bodies\.npz|surface\.json|"
                           r"metadata\.json|domain\.json)\.tmp|"
                           r"stitch\.[A-Za-z0-9.]+")  # what a killed write in OUT.clips/ leaves (stitch.*: finish's scratch)


class UsdClipCache:
    """One layer per frame in ``FINAL.clips/``, stitched into ``FINAL`` by :meth:`finish`.

    Memory does not grow with the number of frames: each frame's stage is written and
    released. Every file in ``FINAL.clips/`` is written whole through a synced temporary file and a
    rename (:func:`save_layer`, :func:`write_atomically`), the frame layers and the mesh a worker adds to
    one alike: a kill, a full disk or a power cut leaves the frame layers written before, each readable,
    and no half-written one. The top-level file is made when the run ends or stops; the frame layers of a
    crashed run stay readable on their own. ``append=K`` continues after frame K (later frame
    layers are dropped). ``metadata`` (customLayerData of the top-level file) waits in
    OUT.clips/metadata.json."""

    def __init__(self, final_path, fps, up_axis="Y", boundary_points=None, boundary_radius=None, append=None,
                 bodies=None, metadata=None, domain=None):
        self.final = Path(final_path)
        self.dir = self.final.with_name(self.final.stem + ".clips")
        self.dir.mkdir(parents=True, exist_ok=True)
        for leftover in [p for p in self.dir.iterdir() if CLIP_LEFTOVER.fullmatch(p.name) and p.is_file()]:
            leftover.unlink()  # a killed write's temporary file
        for layer in self.frame_layers() if append is not None else ():
            if int(layer.name.split(".")[1]) > append:
                layer.unlink()
        self.fps, self.up_axis = fps, up_axis
        self.boundary = (None if boundary_points is None else np.asarray(boundary_points), boundary_radius)
        self.boundary_file = self.dir / "boundary.npz"
        if boundary_points is not None:
            write_atomically(self.boundary_file, _npz_bytes(points=np.asarray(boundary_points), radius=boundary_radius))
        self.metadata_file = self.dir / "metadata.json"
        if metadata:
            import json

            write_atomically(self.metadata_file, json.dumps(metadata).encode())
        self.domain_file = self.dir / "domain.json"  # warpsph:domain of the top-level file
        if domain is not None:
            import json

            write_atomically(self.domain_file, json.dumps(domain_record(domain)).encode())
        self.bodies_file = self.dir / "bodies.npz"
        if bodies:
            arrays = {}
            for n, (name, vertices, faces, moving) in enumerate(bodies):
                arrays.update({f"name_{n}": np.array(name), f"vertices_{n}": vertices, f"faces_{n}": faces,
                               f"moving_{n}": np.array(moving)})
            write_atomically(self.bodies_file, _npz_bytes(count=len(bodies), **arrays))
        self.frames = 0
        self._last_written = 0  # bytes of the last frame's arrays (the next one's space estimate)

    def frame_path(self, frame):
        return self.dir / f"frame.{frame:06d}.usdc"

    def frame_layers(self):
        """The frame layers in OUT.clips/, in frame order (not a killed save's temporary files)."""
        return sorted(p for p in self.dir.glob("frame.*.usdc") if FRAME_LAYER.fullmatch(p.name))

    def flush(self):
        """Nothing to save: each frame's layer is a whole file when :meth:`write_frame` returns."""

    def write_frame(self, frame, points, velocities, ids, radius, fields=None, body_poses=None, widths=True,
                    surface=None):
        """Writes the layer of frame ``frame`` (every asked array: a clip stands on its own);
        returns the bytes of the arrays written."""
        _check_directory(self.dir)
        check_space(self.dir, frame, _frame_estimate(points, self._last_written))
        stage = Usd.Stage.CreateInMemory()  # saved whole under its name below
        stage.SetStartTimeCode(frame)  # StitchClips activates each clip at its layer's start
        stage.SetEndTimeCode(frame)
        UsdGeom.Xform.Define(stage, "/World")
        written = _write_points(UsdGeom.Points.Define(stage, "/World/Fluid"), frame, points, velocities, ids, radius,
                                fields, widths)
        if surface is not None:
            write_surface(stage, frame, surface)
        _write_body_poses(stage, frame, body_poses)
        save_layer(stage.GetRootLayer(), self.frame_path(frame))
        del stage
        self._last_written = written
        self.frames += 1
        return written

    def surface_layer(self, frame):
        """The layer of frame ``frame`` (written before), where a mesher worker writes the frame's mesh itself
        (:func:`write_surface_layer`): opening, writing and saving a 1M-particle frame's layer with its mesh
        held the GIL of the run's process 140-230 ms a frame (2-core VM), time the simulation's host thread
        waited for."""
        return str(self.frame_path(frame))

    def write_surface(self, frame, mesh, save=True):
        """The surface mesh of frame ``frame`` into its layer, written before (the background mesher); a mesh
        that a worker wrote into that layer itself (``mesh.layer``) is there already."""
        if getattr(mesh, "layer", None) is not None and Path(mesh.layer) == self.frame_path(frame):
            return
        write_surface_layer(self.frame_path(frame), frame, mesh)

    def note_surface(self, info):
        """Kept for the top-level file (:meth:`finish`), and in OUT.clips/surface.json meanwhile."""
        import json

        self.surface_note = dict(info)
        write_atomically(self.dir / "surface.json", json.dumps(self.surface_note).encode())

    def finish(self, final_path=None):
        """Stitches every frame layer into the top-level file (value clips + topology layer). A
        frame layer without the surface mesh (``--surface-every``, frames skipped) holds the mesh of
        the frame before (interpolateMissingClipValues: meshes of different vertex counts are held).

        The three stitched files are written crash-consistently, like the frame layers: ``StitchClips`` writes
        scratch layers in OUT.clips/ (stitch.usdc, stitch.topology.usdc, stitch.manifest.usdc), whose asset paths
        are then pointed at the final names, and each is saved through a synced temporary file and a rename
        (:func:`save_layer`): the topology, the manifest, then the top-level file. A kill, a full disk or a power
        cut at any moment leaves the earlier stitched files, each whole, or the new ones (or the earlier
        top-level file over the new topology and manifest, which declare the same prims and attributes or more);
        the scratch files are removed here and when the cache is opened again."""
        final = Path(final_path or self.final)
        frames = self.frame_layers()
        if not frames:
            return
        helpers = [final.with_name(f"{final.stem}.{kind}{final.suffix}") for kind in ("topology", "manifest")]
        scratch = self.dir / f"stitch{final.suffix}"
        scratch_helpers = [self.dir / f"stitch.{kind}{final.suffix}" for kind in ("topology", "manifest")]
        for leftover in [p for p in self.dir.iterdir() if p.name.startswith("stitch.") and p.is_file()]:
            leftover.unlink()
        for path in (final, *helpers):
            remove_leftovers(path)
        try:
            layer = Sdf.Layer.CreateNew(str(scratch))
            numbers = [int(f.name.split(".")[1]) for f in frames]
            UsdUtils.StitchClips(layer, [str(f) for f in frames], Sdf.Path("/World"), min(numbers), max(numbers), True)
            for helper, written in zip(helpers, scratch_helpers):
                written = Sdf.Layer.FindOrOpen(str(written)) if written.exists() else None
                if written is not None:
                    _mark(written)
                    save_layer(written, helper)
            _mark(layer)
            note = self.dir / "surface.json"
            if note.exists():
                import json

                _note_surface(layer, json.loads(note.read_text()))
            if self.metadata_file.exists():
                import json

                _note_metadata(layer, json.loads(self.metadata_file.read_text()))
            if self.domain_file.exists():
                import json

                _note_domain(layer, json.loads(self.domain_file.read_text()))
            stage = Usd.Stage.Open(layer)
            _set_stage_metadata(stage, self.fps, self.up_axis)
            stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
            if self.boundary_file.exists():
                data = np.load(self.boundary_file)
                _define_boundary(stage, data["points"], float(data["radius"]))
            if self.bodies_file.exists():
                data = np.load(self.bodies_file)
                _define_bodies(stage, [(str(data[f"name_{n}"]), data[f"vertices_{n}"], data[f"faces_{n}"],
                                        bool(data[f"moving_{n}"])) for n in range(int(data["count"]))])
            del stage
            # the scratch layers refer to each other and to the frames from OUT.clips/; the final ones from final's folder
            clips_dir = os.path.relpath(self.dir, final.parent).replace(os.sep, "/")
            layer.subLayerPaths[:] = [f"./{helpers[0].name}"]
            clips = dict(layer.GetPrimAtPath("/World").GetInfo("clips"))
            default = dict(clips["default"])
            default["assetPaths"] = Sdf.AssetPathArray([f"./{clips_dir}/{f.name}" for f in frames])
            default["manifestAssetPath"] = Sdf.AssetPath(f"./{helpers[1].name}")
            clips["default"] = default
            layer.GetPrimAtPath("/World").SetInfo("clips", clips)
            save_layer(layer, final)
        finally:
            for path in (scratch, *scratch_helpers):
                if path.exists():
                    path.unlink()


def _note_surface(layer, info):
    """``warpsph:surface`` in the layer's customLayerData: method, every, behind, meshed, skipped
    (a count), skipped_frames and a sentence saying which frames hold the mesh of an earlier one."""
    info = {k: Vt.IntArray(list(map(int, v))) if isinstance(v, (list, tuple)) else v for k, v in info.items()}
    layer.customLayerData = {**layer.customLayerData, "warpsph:surface": info}


SPACE_HEADROOM = 64 * 2**20  # bytes kept free beyond a frame's estimate (the crate's table of contents, the stats)


def check_space(directory, frame, estimate):
    """Before a frame is written: ENOSPC (with the numbers) unless ``directory``'s file system has room for
    ``estimate`` bytes (1.5x the last frame's arrays, or 4x the first frame's points) and SPACE_HEADROOM. A save that
    runs out of space half-way leaves a single-file cache that USD cannot open; refusing before it keeps the
    frames already written."""
    import shutil

    free = shutil.disk_usage(directory).free
    if free < estimate + SPACE_HEADROOM:
        raise OSError(errno.ENOSPC, f"No space left on device: {free / 2**20:.1f} MiB free in {directory}, about "
                                    f"{(estimate + SPACE_HEADROOM) / 2**20:.1f} MiB needed to write frame {frame} safely")


def _frame_estimate(points, last_written):
    return int(1.5 * last_written) if last_written else 4 * np.asarray(points).nbytes


def _check_directory(path):
    """USD would create a missing directory again and go on writing into it: a directory removed
    during a run (and the frames in it) is an error instead."""
    if not path.is_dir():
        raise OSError(errno.ENOENT, f"the output directory {path} was removed during the run")


def _extent(points, pad=0.0):
    if len(points) == 0:
        return Vt.Vec3fArray([Gf.Vec3f(0.0), Gf.Vec3f(0.0)])
    p = np.asarray(points)  # column by column: min(axis=0) of an (N, 3) array is 20x slower
    lo = np.array([p[:, k].min() for k in range(3)]) - pad
    hi = np.array([p[:, k].max() for k in range(3)]) + pad
    return Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))])


def write_host_frame(cache, item, radius, fields=None, surface=None):
    """Writes a :class:`~warpsph.io.frames.HostFrame` to ``cache`` with the ``--fields`` asked
    (None: every field the frame has) and the surface mesh ``surface`` (None: none); returns the
    bytes of the arrays written."""
    a = item.arrays
    if fields is None:
        fields = ["points", "velocities", "ids", "widths", *[k for k in a if k not in ("x", "v", "ids")]]
        if "vorticity" in a:
            fields.append("vorticity_magnitude")
    primvars = {}
    for name in fields:
        if name == "vorticity_magnitude":
            primvars[name] = np.linalg.norm(a["vorticity"], axis=1)
        elif name not in ("points", "velocities", "ids", "widths"):
            primvars[name] = a[name]
    return cache.write_frame(item.frame, a["x"], a["v"] if "velocities" in fields else None,
                             a["ids"] if "ids" in fields else None, radius, primvars, item.poses,
                             widths="widths" in fields, surface=surface)


def frame_writer(cache, fields=None):
    """An ``on_frame`` callback for :meth:`Simulation.run` that writes every frame to ``cache``
    at once (the CLI writes in the background: :class:`~warpsph.io.frames.FrameWriter`)."""
    from warpsph.io.frames import FrameWriter, WriterFailed

    state = {}

    def on_frame(sim, frame):
        if "writer" not in state:
            radius = sim.scene.particle_radius
            state["writer"] = FrameWriter(sim, lambda item: write_host_frame(cache, item, radius, fields),
                                          copy=["v", *sim.fields()], background=False)
        try:
            state["writer"].submit(sim, frame)
        except WriterFailed as failed:
            raise failed.cause from None

    return on_frame


def body_meshes(sim):
    """(name, vertices, faces, moving) of every body, for the writers: a static body in world
    space, a moving one in body space (its pose goes into each frame)."""
    return [(b.name, b.to_world(b.vertices) if b.kind == "static" else b.vertices, b.faces, b.kind != "static")
            for b in sim.bodies]
