"""A run's outputs, written frame by frame through one object: :class:`Recorder`.

The USD cache (a single file, :class:`~warpsph.io.usd.UsdPointCache`, written in a process of its own on a GPU run:
:class:`~warpsph.io.usd.CacheProcess`; or value clips, :class:`~warpsph.io.usd.UsdClipCache`), its surface meshes
(:mod:`warpsph.surface`), the diagnostics CSV (:class:`~warpsph.diagnostics.DiagnosticsWriter`), the HDF5 particle
frames and the checkpoints. Each frame's arrays are copied off the device and written by a background thread
(:class:`~warpsph.io.frames.FrameWriter`); a checkpoint waits for the writer, so it never claims a frame the cache
does not hold. ``warpsph run`` and ``warpsph resume`` record through it (the CLI parses, steps, handles signals and
reports); :class:`UsdWriter` is the library's way to the same cache.

Writing errors are :class:`WriteError` (one line naming the file or frame); the frames written before stay readable.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from types import SimpleNamespace
from warpsph.diagnostics import DiagnosticsWriter
from warpsph.errors import SceneError
from warpsph.io.frames import FrameWriter, WriterFailed, parse_fields
from warpsph.surface import (BackgroundMesher, DeviceMesher, SurfaceOptions, mesher_for, require_pysplashsurf,
    surface_clip)

class WriteError(Exception):
    """Writing an output failed (disk full, permissions): the frames written before stay readable."""


def _write_failure(exc):
    return isinstance(exc, OSError) or type(exc).__name__ == "ErrorException"  # pxr.Tf.ErrorException


@contextlib.contextmanager
def _writing(what):
    try:
        yield
    except Exception as exc:
        if not _write_failure(exc):
            raise
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc).strip().splitlines()[-1]
        raise WriteError(f"{what}: {reason}") from exc


class MesherFailed(Exception):
    """The surface mesher of ``run --surface`` failed or lost a worker process: the particle frames are kept."""


def _mesher_failure(exc):
    """One line on a failed mesh: a worker that died names no exception of its own."""
    from concurrent.futures.process import BrokenProcessPool

    cause, seen = exc, set()
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, BrokenProcessPool):
            return (f"{exc}".split(":")[0] + ": a mesher worker process died (killed by a signal or out of "
                    "memory)").strip()
        cause = cause.__cause__
    return f"{exc}".strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _close(close):
    """Runs ``close``; the reason it failed writing, or None (the run's own error goes first)."""
    try:
        close()
    except MesherFailed as exc:
        return str(exc)
    except Exception as exc:
        if not _write_failure(exc):
            raise
        return str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    return None


def _write_error(failed):
    """The :class:`WriteError` of a failed frame writer (:class:`~warpsph.io.frames.WriterFailed`)."""
    exc = failed.cause
    if isinstance(exc, OSError) and exc.strerror:
        reason = exc.strerror
    elif _write_failure(exc):
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    elif "surface mesh of frame" in str(exc):  # the mesher's error, raised on the writer's thread
        reason = _mesher_failure(exc)
    else:  # not a disk problem: name the exception
        reason = f"{type(exc).__name__}: {exc}"
    error = WriteError(f"cannot write frame {failed.frame}: {reason}")
    error.__cause__ = exc
    return error



class Recorder:
    """Writes every frame of ``sim`` to the outputs ``outputs`` (an object with ``out``, ``partial``, ``stats``,
    ``particles`` and ``checkpoint`` paths: the CLI's ``Outputs``).

    ``options``: the run's recorded options (``fields``, ``clips``, ``particles_h5``, ``surface*``; they go into
    each checkpoint with ``frames``); ``append``: continue the outputs after that frame (a resumed run: later
    frames are dropped and written again, each once); ``background``: write on a thread of its own (False: on the
    caller's, ``--sync-output``); ``cache_process``: the single-file cache in a process of its own (None: where the
    simulation runs on a GPU); ``stats``: write the diagnostics CSV.

    Call :meth:`on_frame` after each frame (``Simulation.run``'s ``on_frame``), :meth:`checkpoint` when one is due,
    :meth:`drain` after the last step, and :meth:`close` at the end whatever happened."""

    def __init__(self, sim, outputs, options, append=None, frames=None, background=True, cache_process=None,
                 stats=True):
        from warpsph.io.usd import (FLUSH_SHARE, CacheProcess, DamagedCache, UsdClipCache, UsdPointCache,
                                    body_meshes, recover_cache, run_metadata)

        self.sim, self.outputs, self.options, self.frames = sim, outputs, options, frames
        scene = sim.scene
        self.fields = parse_fields(options.get("fields") or None, sim)
        static = sim.num_boundary if sim.moving_bodies is None else sim.moving_bodies.first_sample
        boundary = None if append is not None else sim.boundary.x.numpy()[:static]
        meshes = None if append is not None else body_meshes(sim)
        self.metadata = None if append is not None else run_metadata(scene)  # a resumed run keeps its first part's
        if options.get("clips"):
            self.cache = UsdClipCache(outputs.out, scene.output.fps, scene.output.up_axis, boundary_points=boundary,
                                      boundary_radius=scene.particle_radius, append=append, bodies=meshes,
                                      metadata=self.metadata, domain=scene.domain)
        else:
            try:
                if append is not None:  # the copy holding frames 0..append, moved to NAME.partial (else nothing changes)
                    recover_cache(outputs.out, outputs.partial, append)
                if cache_process is None:  # a GPU run's host thread launches the steps: USD's calls would hold its GIL
                    cache_process = any(p.device.is_cuda for p in sim.parts())
                settings = dict(boundary_points=boundary, boundary_radius=scene.particle_radius, append=append,
                                bodies=meshes, metadata=self.metadata, domain=scene.domain,
                                flush_share=FLUSH_SHARE)  # saved while cheap, at each checkpoint and at the end
                where = (outputs.partial, scene.output.fps, scene.output.up_axis)
                self.cache = (CacheProcess(UsdPointCache, *where, **settings) if cache_process
                              else UsdPointCache(*where, **settings))
            except DamagedCache as exc:
                raise SceneError(outputs.out, "", exc.reason) from None
        self.diagnostics = DiagnosticsWriter(outputs.stats, append=append, metadata=self.metadata) if stats else None
        self.particles = None
        if options.get("particles_h5"):
            from warpsph.io.particles_h5 import ParticleFrames

            try:
                self.particles = ParticleFrames(outputs.particles, append=append)
            except OSError as exc:  # h5py: a file it cannot open (not written by this warpsph), or no room
                raise SceneError(outputs.particles, "", f"cannot continue the particle frames ({exc})") from None
        published = list(sim.fields())
        if self.particles is not None:  # the HDF5 frames hold every array
            copy = ["v", *published]
        else:
            copy = (["v"] if "velocities" in self.fields else []) + [n for n in published if n in self.fields]
            if "vorticity_magnitude" in self.fields and "vorticity" not in copy:
                copy.append("vorticity")
        self.surface = surface_options(options)
        if self.surface is not None:  # the mesh interpolates velocity and vorticity magnitude to its vertices
            copy += [n for n in ("v", "vorticity") if (n == "v" or n in published) and n not in copy]
        self.payload = {"bytes": 0, "particle_frames": 0, "surface_seconds": 0.0}
        self.mesher = None
        if self.surface is not None:  # meshes on a thread of its own, fed by the writer (bounded: --surface-behind)
            clip = surface_clip(scene.domain, body_meshes(sim))  # the meshes stop at the walls and bodies
            every = int(options.get("surface_every", 1))
            parts = sim.parts()
            if self.surface.method == "preview" and len(parts) == 1 and parts[0].device.is_cuda:  # between steps
                self.mesher = DeviceMesher(self.surface, scene.particle_radius, clip=clip, every=every)
            else:
                workers = int(options.get("surface_workers", 0) or 0) or None  # None: the mesher's default
                self.mesher = BackgroundMesher(mesher_for(self.surface, scene.particle_radius, sim.device,
                                                          workers=workers, clip=clip),
                                               every=every, behind=str(options.get("surface_behind", "wait")))
        self._mesh_on_device = getattr(self.mesher, "mesh_now", None)
        self._advance_mesh = getattr(self.mesher, "advance", None)  # the device mesher's stages between steps
        self._mesh_count = {"submitted": 0, "written": 0}  # frames handed to the mesher, and their meshes written
        self.writer = FrameWriter(sim, self._write, copy=copy, background=background)

    # -- the writer's thread ------------------------------------------------------------------------------------------
    def _write_meshes(self):
        for frame, mesh in self.mesher.ready():
            self.cache.write_surface(frame, mesh, save=False)  # saved with the next frame (or checkpoint)
            self._mesh_count["written"] += 1

    def _write(self, item):
        """The USD frame, the meshes done, the HDF5 frame, the CSV row (on the writer's thread)."""
        from warpsph.io.usd import write_host_frame

        mesher = self.mesher
        if mesher is not None:
            self._write_meshes()
        self.payload["bytes"] += write_host_frame(self.cache, item, self.sim.scene.particle_radius, self.fields)
        if mesher is not None and mesher.wants(item.frame):
            a = item.arrays
            job = {k: a[k] for k in ("x", "v", "vorticity") if k in a}
            if item.poses:  # the moving bodies' poses, for clipping the mesh to them
                job["poses"] = item.poses
            layer = self.cache.surface_layer(item.frame)
            if layer is not None:  # --clips: the mesher's worker writes the mesh into the frame's layer itself
                job["layer"] = (layer, item.frame)
            self._mesh_count["submitted"] += bool(mesher.submit(item.frame, job))
        self.payload["particle_frames"] += item.count
        if self.particles is not None:
            self.particles.write(item.frame, item.time, item.step, item.arrays)
        if self.diagnostics is not None:
            self.diagnostics.write_row(item.row)

    # -- the simulation's thread --------------------------------------------------------------------------------------
    def on_frame(self, sim, frame):
        """Measures frame ``frame``'s diagnostics, meshes it on the device (the preview on a GPU run) and hands
        its arrays to the writer; :class:`WriteError` when the writer failed on an earlier frame."""
        row = self.diagnostics.measure(sim, frame) if self.diagnostics is not None else None
        if self._mesh_on_device is not None:
            self._mesh_on_device(sim, frame)
        try:
            self.writer.submit(sim, frame, row)
        except WriterFailed as failed:
            raise _write_error(failed) from failed.cause

    def on_step(self, sim):
        """After each step: launches the device mesh's stages whose numbers are back (never waits)."""
        if self._advance_mesh is not None:
            self._advance_mesh(sim)

    def _finish_device_mesh(self):
        """The device mesh in flight, finished on this thread (the writer may be waiting for it)."""
        finish = getattr(self.mesher, "finish", None)
        if finish is not None:
            finish()

    def drain(self):
        """Waits until every frame handed over is written; :class:`WriteError` if one failed."""
        self._finish_device_mesh()
        try:
            self.writer.flush()
        except WriterFailed as failed:
            raise _write_error(failed) from failed.cause

    def _wait_meshes(self):
        """Writes the meshes of every frame handed to the mesher (called with the writer drained, so on this thread
        alone): a checkpoint at frame F claims the meshes of frames <= F too. Without it a kill after the checkpoint
        lost the meshes still in flight, and the resumed run never meshed those frames again."""
        try:
            while True:
                self._write_meshes()
                if self._mesh_count["written"] >= self._mesh_count["submitted"]:
                    return
                time.sleep(0.002)
        except Exception as exc:  # the mesher failed or lost a worker: one line, as from the writer
            raise _write_error(WriterFailed(self.sim.frame, exc)) from exc

    def checkpoint(self):
        """Saves everything written so far and a checkpoint of the simulation's state, which claims only frames the
        outputs hold (it waits for the writer and the mesher)."""
        from warpsph.io.checkpoint import save_checkpoint

        outputs = self.outputs
        self.drain()
        if self.mesher is not None:
            self._wait_meshes()
        with _writing(f"cannot save the cache {outputs.out}"):
            self.cache.flush()
        if self.particles is not None:
            with _writing(f"cannot save {outputs.particles}"):
                self.particles.flush()
        with _writing(f"cannot write the checkpoint {outputs.checkpoint}"):
            save_checkpoint(self.sim, outputs.checkpoint,
                            extra={**self.options, "output": os.path.abspath(outputs.out), "frames": self.frames})

    def _finish_meshes(self):  # after the writer: the meshes still queued, and the note in the metadata
        try:
            done = self.mesher.close()
        except Exception as exc:  # a worker died (SIGKILL, out of memory) or failed: the particle frames stay
            raise MesherFailed(_mesher_failure(exc)) from exc
        for frame, mesh in done:
            self.cache.write_surface(frame, mesh, save=True)
        self.payload["surface_seconds"] = self.mesher.seconds
        self.cache.note_surface(self.mesher.note(self.surface))

    def close(self):
        """Writes the frames still queued (a stopped or unstable run keeps them), then finishes the meshes, the CSV,
        the HDF5 file and the cache (renamed to its final name); returns the reasons that closing failed (None
        each that did not), the run's own error going first."""
        _close(self._finish_device_mesh)
        self.writer.close()
        return [self.mesher is not None and _close(self._finish_meshes),
                self.diagnostics is not None and _close(self.diagnostics.close),
                self.particles is not None and _close(self.particles.close),
                _close(lambda: self.cache.finish(self.outputs.out))]


def surface_options(options):
    """The :class:`~warpsph.surface.SurfaceOptions` of a run's options, or None without --surface;
    raises :class:`SceneError` naming the option (a bad value, pysplashsurf missing)."""
    if not int(options.get("surface", 0) or 0):
        return None
    surface = SurfaceOptions(cube=float(options.get("surface_cube", SurfaceOptions.cube)),
                             smoothing=float(options.get("surface_smoothing", SurfaceOptions.smoothing)),
                             method=str(options.get("surface_method", "splashsurf"))).check("--surface-")
    every = int(options.get("surface_every", 1))
    if every < 1:
        raise SceneError("", "--surface-every", f"expected an integer >= 1 (mesh every K-th frame), got {every}")
    workers = int(options.get("surface_workers", 0) or 0)
    if workers < 0:
        raise SceneError("", "--surface-workers", f"expected an integer >= 0 (0: the default), got {workers}")
    if surface.method == "splashsurf":
        require_pysplashsurf("--surface")
    return surface


class UsdWriter:
    """The public USD writer: every frame of a :class:`~warpsph.simulation.Simulation` into a USD
    point cache (layout in :mod:`warpsph.io.usd`'s docstring), with the domain's boundary samples and the
    scene's bodies. Call it as the ``on_frame`` of :meth:`Simulation.run`, then :meth:`close`
    (or use it as a context manager). ``fields``: the ``--fields`` names to write (``points``, ``velocities``,
    ``ids``, ``widths``, ``density``, ``vorticity``, ...; None: all). ``clips=True`` writes one layer per frame
    (:class:`~warpsph.io.usd.UsdClipCache`, for large runs) instead of a single file
    (:class:`~warpsph.io.usd.UsdPointCache`, saved whenever a save costs at most ``FLUSH_SHARE`` of the time
    since the last one, and at :meth:`close`). It writes through the same :class:`Recorder` as ``warpsph run``, on
    the calling thread, without the run's CSV and checkpoints; a failed write raises :class:`WriteError` naming the
    frame.

    Example:

    ```python
    import warpsph

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    with warpsph.io.UsdWriter("out/dam_break.usdc", sim, fields=["points", "velocities"]) as usd:
        sim.run(frames=5, on_frame=usd)  # on_frame(sim, frame) after the start and each frame
    print(usd.frames, usd.path)  # 6 frames (0 .. 5)
    ```
    """

    def __init__(self, path, sim, fields=None, clips=False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        outputs = SimpleNamespace(out=self.path, partial=self.path)  # no NAME.partial: the file is the API's
        options = {"fields": ",".join(fields) if fields is not None else None, "clips": int(clips)}
        self._recorder = Recorder(sim, outputs, options, background=False, cache_process=False, stats=False)
        self.cache = self._recorder.cache
        self.closed = False

    def __call__(self, sim, frame):
        """Writes frame ``frame`` of ``sim`` (the ``on_frame`` signature)."""
        self._recorder.on_frame(sim, frame)

    @property
    def frames(self):
        """Frames written so far."""
        return self.cache.frames

    def close(self):
        """Finishes the cache (a clip cache gets its top-level file); returns its path."""
        if not self.closed:
            self.closed = True
            failed = [reason for reason in self._recorder.close() if reason]
            if failed:
                raise WriteError(f"cannot finish {self.path}: {failed[0]}")
        return self.path

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
