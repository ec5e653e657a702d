"""Frames leave the device and are written in the background.

At each output frame the simulation's thread copies the particle arrays a run writes into a set
of host buffers (pinned on CUDA, so the copies are asynchronous DMA on the simulation's stream,
followed by an event) and hands them, with the frame's few host numbers (time, step, body poses,
the diagnostics row), to a writer thread through a bounded pool of buffer sets: the simulation
goes on while the USD frame is written, and a slow disk throttles it (it waits for a free
buffer set) instead of filling the memory. ``background=False`` writes each frame on the
simulation's thread instead (``warpsph run --sync-output``): the same bytes, in the same order.

The copies stay on the simulation's stream, not a stream of their own: they do not hold the host
(pinned buffers, an event), only the kernels queued after them, and a copy stream would overlap
them with the next step only if that step's first kernel writing a copied array (the re-sort,
the densities, the integration) waited for them, which means a wait inside the solver's captured
step, or a device staging copy of every copied array (its memory per particle again, with the
same D2D copy on the simulation's stream). The copies cost about bytes copied / PCIe bandwidth:
1-2 ms a frame at 1M particles (30-40 MB) against ~1 s of steps a frame (#24's H100 dam break:
120 steps of 7.9 ms), so neither was worth its risk.

The writer stops at its first error; the frames before it are complete, and the next
:meth:`FrameWriter.submit`, :meth:`~FrameWriter.flush` or :meth:`~FrameWriter.close` raises
:class:`WriterFailed` naming the frame. ``written`` is the last frame written completely.

Particles are handed to the writers in id order (:func:`id_order`): a particle keeps its index
in every frame whatever the re-sorting on the device did, so the ids (and widths) of a frame are
those of the frame before unless emitters or sinks changed the set, and USD interpolates between
frames point by point.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from warpsph.errors import SceneError

BASE_FIELDS = ("points", "velocities", "ids", "widths")
DEPTH = 3  # buffer sets: one being filled or queued, up to DEPTH - 1 more waiting or being written


def scene_fields(sim):
    """Every field name ``--fields`` accepts for this simulation, in the order they are written."""
    names = list(BASE_FIELDS) + list(sim.fields())
    if "vorticity" in names:
        names.insert(names.index("vorticity") + 1, "vorticity_magnitude")
    return names


def parse_fields(text, sim):
    """``--fields points,velocities,...`` as a tuple of names; None or "all": every field."""
    names = scene_fields(sim)
    if text is None or text.strip() == "all":
        return tuple(names)
    asked = [t.strip() for t in text.split(",") if t.strip()]
    unknown = [t for t in asked if t not in names]
    if unknown:
        raise SceneError("", "--fields", f"unknown field {unknown[0]!r}; this scene has {', '.join(names)} (or all)")
    if "points" not in asked:
        raise SceneError("", "--fields", "points is required (the particles' positions)")
    return tuple(n for n in names if n in asked)


def id_order(ids):
    """The permutation that puts particles in id order (a scatter when the ids are 0..n-1)."""
    n = len(ids)
    if n and int(ids.min()) == 0 and int(ids.max()) == n - 1:  # unique ids: a permutation of 0..n-1
        order = np.empty(n, np.int64)
        order[ids] = np.arange(n, dtype=np.int64)
        return order
    return np.argsort(ids, kind="stable")


@dataclass
class HostFrame:
    """One frame on the host: the particle arrays (id order, ``count`` rows) and the small data."""

    frame: int
    time: float
    step: int
    count: int
    arrays: dict  # "x", "v", "ids" and field names -> numpy arrays
    poses: dict | None = None
    row: dict | None = None  # the diagnostics row
    buffers: dict | None = field(default=None, repr=False)
    events: list = field(default_factory=list, repr=False)  # of the copies, one per CUDA device

    def sorted(self):
        """The arrays in id order (waits for the device copies first)."""
        for event in self.events:
            wp.synchronize_event(event)
        self.events = []
        views = {k: a[: self.count] for k, a in self.buffers.items()}
        order = id_order(views["ids"])
        self.arrays = {k: a[order] for k, a in views.items()}
        return self


class WriterFailed(Exception):
    """The writer could not write ``frame``: ``cause`` is its exception."""

    def __init__(self, frame, cause):
        self.frame, self.cause = frame, cause
        super().__init__(f"frame {frame}: {cause}")


class FrameWriter:
    """Copies each frame's arrays off the device and calls ``write(host_frame)`` for it, on a
    writer thread (``background``) or at once. ``copy``: names of the per-particle arrays to
    copy besides x and ids ("v" and ``sim.fields()`` names)."""

    def __init__(self, sim, write, copy=("v",), depth=DEPTH, background=True):
        self.write = write
        self.names = ["x", "ids"] + [n for n in copy if n not in ("x", "ids")]
        self.background = background
        self.device = sim.device
        self.pinned = any(p.device.is_cuda for p in sim.parts())
        self.capacity = sim.capacity
        self.free = queue.Queue()
        for _ in range(max(1, depth)):
            self.free.put(None)  # allocated on first use
        self.work = queue.Queue()
        self.error = None  # (frame, exception)
        self.written = None  # last frame written completely
        self.frames = 0
        self.seconds = 0.0  # time spent writing (on the writer's thread)
        self.waited = 0.0  # time the simulation's thread waited for a free buffer set
        self._thread = None
        if background:
            self._thread = threading.Thread(target=self._loop, name="warpsph-writer", daemon=True)
            self._thread.start()

    def _sources(self, part):
        f = part.fluid
        fields = part.fields()
        return {n: (f.x if n == "x" else f.v if n == "v" else f.ids if n == "ids" else fields[n]) for n in self.names}

    def _allocate(self, sources):
        out = {}
        for name, a in sources.items():
            host = wp.empty(self.capacity, dtype=a.dtype, device="cpu", pinned=self.pinned)
            out[name] = (host, host.numpy())
        return out

    def check(self):
        """Raises :class:`WriterFailed` when the writer has failed."""
        if self.error is not None:
            raise WriterFailed(*self.error)

    def submit(self, sim, frame, row=None):
        """Copies frame ``frame`` off the device and queues it (blocks while every buffer set is
        in use: the writer is behind)."""
        import time

        self.check()
        parts = [(p, self._sources(p)) for p in sim.parts()]  # one; or the subdomains, each with its rows
        start = time.perf_counter()
        buffers = self.free.get()
        self.waited += time.perf_counter() - start
        self.check()
        if buffers is None:
            buffers = self._allocate(parts[0][1])
        n = sim.num_fluid
        now, step = sim.time, sim.step_count  # host reads before the copies are queued, not after them
        poses = sim.moving_bodies.poses() if sim.moving_bodies is not None else None
        events, first = [], 0
        for part, sources in parts:
            k = part.num_fluid
            with wp.ScopedDevice(part.device):
                for name, a in sources.items():
                    if k:
                        wp.copy(buffers[name][0], a, dest_offset=first, count=k)
                if part.device.is_cuda:
                    events.append(wp.record_event())
            first += k
        item = HostFrame(frame, now, step, n, {}, poses, row,
                         buffers={k: v[1] for k, v in buffers.items()}, events=events)
        item._handle = buffers
        if self.background:
            self.work.put(item)
        else:
            self._write(item)
            self.check()

    def _write(self, item):
        import time

        try:
            if self.error is None:
                start = time.perf_counter()
                self.write(item.sorted())
                self.written = item.frame
                self.frames += 1
                self.seconds += time.perf_counter() - start
        except BaseException as exc:  # the run stops at the next submit
            self.error = (item.frame, exc)
        finally:
            item.arrays = {}
            self.free.put(item._handle)

    def _loop(self):
        while True:
            item = self.work.get()
            try:
                if item is None:
                    return
                self._write(item)
            finally:
                self.work.task_done()

    def flush(self):
        """Waits until every frame submitted is written; raises :class:`WriterFailed` if one failed."""
        if self.background:
            self.work.join()
        self.check()

    def close(self):
        """Writes what is queued and stops the thread (the error, if any, stays in ``error``)."""
        if self._thread is not None:
            self.work.put(None)
            self._thread.join()
            self._thread = None
