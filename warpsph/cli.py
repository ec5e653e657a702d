"""Command line.

    warpsph run SCENE.json [--device auto|cpu|cuda] [--out FILE.usdc] [--frames N] [--scale S]
                           [--overwrite] [--checkpoint-every N] [--on-instability stop|reduce-dt] [--dry-run]
                           [--fields points,velocities,...] [--sync-output] [--[no-]cache-process]
                           [--surface [--surface-cube C] [--surface-method splashsurf|preview] [--surface-every K]
                           [--surface-behind wait|skip]]
    warpsph resume CHECKPOINT.h5 [--device ...] [--frames N]
    warpsph surface OUT.usdc|OUT.particles.h5 [--cube C] [--smoothing L] [--frames A B] [--out NEW.usdc]
                    [--method splashsurf|preview] [--device cpu|cuda]
    warpsph warmup [--device auto|cpu|cuda | --arch SM ...] [--scene SCENE.json ...]   (compile the kernels ahead of a first run)

Every command takes -q/--quiet (warnings and errors only, no progress), -v/--verbose (debug
lines too, e.g. each frame's wall time) and --log FILE (the same lines appended to FILE, timed),
before or after its name. On a terminal with rich
installed (pip install 'warpsph[rich]') a run shows a progress bar; otherwise a line per frame.

--overwrite replaces only files warpsph wrote (a directory or anyone else's file is refused). A
checkpoint holds the whole scene: resume works from any directory, and resuming again rewrites
the frames after the checkpoint, so the outputs hold each frame once.

Exit codes: 0 done, 2 bad input (scene, mesh, device, option, existing output, memory), 3 unstable,
130 / 143 stopped by SIGINT / SIGTERM (after finishing the frame, saving the cache and a checkpoint).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import re

import numpy as np
import signal
import sys
import time
from pathlib import Path

from . import __version__, log, warmup
from .device import CUDA_DRIVER_WARNING, init_warp as _init_warp, pick_device as _pick_device  # noqa: F401
from .errors import SceneError
from .io.recorder import Recorder, WriteError, _write_error, _write_failure, surface_options
from .log import PLAIN
from .decomposition import DecomposedSimulation, device_names
from .diagnostics import is_metadata, is_stats_csv
from .io.frames import WriterFailed, parse_fields
from .models import plugin_of
from .plots import plot_energy, plot_slice, slice_from_cache, sweep_figures
from .resources import estimate_bytes, free_bytes
from .scene import load_scene, reference_markdown, scene_json_schema
from .simulation import InstabilityError, Simulation, sample_scene
from .solvers import solver_names
from .surface import SurfaceOptions, plan_remesh, remesh
from .sweep import add_executor_arguments, executor_arguments, run_sweep
from .validation import bench, bench_job, pareto, results, stress
from .validation.cases import check_arguments, table, validate
from .validation.taylor_green import METHODS
from .warmup import frame_modules, surface_modules

EXIT_UNSTABLE = 3
logger = logging.getLogger("warpsph.cli")  # also when run as python -m warpsph.cli


USD_SUFFIXES = (".usdc", ".usda", ".usd")


def _pick_devices(args):
    """(device, devices): --device alone gives (it, None); --devices D,D.. or --subdomains K one simulation
    over several subdomains (``devices``: the list, each checked as --device)."""
    if not args.devices and args.subdomains is None:
        return _pick_device(args.device), None
    if args.subdomains is not None and args.subdomains < 1:
        raise SceneError("", "--subdomains", f"expected an integer >= 1, got {args.subdomains}")
    names = device_names(args.devices or args.device)
    if not names:
        raise SceneError("", "--devices", "expected device names separated by commas (e.g. cuda:0,cuda:1) or a "
                                          "count of GPUs (e.g. 2)")
    try:
        devices = [_pick_device(n) for n in names]
    except SceneError as exc:
        raise SceneError("", "--devices", exc.reason) from None
    return devices[0], devices


class Progress:
    """A run's progress after each frame: a rich bar (frames, steps/s, ETA) when stderr is a
    terminal, rich is installed and info is shown; else an info line per frame. A debug line per
    frame gives its wall time and steps."""

    def __init__(self, frames):
        self.frames = frames
        self.start = self.last = time.perf_counter()
        self.first = None  # (frame, steps) at the first call: a resumed run starts mid-way
        self.last_steps = 0
        self.bar = _rich_bar() if log.enabled(logging.INFO) and sys.stderr.isatty() else None
        self.task = None

    def __call__(self, sim, frame):
        now = time.perf_counter()
        if self.first is None:
            self.first = (frame, sim.step_count)
            self.last_steps = sim.step_count
        elapsed = now - self.start
        stats = sim.statistics()
        steps = sim.step_count - self.first[1]
        rate = steps / elapsed if elapsed > 0 else 0.0
        done = frame - self.first[0]
        eta = elapsed / done * (self.frames - frame) if done else 0.0
        if logger.isEnabledFor(logging.DEBUG):
            k = sim.step_count - self.last_steps
            logger.debug(f"frame {frame}: {now - self.last:.3f} s wall, {k} steps"
                         + (f" ({1e3 * (now - self.last) / k:.1f} ms per step)" if k else "")
                         + f", t={sim.time:.4f}s, {sim.num_fluid} fluid particles")
        self.last, self.last_steps = now, sim.step_count
        if self.bar is not None:
            fields = {"rate": f"{rate:.1f} steps/s", "time": f"t={sim.time:.3f}s"}
            if self.task is None:
                self.bar.start()
                self.task = self.bar.add_task("frame", total=self.frames, completed=frame, **fields)
            else:
                self.bar.update(self.task, completed=frame, **fields)
            return
        logger.info(f"frame {frame}/{self.frames}  t={sim.time:.3f}s  steps={sim.step_count}  {rate:.1f} steps/s  "
                    f"iterations div {stats['divergence_iterations']:.1f} dens {stats['density_iterations']:.1f}  "
                    f"eta {eta:.0f}s")

    def close(self):
        """Stops the bar (it stays on the screen, above the lines that follow)."""
        if self.bar is not None and self.task is not None:
            self.bar.stop()
            self.task = None


def _rich_bar():
    """A rich progress bar on stderr, or None without rich."""
    try:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
        from rich.progress import Progress as Bar
    except ImportError:
        return None
    return Bar(TextColumn("frame"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[time]}"),
               TextColumn("{task.fields[rate]}"), TextColumn("eta"), TimeRemainingColumn(),
               console=Console(file=sys.stderr))


CLIP_FILE = re.compile(r"frame\.\d{6}\.usdc|boundary\.npz|bodies\.npz|surface\.json|metadata\.json|domain\.json|"
                       r"frame\.\d{6}\.tmp\.(usdc|[A-Za-z0-9]{6})|(boundary\.npz|bodies\.npz|surface\.json|metadata\.json|"
                       r"domain\.json)\.tmp|stitch\.[A-Za-z0-9.]+")  # and what a killed write leaves there


class Outputs:
    """The files of one run: the USD cache (single file: written as NAME.partial.usdc and renamed
    when the run stops; value clips: NAME.clips/ stitched into NAME, NAME.topology and
    NAME.manifest when the run stops), the diagnostics CSV, the particle frames and the latest
    checkpoint, all beside each other."""

    def __init__(self, out):
        self.out = Path(out)
        self.partial = self.out.with_name(self.out.stem + ".partial" + self.out.suffix)
        self.clips = self.out.with_name(self.out.stem + ".clips")
        self.stitched = [self.out.with_name(f"{self.out.stem}.{kind}{self.out.suffix}") for kind in ("topology", "manifest")]
        self.stats = self.out.with_suffix(".stats.csv")
        self.stats_meta = self.out.with_suffix(".stats.meta.json")
        self.checkpoint = self.out.with_suffix(".checkpoint.h5")
        self.particles = self.out.with_suffix(".particles.h5")

    def existing(self):
        return [p for p in (self.out, self.partial, self.clips, *self.stitched, self.stats, self.stats_meta, self.checkpoint,
                            self.particles)
                if p.exists() or p.is_symlink()]

    def check(self):
        """Raises :class:`SceneError` when --out cannot name a cache: a directory, another
        extension, a parent that is a file or not writable."""
        if self.out.is_dir():
            raise SceneError(self.out, "--out", f"is a directory; --out names the USD file to write, "
                                                f"e.g. {self.out / 'NAME.usdc'}")
        if self.out.suffix.lower() not in USD_SUFFIXES:
            raise SceneError(self.out, "--out", f"expected a file name ending in {', '.join(USD_SUFFIXES)}")
        check_writable_parent(self.out, "--out")

    def owned(self, path):
        """Whether warpsph wrote ``path`` (so that --overwrite may replace it)."""
        from .io.particles_h5 import is_particles_h5

        if path.is_symlink():
            return False
        if path == self.clips:
            return path.is_dir() and all(p.is_file() and CLIP_FILE.fullmatch(p.name) for p in path.iterdir())
        if not path.is_file():
            return False
        if path == self.stats:
            return is_stats_csv(path)
        if path == self.stats_meta:
            return is_metadata(path)
        if path == self.particles:
            return is_particles_h5(path)
        if path == self.checkpoint:
            from .io.checkpoint import is_checkpoint

            return is_checkpoint(path)
        from .io.usd import written_by_warpsph

        return written_by_warpsph(path)

    def foreign(self):
        """The existing paths of this run's outputs that warpsph did not write."""
        return [p for p in self.existing() if not self.owned(p)]

    def remove(self, path):
        if path.is_dir():
            import shutil

            shutil.rmtree(path)
        else:
            path.unlink()


