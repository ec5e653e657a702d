"""Per-frame particle data in HDF5 (``--particles-h5``), for analysis in numpy or pandas.

``OUT.particles.h5`` holds one group per frame, ``frames/000012``, with datasets ``x``, ``v``,
``ids`` and every published field (``density``, ``vorticity``, ...), and attributes ``time``
and ``step``. Read it with ``h5py.File(path)["frames/000012/x"][...]``.
"""

from __future__ import annotations

from pathlib import Path

import h5py

FORMAT = "warpsph-particles-1"


class ParticleFrames:
    """An ``on_frame`` callback that appends each frame to an HDF5 file (flushed every frame).
    ``append``: continue the file after frame ``append`` (later frames are dropped)."""

    def __init__(self, path, append=None):
        self.path = Path(path)
        self.file = h5py.File(self.path, "w" if append is None else "a")
        self.file.attrs["format"] = FORMAT
        self.frames = self.file.require_group("frames")
        for name in list(self.frames) if append is not None else ():
            if int(name) > append:
                del self.frames[name]

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
        self.file.flush()

    def close(self):
        """Closes the file (the frames written so far are in it)."""
        self.file.close()


def is_particles_h5(path):
    """Whether ``path`` is an HDF5 file of particle frames that warpsph wrote."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == FORMAT or set(f) == {"frames"}
    except Exception:  # h5py raises OSError, and others for damaged files
        return False
