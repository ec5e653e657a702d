"""SPlisHSPlasH scene files (doc/file_format.md) converted into warpsph scenes.

Understood: Configuration (particleRadius, timeStepSize, cflMethod, cflFactor, cflMinTimeStepSize,
cflMaxTimeStepSize, gravitation, simulationMethod 4 = DFSPH, the solver keys flat or in a "DFSPH"
block: minIterations, maxIterations, maxError, maxIterationsV, maxErrorV, enableDivergenceSolver,
stopAt, fps/dataExportFPS), Materials (density0, viscosity, vorticityMethod 1 = micropolar with
vorticity/viscosityOmega/inertiaInverse, 3 = vorticity refinement), FluidBlocks (start, end,
translation, scale), RigidBodies (geometryFile, translation, rotationAxis, rotationAngle, scale,
isDynamic, isWall, mapInvert: an inverted wall box is the domain). Every other key is listed in
one warning; an unsupported simulation method is an error.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from warpsph.errors import SceneError

SOLVER_KEYS = {"minIterations": "min_iterations", "maxIterations": "max_iterations", "maxError": "density_max_error",
               "maxIterationsV": "divergence_max_iterations", "maxErrorV": "divergence_max_error",
               "enableDivergenceSolver": "divergence_solver"}
CONFIG_KEYS = {"particleRadius", "timeStepSize", "cflMethod", "cflFactor", "cflMinTimeStepSize", "cflMaxTimeStepSize",
               "gravitation", "simulationMethod", "DFSPH", "stopAt", "fps", "dataExportFPS", "boundaryHandlingMethod",
               *SOLVER_KEYS}
MATERIAL_KEYS = {"id", "density0", "viscosity", "vorticityMethod", "vorticity", "viscosityOmega", "inertiaInverse"}
BLOCK_KEYS = {"id", "start", "end", "translation", "scale"}
BODY_KEYS = {"geometryFile", "translation", "rotationAxis", "rotationAngle", "scale", "isDynamic", "isWall",
             "mapInvert", "id"}


class SplishSplashWarning(UserWarning):
    """Keys of a SPlisHSPlasH scene that warpsph does not support (listed, never silently dropped)."""


def is_splishsplash(data) -> bool:
    return isinstance(data, dict) and "Configuration" in data


def _unknown(section, keys, known, where, out):
    out += [f"{where}.{k}" for k in keys if k not in known]


def _box_bounds(body, base):
    """World bounds of a (wall) body: its mesh's bounds, or SPlisHSPlasH's UnitBox when the file is absent."""
    path = base / body.get("geometryFile", "")
    if path.is_file():
        import trimesh

        lo, hi = trimesh.load(str(path), force="mesh").bounds
    elif Path(body.get("geometryFile", "")).name == "UnitBox.obj":
        lo, hi = np.full(3, -0.5), np.full(3, 0.5)
    else:
        raise SceneError(path, "RigidBodies.geometryFile", "mesh file not found")
    scale = np.asarray(body.get("scale", [1, 1, 1]), float)
    translation = np.asarray(body.get("translation", [0, 0, 0]), float)
    return (lo * scale + translation).tolist(), (hi * scale + translation).tolist()


def convert(data, file) -> dict:
    """A warpsph scene dict from a SPlisHSPlasH scene dict (paths stay relative to ``file``)."""
    file = Path(file)
    base = file.parent
    ignored = []
    config = data.get("Configuration", {})
    _unknown("Configuration", config, CONFIG_KEYS, "Configuration", ignored)
    method = config.get("simulationMethod", 4)
    if method != 4:
        raise SceneError(file, "Configuration.simulationMethod",
                         f"method {method} is not supported: warpsph runs DFSPH (simulationMethod 4)")
    if config.get("boundaryHandlingMethod", 0) != 0:
        ignored.append("Configuration.boundaryHandlingMethod (warpsph uses Akinci particles, method 0)")
    solver_block = dict(config.get("DFSPH", {}))
    _unknown("DFSPH", solver_block, SOLVER_KEYS, "Configuration.DFSPH", ignored)
    solver = {ours: solver_block.get(theirs, config.get(theirs)) for theirs, ours in SOLVER_KEYS.items()}
    solver = {k: v for k, v in solver.items() if v is not None}
    if "divergence_solver" in solver:
        solver["divergence_solver"] = bool(solver["divergence_solver"])
    scene = {"name": file.stem, "particle_radius": config.get("particleRadius", 0.025), "solver": solver}
    if "gravitation" in config:
        scene["gravity"] = config["gravitation"]
    time = {}
    if config.get("cflMethod", 1) == 0:
        time["fixed_dt"] = config.get("timeStepSize", 0.001)
    for theirs, ours in (("cflFactor", "cfl"), ("cflMinTimeStepSize", "dt_min"), ("cflMaxTimeStepSize", "dt_max")):
        if theirs in config:
            time[ours] = config[theirs]
    scene["time"] = time
    fps = config.get("dataExportFPS", config.get("fps", 25))
    output = {"fps": fps}
    if "stopAt" in config and config["stopAt"] > 0:
        output["frames"] = max(1, int(round(config["stopAt"] * fps)))
    scene["output"] = output

    materials = data.get("Materials", [])
    if len(materials) > 1:
        ignored.append(f"Materials[1:] ({len(materials) - 1} more materials: one fluid phase is supported)")
    if materials:
        m = materials[0]
        _unknown("Materials", m, MATERIAL_KEYS, "Materials[0]", ignored)
        scene["fluid"] = {k: m[theirs] for theirs, k in (("density0", "density"), ("viscosity", "viscosity")) if theirs in m}
        method = m.get("vorticityMethod", 0)
        if method == 1:
            scene["models"] = [{"type": "micropolar", **{ours: m[theirs] for theirs, ours in (
                ("vorticity", "transfer_coefficient"), ("viscosityOmega", "viscosity_omega"),
                ("inertiaInverse", "inverse_inertia")) if theirs in m}}]
        elif method == 3:
            scene["models"] = [{"type": "vorticity_refinement"}]
        elif method not in (0,):
            ignored.append(f"Materials[0].vorticityMethod {method} (supported: 1 micropolar, 3 vorticity refinement)")

    blocks = []
    for n, b in enumerate(data.get("FluidBlocks", [])):
        _unknown("FluidBlocks", b, BLOCK_KEYS, f"FluidBlocks[{n}]", ignored)
        scale = np.asarray(b.get("scale", [1, 1, 1]), float)
        translation = np.asarray(b.get("translation", [0, 0, 0]), float)
        ends = [np.asarray(b.get(k, [0, 0, 0]), float) * scale + translation for k in ("start", "end")]
        blocks.append({"start": np.minimum(*ends).tolist(), "end": np.maximum(*ends).tolist()})
    scene["fluid_blocks"] = blocks

    obstacles, domain = [], None
    for n, body in enumerate(data.get("RigidBodies", [])):
        _unknown("RigidBodies", body, BODY_KEYS, f"RigidBodies[{n}]", ignored)
        if body.get("isWall") and body.get("mapInvert"):
            if domain is None:
                lo, hi = _box_bounds(body, base)
                domain = {"min": lo, "max": hi}
                continue
        if body.get("isDynamic"):
            ignored.append(f"RigidBodies[{n}].isDynamic (dynamic bodies are not supported yet: treated as static)")
        obstacles.append({"mesh": body.get("geometryFile", ""), "translation": body.get("translation", [0, 0, 0]),
                          "scale": body.get("scale", [1, 1, 1]), "rotation_axis": body.get("rotationAxis", [0, 1, 0]),
                          "rotation_angle": body.get("rotationAngle", 0.0)})
    if domain is None:
        raise SceneError(file, "RigidBodies", "no container: warpsph needs a wall box (isWall and mapInvert) as its domain")
    scene["domain"] = domain
    scene["obstacles"] = obstacles
    other = [k for k in data if k not in ("Configuration", "Materials", "FluidBlocks", "RigidBodies")]
    ignored += other
    if ignored:
        warnings.warn(f"{file}: SPlisHSPlasH keys not supported, ignored: {', '.join(ignored)}", SplishSplashWarning,
                      stacklevel=3)
    return scene