class StopRequest(Exception):
    def __init__(self, signum):
        self.signum = signum


def _disk_usage(outputs, clips):
    """Bytes of the USD cache on disk (the frame layers and the stitched files of a --clips run)."""
    paths = [outputs.out] + ([*outputs.clips.glob("frame.*.usdc"), *outputs.stitched] if clips else [])
    return sum(p.stat().st_size for p in paths if p.is_file())


def _cache_exists(outputs, clips):
    return outputs.clips.is_dir() if clips else outputs.out.exists() or outputs.partial.exists()


last_run = {}  # timings and sizes of the last _simulate (warpsph bench job reads them)


def _simulate(sim, outputs, frames, args, options, append):
    """Runs to ``frames``, writing every frame through a :class:`~warpsph.io.recorder.Recorder` (``--sync-output``:
    on this thread; ``--cache-process``); ``append`` (a frame number) continues the outputs after that frame (a
    resumed run: later frames are dropped and written again, each once). Ctrl-C / SIGTERM finish the frame, save
    and checkpoint; the exit code and the lines on what was written are this function's."""
    recorder = Recorder(sim, outputs, options, append=append, frames=frames,
                        background=not getattr(args, "sync_output", False),
                        cache_process=getattr(args, "cache_process", None))
    progress = Progress(frames)
    every = options.get("checkpoint_every", 0)
    preview = options.get("preview", 0)
    stop = {}

    def request_stop(signum, _frame):
        stop["signum"] = signum

    def on_frame(sim, frame):
        recorder.on_frame(sim, frame)
        progress(sim, frame)
        if "signum" in stop:
            recorder.checkpoint()
            raise StopRequest(stop["signum"])
        if every and frame and frame % every == 0:
            recorder.checkpoint()
        if preview and frame % preview == 0:
            _plot_preview(sim, outputs, frame)

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    start = time.perf_counter()
    steps0 = sim.step_count
    outcome = stepped = None
    try:
        sim.run(frames=frames, on_frame=on_frame, on_step=recorder.on_step)
        stepped = time.perf_counter() - start  # to the last step; then the writer and mesher finish
        recorder.drain()
    except (StopRequest, WriteError) as exc:
        outcome = exc
    except Exception as exc:
        if not isinstance(exc, InstabilityError):
            raise
        outcome = exc
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        progress.close()
        closing = recorder.close()
    loop_wall = time.perf_counter() - start
    code = _failure(sim, outputs, options, recorder, outcome, closing)
    if code is not None:
        return code
    _report_done(sim, outputs, options, recorder, frames, sim.step_count - steps0, loop_wall, stepped)
    return 0


