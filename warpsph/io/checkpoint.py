"""HDF5 checkpoints (h5py): the complete state of a simulation, written atomically.

A checkpoint holds the scene (as JSON) and its hash, the Warp version, and
``Simulation.state_arrays()`` (positions, velocities, ids, the solvers' warm-start pressures,
the device clock, every model's ``state()``) with ``state_flags()`` (step, frame, model flags). Restoring it into a new :class:`Simulation` continues the run bit for bit on ``cpu``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import h5py
import warp as wp

from warpsph.errors import SceneError

FORMAT = "warpsph-checkpoint-1"


def scene_json(scene) -> str:
    data = dataclasses.asdict(scene)
    data["models"] = [{"type": type(m).__name__, **dataclasses.asdict(m)} for m in scene.models]
    return json.dumps(data, sort_keys=True)


def scene_hash(scene) -> str:
    return hashlib.sha256(scene_json(scene).encode()).hexdigest()[:16]


def save_checkpoint(sim, path, extra=None):
    """Writes the state to ``path`` through a temporary file and a rename: a crash never
    leaves a corrupt file under ``path``. ``extra`` (run options) is kept as ``run:`` attributes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["warp_version"] = wp.__version__
        f.attrs["scene_hash"] = scene_hash(sim.scene)
        f.attrs["scene"] = scene_json(sim.scene)
        f.attrs["scene_file"] = str(sim.scene.source or "")
        f.attrs["particle_radius"] = sim.scene.particle_radius
        f.attrs["time"] = sim.time  # for people; the state is in clock/time
        f.attrs["frame"] = sim.frame
        for k, v in (extra or {}).items():
            f.attrs[f"run:{k}"] = v
        for k, v in sim.state_flags().items():
            f.attrs[f"flag:{k}"] = v
        for name, a in sim.state_arrays().items():
            f[name] = a.numpy()
        f.flush()
        os.fsync(f.id.get_vfd_handle())
    os.replace(tmp, path)


def load_checkpoint(path, scene=None, device=None):
    """A :class:`Simulation` in the checkpoint's state. ``scene`` (the same scene file, loaded
    with the same scale) is checked against the stored hash; by default the scene is read
    from the file named in the checkpoint."""
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation

    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise SceneError(path, "", f"cannot read checkpoint ({exc})") from None
    with f:
        if f.attrs.get("format") != FORMAT:
            raise SceneError(path, "", "not a warpsph checkpoint")
        if scene is None:
            scene_file = f.attrs["scene_file"]
            base = load_scene(scene_file)
            scale = (base.particle_radius / float(f.attrs["particle_radius"])) ** 3
            scene = load_scene(scene_file, scale=scale)
        if scene_hash(scene) != f.attrs["scene_hash"]:
            raise SceneError(path, "", "the scene differs from the one this checkpoint was written for")
        sim = Simulation(scene, device=device)
        if len(f["fluid/x"]) != sim.capacity:
            raise SceneError(path, "", "particle count differs from the scene's")
        for name, a in sim.state_arrays().items():
            a.assign(f[name][...])
        sim.restore_flags({k[5:]: v for k, v in f.attrs.items() if k.startswith("flag:")})
        with wp.ScopedDevice(sim.device):
            sim.neighbours.update(sim.fluid.x)
            sim._compute_density()
    return sim
