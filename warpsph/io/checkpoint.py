"""HDF5 checkpoints (h5py): the complete state of a simulation, written atomically.

A checkpoint holds the scene (as JSON, with the scene file's absolute path: its meshes resolve
against it from any working directory) and its hash, the Warp version, and
``Simulation.state_arrays()`` (positions, velocities, ids, the solvers' warm-start pressures,
the device clock, every model's ``state()``) with ``state_flags()`` (step, frame, model flags). Restoring it into a new :class:`Simulation` continues the run bit for bit on ``cpu``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from pathlib import Path

import h5py
import numpy as np
import warp as wp

from warpsph.errors import SceneError
from warpsph.io.files import fsync
from warpsph.scene import Scene, load_scene, model_types, parse_dataclass
from warpsph.simulation import Simulation
from warpsph.solvers import DEFAULT_SOLVER, solver_keys

FORMAT = "warpsph-checkpoint-1"


def scene_json(scene) -> str:
    """The scene as JSON, without the path it was read from."""
    data = dataclasses.asdict(scene)
    data.pop("source")
    data["models"] = [{"type": type(m).__name__, **dataclasses.asdict(m)} for m in scene.models]
    return json.dumps(data, sort_keys=True)


def scene_hash(scene) -> str:
    return hashlib.sha256(scene_json(scene).encode()).hexdigest()[:16]


def save_checkpoint(sim, path, extra=None):
    """Writes the state to ``path`` through a temporary file and a rename: a crash never
    leaves a corrupt file under ``path``. ``extra`` (run options) is kept as ``run:`` attributes.

    Example:

    ```python
    import warpsph
    from warpsph.io.checkpoint import save_checkpoint

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    sim.run(frames=2)
    save_checkpoint(sim, "out/dam_break.checkpoint.h5")  # what `warpsph resume` continues
    ```
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["warp_version"] = wp.__version__
        f.attrs["scene_hash"] = scene_hash(sim.scene)
        f.attrs["scene"] = scene_json(sim.scene)
        f.attrs["scene_file"] = os.path.abspath(sim.scene.source) if sim.scene.source else ""
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
    fsync(path.parent)  # the rename itself survives a power cut


def _same(a, b):
    """Equal JSON values, floats to rounding (a scene reloaded at a --scale)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)
    return a == b


def _stored_scene(f, path):
    """The scene the checkpoint holds, its source the original scene file's absolute path (older
    checkpoints stored it relative to the working directory of the run)."""
    source = Path(f.attrs["scene_file"]).absolute() if f.attrs["scene_file"] else path.absolute()
    stored = json.loads(f.attrs["scene"])
    stored.pop("source", None)
    names = {cls.__name__: key for key, cls in model_types().items()}
    data = {**stored, "models": [{**m, "type": names.get(m["type"], m["type"])} for m in stored["models"]]}
    solver = stored.get("solver")
    if isinstance(solver, dict):  # checkpoints before the solvers' own keys hold every solver's keys: the others go
        owners, method = solver_keys(), solver.get("method", DEFAULT_SOLVER)
        data["solver"] = {k: v for k, v in solver.items() if k not in owners or method in owners[k]}
    scene = parse_dataclass(Scene, data, source)
    stored = {**stored, "solver": dataclasses.asdict(scene.solver)}
    return dataclasses.replace(scene, source=str(source)), stored


def load_checkpoint(path, scene=None, device=None):
    """A :class:`Simulation` in the checkpoint's state. By default the scene is the one stored in
    the checkpoint (its mesh files found beside the original scene file); ``scene`` (the same
    scene file, loaded with the same scale) is checked against it, and so is the original scene
    file while it exists: an edited scene file is refused.

    Example:

    ```python
    import warpsph
    from warpsph.io.checkpoint import load_checkpoint, save_checkpoint

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    sim.run(frames=2)
    save_checkpoint(sim, "out/dam_break.checkpoint.h5")
    sim = load_checkpoint("out/dam_break.checkpoint.h5", device="cpu")
    sim.run(frames=4)  # continues after frame 2, as the first run would have
    ```
    """
    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise SceneError(path, "", f"cannot read checkpoint ({exc})") from None
    with f:
        if f.attrs.get("format") != FORMAT:
            raise SceneError(path, "", "not a warpsph checkpoint")
        try:
            stored, data = _stored_scene(f, path)
        except SceneError:
            raise
        except (KeyError, ValueError, TypeError) as exc:
            raise SceneError(path, "", f"damaged checkpoint ({exc!r})") from None
        if scene is None:
            scene = stored
            if Path(stored.source).is_file():
                base = load_scene(stored.source)
                scene_file = load_scene(stored.source, scale=(base.particle_radius / stored.particle_radius) ** 3)
                if not _same(json.loads(scene_json(scene_file)), json.loads(scene_json(stored))):
                    raise SceneError(path, "", f"the scene differs from the one this checkpoint was written for "
                                               f"({stored.source} was edited since)")
        elif not _same(json.loads(scene_json(scene)), data):
            raise SceneError(path, "", "the scene differs from the one this checkpoint was written for")
        sim = Simulation(scene, device=device)
        if "fluid/x" not in f or len(f["fluid/x"]) != sim.capacity:
            raise SceneError(path, "", "particle count differs from the scene's")
        try:
            for name, a in sim.state_arrays().items():
                if name not in f and name in sim.state.optional:
                    continue  # written before the array existed: it keeps its start
                stored = f[name][...]
                if len(a.shape) == 2 and stored.ndim == 2 and stored.shape[:1] == a.shape[:1] and stored.shape[1] < a.shape[1]:
                    # a row that has grown columns since (a dynamic body's accelerations): they start at zero
                    stored = np.pad(stored, ((0, 0), (0, a.shape[1] - stored.shape[1])))
                a.assign(stored)
        except (KeyError, ValueError, TypeError) as exc:
            raise SceneError(path, "", f"damaged checkpoint ({exc!r})") from None
        sim.restore_flags({k[5:]: v for k, v in f.attrs.items() if k.startswith("flag:")})
        sim.update_densities()
    return sim


def is_checkpoint(path):
    """Whether ``path`` is a checkpoint that warpsph wrote.

    Example:

    ```python
    from warpsph.io.checkpoint import is_checkpoint

    assert not is_checkpoint("scenes/dam_break.json")  # False for any other file, or none
    ```
    """
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == FORMAT
    except Exception:  # h5py raises OSError, and others for damaged files
        return False