def _plot_preview(sim, outputs, frame):
    """``--preview K``: OUT.preview.FFFFF.png, a slice of the speed (or vorticity) at frame ``frame``."""
    scene = sim.scene
    values = (np.linalg.norm(sim.field_values("vorticity"), axis=1) if "vorticity" in sim.fields()
              else np.linalg.norm(sim.velocities(), axis=1))
    plot_slice(sim.positions(), values, outputs.out.with_name(f"{outputs.out.stem}.preview.{frame:05d}.png"),
               "z", thickness=2.0 * scene.particle_diameter, title=f"{scene.name}, frame {frame}, t = {sim.time:.3f} s")


def _failure(sim, outputs, options, recorder, outcome, closing):
    """The exit code of a run that did not finish (stopped, unstable, a write that failed, outputs that could not
    be closed), after logging what the outputs keep; None when it finished."""
    writer = recorder.writer
    written = "no frames" if writer.written is None else f"frames 0..{writer.written}"
    hint = "" if not outputs.checkpoint.exists() else f"; last checkpoint: {outputs.checkpoint}"
    messages, code = [], None  # (level, text, extra) of a run that did not finish
    if isinstance(outcome, StopRequest):
        name = signal.Signals(outcome.signum).name
        code = 128 + outcome.signum
        messages.append((logging.WARNING, f"{name}: stopped after frame {sim.frame}; the cache {outputs.out} holds "
                                          f"{written}; continue with: warpsph resume {outputs.checkpoint}", PLAIN))
    elif isinstance(outcome, WriteError):
        kept = (f"the cache {outputs.out} keeps the frames before it" if _cache_exists(outputs, options.get("clips"))
                else f"the cache {outputs.out} is gone")
        code = 2
        messages.append((logging.ERROR, f"{outcome}; {kept}{hint}", None))
    elif outcome is not None:
        code = EXIT_UNSTABLE
        messages.append((logging.ERROR, f"{outcome}. The cache {outputs.out} keeps {written}{hint}. "
                                        f"Try a smaller time step (time.dt_max, time.cfl) or --on-instability reduce-dt.",
                         PLAIN))
        if writer.error is not None:
            messages.append((logging.ERROR, str(_write_error(WriterFailed(*writer.error))), None))
    elif writer.error is not None:
        code = 2
        messages.append((logging.ERROR, f"{_write_error(WriterFailed(*writer.error))}; the cache {outputs.out} "
                                        f"keeps the frames before it{hint}", None))
    if code is None and any(closing):
        code = 2
        messages.append((logging.ERROR, f"cannot finish the outputs: {next(c for c in closing if c)}", None))
    for level, text, extra in messages:
        logger.log(level, "%s", text, extra=extra)
    return code


def _report_done(sim, outputs, options, recorder, frames, steps, loop_wall, stepped):
    """The end-of-run lines of a finished run (steps, wall, iterations, outputs, surface) and ``last_run``."""
    writer, mesher, surface = recorder.writer, recorder.mesher, recorder.surface
    stats = sim.statistics()
    disk = _disk_usage(outputs, options.get("clips"))
    payload, fields, metadata = recorder.payload, recorder.fields, recorder.metadata
    per_particle = payload["bytes"] / max(payload["particle_frames"], 1)
    last_run.clear()
    last_run.update(wall=loop_wall, stepping_wall=stepped, steps=steps, frames=writer.frames, payload_bytes=payload["bytes"],
                    particle_frames=payload["particle_frames"], disk_bytes=disk, writer_seconds=writer.seconds,
                    writer_waited=writer.waited, background=writer.background, fields=list(fields),
                    surface_seconds=payload["surface_seconds"] if surface is not None else None,
                    surface_meshed=mesher.meshed if mesher is not None else None,
                    surface_skipped=list(mesher.skipped) if mesher is not None else None)
    logger.info(f"done: frame {frames}, {steps} steps, {sim.time:.3f} s simulated, {loop_wall:.1f} s wall "
                f"({steps / max(loop_wall, 1e-9):.1f} steps/s; {stepped:.1f} s to the last step, "
                f"{1000 * stepped / max(steps, 1):.2f} ms a step); mean iterations: divergence "
                f"{stats['divergence_iterations']:.2f}, density {stats['density_iterations']:.2f}; wrote {outputs.out} "
                f"and {outputs.stats.name}")
    if metadata:
        logger.warning(f"run anyway: {len(metadata['warpsph:import_dropped'])} part(s) of the SPlisHSPlasH scene left out, "
                       f"listed in the cache's metadata warpsph:import_dropped and in {outputs.stats_meta.name}")
    if stats["removed_in_sinks"] or stats["removed_outside"]:
        logger.info(f"removed: {stats['removed_in_sinks']} particles in sinks, {stats['removed_outside']} that left "
                    f"the open domain; {sim.num_fluid} remain")
    logger.info(f"output: {writer.frames} frames, {per_particle:.1f} B per particle per frame of USD arrays "
                f"({','.join(fields)}), {_size(disk)} on disk; writing took {writer.seconds:.1f} s "
                f"{'in the background' if writer.background else 'on the simulation thread'}"
                + (f", the simulation waited {writer.waited:.1f} s for it" if writer.background else ""))
    if mesher is not None:
        _report_surface(mesher, surface, loop_wall, writer)


