"""HDF5 checkpoints (h5py): the complete state of a simulation, written atomically.

A checkpoint holds the scene (as JSON) and its hash, the Warp version, the clock (time, dt,
previous dt, step, frame), every fluid array that carries state between steps (positions,
velocities, ids, the solvers' warm-start pressures) and every model's ``state()`` arrays
and flags. Restoring it into a new :class:`Simulation` continues the run bit for bit on ``cpu``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import h5py
import numpy as np
import warp as wp

from warpsph.errors import SceneError

FORMAT = "warpsph-checkpoint-1"


def scene_json(scene) -> str:
    data = dataclasses.asdict(scene)
    data["models"] = [{"type": type(m).__name__, **dataclasses.asdict(m)} for m in scene.models]
    return json.dumps(data, sort_keys=True)


def scene_hash(scene) -> str:
    return hashlib.sha256(scene_json(scene).encode()).hexdigest()[:16]


def _model_flags(model):
    return {k: v for k, v in vars(model).items() if k.startswith("has_")}


def save_checkpoint(sim, path):
    """Writes the state to ``path`` through a temporary file and a rename: a crash never
    leaves a corrupt file under ``path``."""
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
        f.attrs["step"] = sim.step_count
        f.attrs["frame"] = sim.frame
        f.attrs["time"] = float(sim.time_device.numpy()[0])
        f.attrs["steps_device"] = int(sim.steps_device.numpy()[0])
        f.attrs["dt"] = float(sim.dt.numpy()[0])
        f.attrs["dt_previous"] = float(sim.dt_previous.numpy()[0])
        fluid = f.create_group("fluid")
        fluid["x"] = sim.fluid.x.numpy()
        fluid["v"] = sim.fluid.v.numpy()
        fluid["ids"] = sim.fluid.ids.numpy()
        solver = f.create_group("solver")
        for n, a in enumerate(sim.pressure_solver.pressure_sum):
            solver[f"pressure_sum_{n}"] = a.numpy()
        solver["totals"] = sim.pressure_solver.totals.numpy()
        models = f.create_group("models")
        for m in sim.turbulence_models:
            g = models.create_group(m.name)
            for name, a in m.state().items():
                g[name] = a.numpy()
            for k, v in _model_flags(m).items():
                g.attrs[k] = v
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
        if len(f["fluid/x"]) != sim.num_fluid:
            raise SceneError(path, "", "particle count differs from the scene's")
        sim.fluid.x.assign(f["fluid/x"][...])
        sim.fluid.v.assign(f["fluid/v"][...])
        sim.fluid.ids.assign(f["fluid/ids"][...])
        for n, a in enumerate(sim.pressure_solver.pressure_sum):
            a.assign(f[f"solver/pressure_sum_{n}"][...])
        sim.pressure_solver.totals.assign(f["solver/totals"][...])
        for m in sim.turbulence_models:
            g = f["models"][m.name]
            for name, a in m.state().items():
                a.assign(g[name][...])
            for k in _model_flags(m):
                setattr(m, k, int(g.attrs[k]))
        sim.time_device.assign(np.array([f.attrs["time"]], np.float64))
        sim.steps_device.assign(np.array([f.attrs["steps_device"]], np.int64))
        sim.dt.assign(np.array([f.attrs["dt"]], np.float32))
        sim.dt_previous.assign(np.array([f.attrs["dt_previous"]], np.float32))
        sim.step_count = int(f.attrs["step"])
        sim.frame = int(f.attrs["frame"])
        with wp.ScopedDevice(sim.device):
            sim.neighbours.update(sim.fluid.x)
            sim._compute_density()
    return sim
