"""Per-frame particle data in HDF5 (``--particles-h5``), for analysis in numpy or pandas.

``OUT.particles.h5`` holds one group per frame, ``frames/000012``, with datasets ``x``, ``v``,
``ids`` and every published field (``density``, ``vorticity``, ...), and attributes ``time``
and ``step``. Read it with ``h5py.File(path)["frames/000012/x"][...]``.

The file is never written in place (HDF5 rewrites its metadata as it goes, and a kill or a full
disk in the middle leaves a file h5py cannot open): frames go into a copy, OUT.particles.h5.tmp,
which each save syncs and renames over OUT.particles.h5 (then copies again for the next frames).
``OUT.particles.h5`` holds the frames of the last save, whole, at every moment.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from time import perf_counter

import h5py

from warpsph.io.files import fsync

FORMAT = "warpsph-particles-1"
FLUSH_SHARE = 0.1  # saves (a sync, a rename and a copy of the file) take at most this share of the time


class ParticleFrames:
    """An ``on_frame`` callback that appends each frame to an HDF5 file, saved crash-consistently (see the
    module's docstring) after a frame while a save costs at most ``flush_share`` of the time since the last one
    (None: after every frame), at :meth:`flush` (a checkpoint) and at :meth:`close`.
    ``append``: continue the file after frame ``append`` (later frames are dropped).

    Example:

    ```python
    import h5py
    import warpsph
    from warpsph.io.particles_h5 import ParticleFrames

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    frames = ParticleFrames("dam_break.particles.h5")
    sim.run(frames=3, on_frame=frames)
    frames.close()
    x = h5py.File("dam_break.particles.h5")["frames/000003/x"][...]
    ```
    """

    def __init__(self, path, append=None, flush_share=FLUSH_SHARE):
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".tmp")
        self.flush_share = flush_share
        self.saves = 0
        self._saved = (0.0, 0.0)  # (start, seconds) of the last save
        if self.tmp.exists():
            self.tmp.unlink()  # a killed run's copy: its frames after the last save are not kept
        if append is not None and self.path.exists():
            shutil.copyfile(self.path, self.tmp)
            self.file = h5py.File(self.tmp, "a")
        else:
            self.file = h5py.File(self.tmp, "w")
        self.file.attrs["format"] = FORMAT
        self.frames = self.file.require_group("frames")
        for name in list(self.frames) if append is not None else ():
            if int(name) > append:
                del self.frames[name]
        self._dirty = True
        self.save()  # a new file appears whole and marked

    def __call__(self, sim, frame):
        arrays = {"x": sim.host(sim.fluid.x), "v": sim.host(sim.fluid.v), "ids": sim.host(sim.fluid.ids)}
        arrays.update({field: sim.host(array) for field, array in sim.fields().items()})
        self.write(frame, sim.time, sim.step_count, arrays)

    def write(self, frame, time, step, arrays):
        """One frame: ``arrays`` holds x, v, ids and the fields (a writer thread calls this)."""
        name = f"{frame:06d}"
        if name in self.frames:  # a resumed run rewrites the frames after its checkpoint
            del self.frames[name]
        g = self.frames.create_group(name)
        g.attrs["time"] = time
        g.attrs["step"] = step
        for field, array in arrays.items():
            g[field] = array
        self._dirty = True
        if self._due():
            self.save()

    def _due(self):
        if self.flush_share is None:
            return True
        start, seconds = self._saved
        return perf_counter() - start >= seconds / self.flush_share

    def save(self, reopen=True):
        """The frames written so far into OUT.particles.h5: the copy is synced and renamed over it, then (with
        ``reopen``) copied again for the next frames."""
        if not self._dirty:
            return
        start = perf_counter()
        self.file.flush()
        os.fsync(self.file.id.get_vfd_handle())
        self.file.close()
        self.file = None
        os.replace(self.tmp, self.path)
        fsync(self.path.parent)
        self._dirty = False
        if reopen:
            try:
                shutil.copyfile(self.path, self.tmp)
                self.file = h5py.File(self.tmp, "a")
            except BaseException:  # a full disk: OUT.particles.h5 holds every frame written
                if self.tmp.exists():
                    self.tmp.unlink()
                raise
            self.frames = self.file["frames"]
        self._saved = (start, perf_counter() - start)
        self.saves += 1

    def flush(self):
        """Saves the frames written so far (before a checkpoint claims them)."""
        self.save()

    def close(self):
        """Saves and closes the file (the frames written so far are in it)."""
        if self.file is None:
            return
        if self._dirty:
            self.save(reopen=False)
        else:
            self.file.close()
            self.file = None
            self.tmp.unlink()


def is_particles_h5(path):
    """Whether ``path`` is an HDF5 file of particle frames that warpsph wrote.

    Example:

    ```python
    from warpsph.io.particles_h5 import ParticleFrames, is_particles_h5

    ParticleFrames("empty.particles.h5").close()  # a file of no frames
    assert is_particles_h5("empty.particles.h5") and not is_particles_h5("scenes/dam_break.json")
    ```
    """
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == FORMAT or set(f) == {"frames"}
    except Exception:  # h5py raises OSError, and others for damaged files
        return False