def _report_surface(mesher, surface, loop_wall, writer):
    """The end-of-run line on the surface (frames meshed, seconds per mesh), and warnings on the
    frames skipped and on what would keep up when the simulation waited for the mesher."""
    per_mesh = mesher.seconds / max(mesher.meshed, 1)
    every = f"every {mesher.every}-th frame" if mesher.every > 1 else "every frame"
    logger.info(f"surface: /World/FluidSurface ({surface.method}, cube {surface.cube:g} r, smoothing length "
                f"{surface.smoothing:g} r) in {mesher.meshed} frames ({every}), {per_mesh:.2f} s of meshing per mesh")
    if mesher.skipped:
        logger.warning(f"surface: {len(mesher.skipped)} frames skipped (the mesher was behind; noted in the cache's "
                       f"metadata warpsph:surface; re-mesh them with warpsph surface)")
    if mesher.behind == "wait" and writer.background and writer.waited > 0.05 * loop_wall:
        simulated = (loop_wall - writer.waited) / max(writer.frames, 1)  # seconds of simulation per frame
        keep_up = max(2, int(np.ceil(per_mesh / max(simulated, 1e-9))))
        logger.warning(f"surface: the simulation waited {writer.waited:.1f} s for the writer and mesher: "
                       f"--surface-every {keep_up} or --surface-behind skip would not make it wait")


def _default_surface_method(args):
    """``--surface-method`` left out: preview (marching cubes on the GPU, between the steps) where the run is on
    CUDA, splashsurf (the host's cores) on the CPU."""
    if args.devices:
        names = device_names(args.devices)
    else:
        names = [_pick_device(args.device)]
    return "preview" if all(name.startswith("cuda") for name in names) else "splashsurf"


def _check_options(args):
    if args.frames is not None and args.frames < 1:
        raise SceneError("", "--frames", f"expected an integer >= 1 (the last frame to simulate), got {args.frames}")
    for option in ("checkpoint_every", "preview"):
        if getattr(args, option, 0) < 0:
            raise SceneError("", "--" + option.replace("_", "-"), f"expected an integer >= 0, got {getattr(args, option)}")


def check_writable_parent(path, option):
    """Raises :class:`SceneError` naming ``option`` unless the nearest existing folder above ``path`` is a directory
    this process can write in (the folders missing below it are made when the file is written)."""
    parent = Path(path).absolute().parent
    while not parent.exists() and not parent.is_symlink():
        parent = parent.parent
    if not parent.is_dir():
        raise SceneError(path, option, f"{parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise SceneError(path, option, f"cannot write in {parent}")


def check_new_file(path, option, overwrite):
    """The one rule for a verb's output file (``schema --out``, ``plot --out``, ``validate --json``): a directory or
    a parent that is not a directory is refused, an existing file is replaced only with ``--overwrite``. Missing
    parent folders are created when the file is written. Returns the path; raises :class:`SceneError` naming
    ``option``."""
    path = Path(path)
    if not str(path) or path.is_dir():
        raise SceneError(path, option, f"is a directory; {option} names the file to write")
    check_writable_parent(path, option)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise SceneError(path, option, "exists; pass --overwrite to replace it, or choose another name")
    return path


def _lock_holder(lock):
    """Who holds ``lock`` ({"pid", "host"}), or None when it is stale (its process is gone from this host, or the
    file is unreadable)."""
    import json
    import socket

    try:
        holder = json.loads(lock.read_text())
        pid, host = int(holder["pid"]), str(holder["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if host == socket.gethostname():
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass  # alive, another user's
    return {"pid": pid, "host": host}


@contextlib.contextmanager
def output_lock(out):
    """Holds OUT.lock (pid and host) while a run writes OUT: a second run on the same output is refused, naming the
    first; a lock whose process is gone from this host is taken over."""
    import json
    import socket

    lock = Path(f"{out}.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    me = {"pid": os.getpid(), "host": socket.gethostname()}
    for attempt in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder = _lock_holder(lock)
            if holder is None and attempt == 0:
                logger.warning(f"{lock}: a stale lock (its run is gone): taken over")
                lock.unlink(missing_ok=True)
                continue
            who = f"pid {holder['pid']} on {holder['host']}" if holder else "another run"
            raise SceneError(out, "--out", f"is being written by another warpsph run ({who}; lock {lock}): wait for "
                                           "it to end or choose another --out") from None
        with os.fdopen(fd, "w") as f:
            json.dump(me, f)
        break
    try:
        yield lock
    finally:
        try:
            if json.loads(lock.read_text()).get("pid") == me["pid"]:
                lock.unlink()
        except (OSError, ValueError):
            pass


def _refusal(outputs, overwrite):
    """Why the run would not start over the existing outputs, or None."""
    foreign = outputs.foreign()
    if foreign:
        return SceneError(foreign[0], "--out", "exists and was not written by warpsph: refusing to replace it "
                                               "(--overwrite replaces only warpsph's own outputs); choose another --out")
    existing = outputs.existing()
    if existing and not overwrite:
        return SceneError(existing[0], "--out", "exists; pass --overwrite to replace it, or choose another --out")
    return None


FIELD_BYTES = {"points": 12, "velocities": 12, "ids": 8, "widths": 4, "density": 4, "vorticity": 12,
               "vorticity_magnitude": 4}


def disk_bytes(scene, num_fluid, frames, particles_h5=False, fields=None, clips=False):
    """Disk the outputs of a run take (an estimate): per frame and fluid particle the USD cache's
    arrays (``fields``, a --fields string; None: all), ids and widths once in a single-file cache
    without emitters or sinks (every frame otherwise), and with --particles-h5 every array again."""
    model_fields = {name: size for m in scene.models for name, size in plugin_of(m).output_fields.items()}
    sizes = {**FIELD_BYTES, **model_fields}
    available = ["points", "velocities", "ids", "widths", "density"] + (["vorticity", "vorticity_magnitude"] if scene.models else [])
    available += list(model_fields)
    asked = available if not fields else [f.strip() for f in fields.split(",") if f.strip()]
    once = sum(FIELD_BYTES[f] for f in ("ids", "widths") if f in asked)
    every = sum(sizes.get(f, 4) for f in asked if f not in ("ids", "widths"))
    if clips or scene.emitters or scene.sinks:
        every, once = every + once, 0
    usd = num_fluid * ((frames + 1) * every + once)
    h5 = (frames + 1) * num_fluid * (12 + 12 + 4 + sum(sizes.get(f, 4) for f in available[4:] if f != "vorticity_magnitude"))
    return usd + (h5 if particles_h5 else 0)


def _size(n):
    return next(f"{n / 2**k:.1f} {unit}" for k, unit in ((30, "GiB"), (20, "MiB"), (10, "KiB"), (0, "B")) if n >= 2**k or not k)


def _dry_run(scene, frames, outputs, args):
    import warp as wp

    device = wp.get_device(_pick_device(args.device))
    fluid, _, static, _, bodies = sample_scene(scene)
    boundary = len(static) + sum(len(b.samples) for b in bodies if b.kind != "static")
    need, free = estimate_bytes(scene, len(fluid), boundary), free_bytes(device)
    disk = disk_bytes(scene, len(fluid), frames, args.particles_h5, args.fields, args.clips)
    refusal = _refusal(outputs, args.overwrite)
    existing = outputs.existing()
    if refusal is not None:
        status = f"the run would refuse: {refusal}"
    elif existing:
        status = f"the run would replace {', '.join(str(p) for p in existing)}"
    else:
        status = f"would write {outputs.out}"
    print(f"{scene.name}: {len(fluid)} fluid + {boundary} boundary particles, r = {scene.particle_radius:.4g} m, "
          f"{frames} frames; about {need / 2**20:.1f} MiB on {device}"
          + ("" if free is None else f" ({free / 2**20:.0f} MiB free)")
          + f"; about {_size(disk)} of disk" + (" (more as emitters add particles)" if scene.emitters else "")
          + f"; {status}")
    return 0


def run_command(args):
    _check_options(args)
    surface = {"surface": int(args.surface), "surface_cube": args.surface_cube, "surface_smoothing": args.surface_smoothing,
               "surface_every": args.surface_every, "surface_behind": args.surface_behind,
               "surface_workers": args.surface_workers,
               "surface_method": args.surface_method or (_default_surface_method(args) if args.surface else "splashsurf")}
    surface_options(surface)  # a bad value or no pysplashsurf: refused before anything is written
    scene = load_scene(args.scene, scale=args.scale, run_anyway=True if args.run_anyway else None)
    frames = scene.output.frames if args.frames is None else args.frames
    outputs = Outputs(args.out or f"out/{scene.name}.usdc")
    outputs.check()
    if args.dry_run:
        return _dry_run(scene, frames, outputs, args)
    with output_lock(outputs.out):
        return _run_locked(args, scene, frames, outputs, surface)


def _run_locked(args, scene, frames, outputs, surface):
    """run_command's part that holds the output's lock."""
    refusal = _refusal(outputs, args.overwrite)
    if refusal is not None:
        raise refusal
    device, devices = _pick_devices(args)
    if devices is None:
        meshed_here = int(surface["surface"]) and surface["surface_method"] == "preview"  # on the run's device
        sim = Simulation(scene, device=device,  # with the diagnostics' kernels, and the preview mesher's
                         preload=frame_modules(scene) + (surface_modules() if meshed_here else []))
    else:
        sim = DecomposedSimulation(scene, devices, subdomains=args.subdomains)
        device = ",".join(devices) + f" ({sim.count} subdomains along {'xyz'[sim.axis]})"
    sim.on_instability = args.on_instability
    fields = parse_fields(args.fields, sim)  # refused before the outputs are touched
    for path in outputs.existing():
        outputs.remove(path)
    logger.info(f"{scene.name} on {device}: {sim.num_fluid} fluid + {sim.num_boundary} boundary particles, "
                f"r = {scene.particle_radius:.4g} m, {frames} frames at {scene.output.fps:g} fps -> {outputs.out}",
                extra=PLAIN)
    options = {"checkpoint_every": args.checkpoint_every, "on_instability": args.on_instability, "clips": int(args.clips),
               "preview": args.preview, "particles_h5": int(args.particles_h5), "fields": ",".join(fields), **surface}
    return _simulate(sim, outputs, frames, args, options, append=None)


def resume_command(args):
    import h5py

    from .io.checkpoint import load_checkpoint

    _check_options(args)
    device, devices = _pick_devices(args)
    checkpoint = Path(args.checkpoint)
    sim = load_checkpoint(checkpoint, device=device)
    if devices is not None:  # the checkpoint's state, split into subdomains
        state = ({k: a.numpy() for k, a in sim.state_arrays().items()}, sim.state_flags())
        sim = DecomposedSimulation(sim.scene, devices, subdomains=args.subdomains, state=state)
        device = ",".join(devices) + f" ({sim.count} subdomains along {'xyz'[sim.axis]})"
    with h5py.File(checkpoint, "r") as f:
        options = {k[4:]: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items() if k.startswith("run:")}
    if "output" not in options:
        raise SceneError(checkpoint, "", "written without the command line's options: continue it from Python "
                                         "(warpsph.io.checkpoint.load_checkpoint)")
    frames = int(options.get("frames", sim.scene.output.frames)) if args.frames is None else args.frames
    if frames < sim.frame:
        raise SceneError("", "--frames", f"the checkpoint is at frame {sim.frame}; expected {sim.frame} or more, got {frames}")
    outputs = Outputs(checkpoint.parent / Path(options["output"]).name)  # the outputs lie beside their checkpoint
    with output_lock(outputs.out):
        return _resume_locked(args, sim, options, frames, outputs, device)


def _resume_locked(args, sim, options, frames, outputs, device):
    """resume_command's part that holds the output's lock."""
    clips = bool(int(options.get("clips", 0)))
    if not (outputs.clips.is_dir() if clips else outputs.out.exists() or outputs.partial.exists()):
        raise SceneError(outputs.out, "", "the cache of this checkpoint's run is missing: it cannot be continued")
    surface = {k: options[k] for k in ("surface", "surface_cube", "surface_smoothing", "surface_every", "surface_behind",
                                       "surface_workers", "surface_method") if k in options}
    surface_options(surface)
    sim.on_instability = options.get("on_instability", "stop")
    logger.info(f"resuming {sim.scene.name} at frame {sim.frame} (t = {sim.time:.3f} s) on {device} -> {outputs.out}",
                extra=PLAIN)
    run_options = {"checkpoint_every": int(options.get("checkpoint_every", 0)), "on_instability": sim.on_instability,
                   "clips": int(clips), "preview": int(options.get("preview", 0)),
                   "particles_h5": int(options.get("particles_h5", 0)), "fields": str(options.get("fields", "")),
                   **surface}
    return _simulate(sim, outputs, frames, args, run_options, append=sim.frame)


def surface_command(args):
    options = SurfaceOptions(cube=args.cube, smoothing=args.smoothing, iso=args.iso, method=args.method)
    source, frames, out, radius = plan_remesh(args.cache, args.frames, args.out, args.radius, args.overwrite, options)
    device = _pick_device(args.device) if options.method == "preview" else "cpu"
    logger.info(f"meshing {len(frames)} frames of {args.cache} ({options.method}"
                + (f" on {device}" if options.method == "preview" else "") + f", r = {radius:.4g} m, cube "
                f"{options.cube:g} r, smoothing length {options.smoothing:g} r) -> {out}", extra=PLAIN)
    partial = out.with_name(out.stem + ".partial" + out.suffix)
    try:
        done = remesh(source, frames, out, radius, options, log=logger.info, device=device)
    except Exception as exc:  # a full disk, a quota: one line (the saves are whole: nothing is half-written)
        if not _write_failure(exc):
            raise
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc).strip().splitlines()[-1]
        kept = f"; {partial} keeps the frames of its last save" if partial.exists() else ""
        logger.error("%s", f"cannot write {out}: {reason}" + (f" ({out} is as it was)" if out.exists() else "") + kept)
        return 2
    logger.info(f"wrote {out}: {done['frames']} frames, {done['seconds'] / max(done['frames'], 1):.2f} s per frame, "
                f"{done['triangles'] / max(done['frames'], 1):.0f} triangles per frame")
    return 0


def plot_energy_command(args):
    out = check_new_file(args.out, "--out", args.overwrite)
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    print(f"wrote {plot_energy(args.runs, str(out), args.labels)}")
    return 0


def plot_slice_command(args):
    out = check_new_file(args.out, "--out", args.overwrite)
    out.absolute().parent.mkdir(parents=True, exist_ok=True)
    path, shown = slice_from_cache(args.run, args.frame, args.axis, str(out))
    print(f"wrote {path} ({shown} particles in the slab)")
    return 0


def validate_command(args):
    case, resolutions, out = check_arguments(args.case, args.resolutions, args.json)
    if out is not None:
        check_new_file(out, "--json", args.overwrite)
    device = _pick_device(args.device)
    report = validate(case, resolutions, args.methods, device, out, log=logger.info, solver=args.solver,
                      command=" ".join(["warpsph", "validate", case, "--resolutions", *map(str, resolutions),
                                        "--methods", *args.methods, "--device", args.device]
                                       + (["--solver", args.solver] if args.solver else [])
                                       + (["--json", str(args.json)] if args.json else [])))
    print(table(report["rows"]))
    if out is not None:
        print(f"wrote {out}")
    return EXIT_UNSTABLE if any(r.get("unstable") for r in report["rows"]) else 0


def schema_command(args):
    import json

    text = reference_markdown() if args.markdown else json.dumps(scene_json_schema(), indent=2) + "\n"
    if args.out:
        out = check_new_file(args.out, "--out", args.overwrite)
        out.absolute().parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, out)
        print(f"wrote {out}")
    else:
        sys.stdout.write(text)
    return 0


def sweep_command(args):
    table = run_sweep(args.sweep, args.out, **executor_arguments(args))
    print((Path(args.out) / "table.md").read_text(), end="")
    if args.plot:
        print("wrote " + ", ".join(map(str, sweep_figures(table, Path(args.out) / "table"))))
    return 0 if table["complete"] else 1


def study_command(module, device=True):
    """The command of a study module (warpsph.validation: bench, bench_job, pareto, stress, results): its
    ``command(args)`` after ``--device`` is checked (``device`` False: not here; bench job times Warp's start)."""
    def command(args):
        if device and not getattr(args, "plot_only", None):
            args.device = _pick_device(args.device)
        args.run_cli, args.last_run = main, last_run  # bench job runs `warpsph run` in this process
        return module.command(args)
    return command


def build_parser():
    parser = argparse.ArgumentParser(prog="warpsph", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"warpsph {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run, resume = _run_parsers(sub)
    kinds = _plot_parser(sub)
    _surface_parser(sub)
    _validate_parser(sub)
    _sweep_parser(sub)
    _study_parsers(sub, kinds)
    _schema_parser(sub)
    _verbosity_flags(parser, default=0)
    return parser




def _run_parsers(sub):
    """``warpsph run`` and ``warpsph resume`` (their shared options last)."""
    run = sub.add_parser("run", help="simulate a scene and write a USD point cache")
    run.add_argument("scene", help="scene file (JSON), e.g. scenes/dam_break.json")
    run.add_argument("--out", help="output .usdc/.usda file (default out/<scene name>.usdc)")
    run.add_argument("--scale", type=float, default=1.0,
                     help="particle-count factor: 0.1 runs about a tenth of the particles (radius / scale^(1/3))")
    run.add_argument("--overwrite", action="store_true", help="replace an existing output (refused otherwise)")
    run.add_argument("--checkpoint-every", type=int, default=0, metavar="N",
                     help="write OUT.checkpoint.h5 every N frames (atomically; the latest one is kept)")
    run.add_argument("--on-instability", choices=["stop", "reduce-dt"], default="stop",
                     help="stop with a diagnostic (default), or redo an unstable frame from its start with dt halved (up to 4 times)")
    run.add_argument("--clips", action="store_true",
                     help="large runs: one USD layer per frame in OUT.clips/, stitched into OUT with value clips")
    run.add_argument("--particles-h5", action="store_true",
                     help="also write every frame's particles to OUT.particles.h5 (for numpy/pandas)")
    run.add_argument("--preview", type=int, default=0, metavar="K",
                     help="every K frames write OUT.preview.FRAME.png, a mid-depth slab coloured by vorticity (or speed)")
    run.add_argument("--fields", metavar="NAMES",
                     help="comma-separated USD arrays to write: points (required), velocities, ids, widths and the "
                          "scene's fields (density, vorticity, vorticity_magnitude, angular_velocity, ...); default all. "
                          "ids and widths get a time sample only when they change (particles are written in id order)")
    run.add_argument("--dry-run", action="store_true", help="print particle counts and the memory estimate, run nothing")
    run.add_argument("--run-anyway", action="store_true",
                     help="a SPlisHSPlasH scene: run without the physics warpsph refuses (the list is printed and recorded "
                          "in the cache's metadata warpsph:import_dropped and in OUT.stats.meta.json)")
    _surface_run_options(run)
    run.set_defaults(func=run_command)
    resume = sub.add_parser("resume", help="continue a run from its checkpoint")
    resume.add_argument("checkpoint", help="OUT.checkpoint.h5 written by --checkpoint-every or at Ctrl-C")
    resume.set_defaults(func=resume_command)
    for p in (run, resume):
        p.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto (CUDA when present)")
        p.add_argument("--devices", help="D[,D...] or N: one simulation over several devices, a slab of the domain "
                                          "each (e.g. cuda:0,cuda:1, or 2 for the first two GPUs; emitters, sinks, "
                                          "dynamic bodies and IISPH not yet)")
        p.add_argument("--subdomains", type=int, help="slabs (default one per --devices entry; several per device "
                                                      "when more)")
        p.add_argument("--frames", type=int, help="last frame to simulate (default: the scene's output.frames)")
        p.add_argument("--sync-output", action="store_true",
                       help="write each frame on the simulation's thread (default: a background writer thread, "
                            "so the simulation goes on while a frame is written)")
        p.add_argument("--cache-process", action=argparse.BooleanOptionalAction, default=None,
                       help="write the single-file cache in a process of its own, so that USD's encoding and saves "
                            "never hold the simulation's thread (default: on a GPU run)")
    return run, resume


def _surface_run_options(run):
    """``warpsph run``'s --surface options."""
    run.add_argument("--surface", action="store_true",
                     help="also write the fluid's surface mesh /World/FluidSurface every frame (see "
                          "--surface-method)")
    run.add_argument("--surface-cube", type=float, default=0.75, metavar="C",
                     help="marching-cubes cell of the surface in particle radii (default 0.75; 0.5 is finer)")
    run.add_argument("--surface-smoothing", type=float, default=2.0, metavar="L",
                     help="smoothing length of the surface's colour field in particle radii (default 2.0)")
    run.add_argument("--surface-method", choices=["splashsurf", "preview"], default=None,
                     help="preview (the default on a GPU: Warp's sparse marching cubes and Taubin smoothing on the "
                          "simulation's device, between its steps) or splashsurf (the default on the CPU: on the "
                          "host's cores, needs pip install 'warpsph[surface]')")
    run.add_argument("--surface-every", type=int, default=1, metavar="K",
                     help="mesh every K-th frame only (default 1); a frame between holds the last mesh")
    run.add_argument("--surface-workers", type=int, default=0, metavar="N",
                     help="splashsurf: frames meshed at once, each in a process of its own on its share of the cores "
                          "(default 0: one per 4 cores beyond two, at most 4)")
    run.add_argument("--surface-behind", choices=["wait", "skip"], default="wait",
                     help="when the mesher is behind (one frame waits while one is meshed): wait (default: every asked "
                          "frame gets its mesh, the simulation waits) or skip the frame (the simulation never waits "
                          "for meshing; skipped frames are counted at the end and in the cache's metadata)")


def _plot_parser(sub):
    """``warpsph plot energy|slice`` (``plot results`` is a study: :func:`_study_parsers`); returns its kinds."""
    plot = sub.add_parser("plot", help="PNG plots of finished runs (needs matplotlib)")
    kinds = plot.add_subparsers(dest="kind", required=True)
    energy = kinds.add_parser("energy", help="energy over time for several runs (like Fig 7 of the VR paper)")
    energy.add_argument("runs", nargs="+", help="OUT.usdc of each run (or its OUT.stats.csv)")
    energy.add_argument("--labels", nargs="+", help="one label per run")
    energy.add_argument("--out", default="energy.png")
    energy.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    energy.set_defaults(func=plot_energy_command)
    slab = kinds.add_parser("slice", help="particles in a thin slab coloured by vorticity magnitude")
    slab.add_argument("run", help="OUT.usdc (or the top-level OUT.usda of a --clips run)")
    slab.add_argument("--frame", type=int, default=0)
    slab.add_argument("--axis", choices=["x", "y", "z"], default="z")
    slab.add_argument("--out", default="slice.png")
    slab.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    slab.set_defaults(func=plot_slice_command)
    return kinds


def _surface_parser(sub):
    """``warpsph surface``: mesh a finished run."""
    mesh = sub.add_parser("surface", help="mesh the fluid surface of a finished run into a new USD file "
                                          "(it sublayers the cache), without simulating again")
    mesh.add_argument("cache", help="OUT.usdc (single file or the top-level file of --clips) or OUT.particles.h5")
    mesh.add_argument("--out", help="the new file (default CACHE.surface.usdc beside the cache)")
    mesh.add_argument("--frames", type=int, nargs=2, metavar=("A", "B"), help="mesh frames A..B only (default all)")
    mesh.add_argument("--cube", type=float, default=0.75, help="marching-cubes cell in particle radii (default 0.75)")
    mesh.add_argument("--smoothing", type=float, default=2.0, help="smoothing length in particle radii (default 2.0)")
    mesh.add_argument("--iso", type=float, help="iso threshold of the colour field (default 0.6)")
    mesh.add_argument("--method", choices=["splashsurf", "preview"], default="splashsurf",
                      help="splashsurf (default) or preview (Warp's sparse marching cubes, see run --surface-method)")
    mesh.add_argument("--device", default="cpu", help="device of --method preview: cpu (default), cuda, cuda:N or auto")
    mesh.add_argument("--radius", type=float, help="particle radius in metres (default: the cache's widths / 2)")
    mesh.add_argument("--overwrite", action="store_true", help="replace an existing --out that warpsph wrote")
    mesh.set_defaults(func=surface_command)


def _validate_parser(sub):
    """``warpsph validate``: the validation cases."""
    check = sub.add_parser("validate", help="validation cases with the default solver: error, particles, steps and "
                                            "wall time per method and resolution (JSON and a table)")
    check.add_argument("case", metavar="CASE", help="taylor-green, lamb-oseen, vortex-surface, standing-wave, hydrostatic, dam-front, tank-at-rest, "
                            "sinking-sphere or poiseuille")
    check.add_argument("--resolutions", nargs="+", required=True, metavar="N",
                       help="integers >= 4: particles across L (vortices), along the tank (standing-wave), across the water cube (hydrostatic) or "
                            "across the column width a (dam-front), across the 0.4 m tank (tank-at-rest), across the "
                            "sphere's diameter (sinking-sphere) or across the 0.2 m channel (poiseuille)")
    check.add_argument("--methods", nargs="+", default=["dfsph"], choices=list(METHODS),
                       help="dfsph (the solver alone, default), vr, rankine, micropolar")
    check.add_argument("--solver", choices=solver_names(),
                       help="pressure solver (scene key solver.method; default: the scenes' default, dfsph)")
    check.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto (CUDA when present)")
    check.add_argument("--json", metavar="OUT.json", help="write the rows and metadata here (atomically, after every row)")
    check.add_argument("--overwrite", action="store_true", help="replace an existing --json")
    check.set_defaults(func=validate_command)


def _sweep_parser(sub):
    """``warpsph sweep``: many runs over processes, GPUs or a Ray cluster."""
    sweep = sub.add_parser("sweep", help="many runs (a validation case or a scene file, a sweep file's axes) over "
                                         "processes, GPUs or a Ray cluster; resumable (one file per cell, then "
                                         "table.json and table.md)")
    sweep.add_argument("sweep", metavar="SWEEP.json", help="sweep file: base (a validation case) or scene (a scene "
                                                           "file), axes, measures (see warpsph/sweep.py)")
    sweep.add_argument("--out", required=True, metavar="DIR", help="output folder (cells/, table.json, table.md); "
                                                                   "running again skips the finished cells")
    add_executor_arguments(sweep, default_devices="the sweep file's device, else cpu")
    sweep.add_argument("--plot", action="store_true", help="also DIR/table.pareto.png (with a time and an error "
                                                           "measure) and DIR/table.heat_map.png (needs matplotlib)")
    sweep.set_defaults(func=sweep_command)


def _study_parsers(sub, kinds):
    """The studies whose modules bring their own arguments: bench steps|job, pareto, stress, plot results, warmup."""
    def study(subparsers, name, module, text, device=True):
        p = subparsers.add_parser(name, help=text, description=module.__doc__,
                                  formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(func=study_command(module, device))

    benches = sub.add_parser("bench", help="benchmarks: ms per step and per stage (steps); the whole job with its "
                                           "output, and the time to the first step (job)")
    benches = benches.add_subparsers(dest="kind", required=True)
    study(benches, "steps", bench, "a scene at ~N fluid particles: ms per step in total and per stage, memory")
    study(benches, "job", bench_job, "warpsph run with its USD output against the solver alone; the start-up",
          device=False)
    study(sub, "pareto", pareto, "cost against accuracy per method, resolution and solver tolerance; the Pareto front")
    study(sub, "stress", stress, "stability matrix: the scene as plain DFSPH with one parameter changed per cell")
    study(kinds, "results", results, "the figures of result JSON files (validation, Pareto, stress, benchmark sizes)",
          device=False)
    study(sub, "warmup", warmup, "compile the kernels (all, or those of --scene files) into Warp's kernel cache "
                                 "in one parallel pass, ahead of a first run")


def _schema_parser(sub):
    """``warpsph schema``: the scene file's JSON Schema or its markdown reference."""
    schema = sub.add_parser("schema", help="the scene file's JSON Schema (for editors), or with --markdown the "
                                           "scene reference: every key, type, unit, default and range")
    schema.add_argument("--markdown", action="store_true", help="the scene reference as markdown instead")
    schema.add_argument("--out", help="write it to this file instead of stdout")
    schema.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    schema.set_defaults(func=schema_command)


def _verbosity_flags(parser, default):
    """-q/--quiet, -v/--verbose and --log on ``parser`` and on each of its subcommands (where they default
    to nothing, so that a flag before the subcommand holds)."""
    parser.add_argument("-q", "--quiet", action="count", default=default,
                        help="warnings and errors only: no progress, no info lines")
    parser.add_argument("-v", "--verbose", action="count", default=default,
                        help="debug lines too (e.g. each frame's wall time and steps)")
    parser.add_argument("--log", metavar="FILE", default=None if default == 0 else default,
                        help="also append the log lines (at the level -q/-v choose) to FILE, each with its time; "
                             "they still go to stderr")
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _verbosity_flags(sub, argparse.SUPPRESS)


def main(argv=None):
    args = build_parser().parse_args(argv)
    level = log.verbosity(args.quiet, args.verbose)
    try:
        undo = log.configure(level, file=args.log)
    except SceneError as exc:  # --log cannot be written: said on stderr alone
        undo = log.configure(level)
        logger.error("%s", exc)
        undo()
        return 2
    try:
        return args.func(args)
    except SceneError as exc:
        logger.error("%s", exc)
        return 2
    except KeyboardInterrupt as exc:  # a sweep's SweepInterrupted says what it kept, and may be a SIGTERM
        logger.warning("%s", str(exc) or "interrupted", extra=PLAIN)
        return 128 + int(getattr(exc, "signum", signal.SIGINT))
    finally:
        undo()


if __name__ == "__main__":
    sys.exit(main())
