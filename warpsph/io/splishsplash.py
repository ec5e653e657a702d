"""SPlisHSPlasH scene files (its doc/file_format.md) converted into warpsph scenes, read the way
SPlisHSPlasH 2.19 reads them; physics warpsph cannot reproduce is refused, never silently changed.

How SPlisHSPlasH 2.19 reads a scene (Simulator/SimulatorBase.cpp, Utilities/SceneLoader.cpp):

* the pressure solver's parameters only from its block in "Configuration" (``"DFSPH": {...}``);
* a non-pressure method's parameters only from the material's block named after the method
  (``"Standard viscosity": {"viscosity": 0.01}``, ``"Bender et al. 2017": {...}``,
  ``"Liu et al. 2021": {...}``), chosen by ``viscosityMethod``, ``vorticityMethod``, ... (default 0:
  none, so a material without ``viscosityMethod`` is inviscid);
* a material applies to the fluid blocks, models and emitters with its ``id`` (default "Fluid").

Files written for SPlisHSPlasH before 2.16 have the same parameters flat (in "Configuration" or the
material); SPlisHSPlasH 2.19 ignores them and uses its defaults, and so does warpsph, naming each
ignored key and its value in one of :attr:`Conversion.notes` (printed as a warning).

Every key ends up in one of three lists of a :class:`Conversion`: ``mapped`` (key -> warpsph
value), ``refused`` (physics warpsph does not simulate: the key and what it would have changed)
and ``notes`` (approximations, and keys without effect on the simulation: GUI, export, and
keys SPlisHSPlasH does not read either). A scene with refused keys is a :class:`SceneError`
listing each one, unless run anyway: ``convert(..., run_anyway=True)``, the environment variable
``WARPSPH_SPLISHSPLASH_RUN_ANYWAY=1`` or ``"warpsph": {"run_anyway": true}`` in the scene file;
then the list is printed (one :class:`SplishSplashWarning`) and kept: ``conversion_of(scene)``
gives the :class:`Conversion` of a loaded scene (``refused`` is what the run leaves out).

Fluid blocks are filled by SPlisHSPlasH's rule (``sampling.splishsplash_block``): a denseMode 0
block becomes the warpsph block whose lattice is exactly SPlisHSPlasH's (DamBreakModel: 6859
particles, as SPlisHSPlasH prints); denseMode 1 and 2 (staggered lattices) are refused. A FluidModels
entry with an OBJ/PLY mesh becomes a warpsph fluid mesh filled on SPlisHSPlasH's lattice (the scaled
mesh's bounding box corner plus r, spacing 2r, then rotated and translated); particle files are refused.

The container (the first static body with mapInvert) becomes the domain, its faces moved in to where
SPlisHSPlasH's walls hold the fluid (:func:`container_inset`): its boundary particles lie on the mesh
surface, its volume maps hold a fluid at rest :func:`volume_map_standoff` (2.40 r) from it, and warpsph's
wall layer, 1.2 r outside the domain's faces, holds it :func:`wall_layer_standoff` (2.20 r) from itself.
A static body that touches the container then reaches past the faces: its samples behind the wall layer are dropped
(``scene_setup.inside_wall_layer``).

A velocity motor (``TargetVelocityMotorHingeJoints``) that turns a dynamic body against a static one makes that body
kinematic, spinning about the hinge at the target rate (:meth:`_Reader.motor_joints`); other joints are refused.
"""

from __future__ import annotations

import functools
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warpsph import sampling
from warpsph.errors import SceneError
from ..sampling import rotation_matrix
from warpsph.sampling import WALL_OFFSET
from warpsph.solvers import DEFAULT_SOLVER, solver_classes, solver_keys

RUN_ANYWAY_ENV = "WARPSPH_SPLISHSPLASH_RUN_ANYWAY"
REAL_MAX = 1e30  # SPlisHSPlasH's "never" (numeric_limits<Real>::max) for emitEndTime

# pressure solvers (Configuration.simulationMethod) and their blocks
METHODS = {0: "WCSPH", 1: "PCISPH", 2: "PBF", 3: "IISPH", 4: "DFSPH", 5: "Projective Fluids", 6: "ICSPH"}


def solver_methods():
    """The pressure solvers warpsph runs, by SPlisHSPlasH's number: {simulationMethod: solver.method}."""
    return {cls.splishsplash_method: name for name, cls in solver_classes().items()
            if cls.splishsplash_method is not None}

# DFSPH parameter -> (warpsph solver key, SPlisHSPlasH default); the other solvers' blocks have those of these
# whose warpsph key they read (a key of the solver block every solver reads, or one of its own Parameters)
DFSPH_KEYS = {"minIterations": ("min_iterations", 2), "maxIterations": ("max_iterations", 100),
              "maxError": ("density_max_error", 0.01), "maxIterationsV": ("divergence_max_iterations", 100),
              "maxErrorV": ("divergence_max_error", 0.1), "enableDivergenceSolver": ("divergence_solver", True)}
# Configuration keys without effect on what is simulated (GUI, export, performance, scripting aside)
CONFIG_NO_EFFECT = {"pause", "pauseAt", "cameraPosition", "cameraLookat", "numberOfStepsPerRenderUpdate",
                    "renderWalls", "enablePartioExport", "enableVTKExport", "enableRigidBodyExport",
                    "enableRigidBodyVTKExport", "particleAttributes", "enableStateExport", "stateExportFPS",
                    "enableAsyncExport", "enableObjectSplitting", "enableZSort", "stepsPerZSort",
                    "determineThreadIds", "determineNumNeighbors", "determineVelocityChanges", "colorMapType"}
CONFIG_READ = {"particleRadius", "sim2D", "gravitation", "cflMethod", "cflFactor", "cflMinTimeStepSize",
               "cflMaxTimeStepSize", "timeStepSize", "kernel", "gradKernel", "simulationMethod",
               "boundaryHandlingMethod", "stopAt", "dataExportFPS", "scriptFile", *METHODS.values(), *DFSPH_KEYS}
# every parameter of every pressure solver block (flat in files before 2.16)
SOLVER_PARAMS = {"minIterations", "maxIterations", "maxError", "maxIterationsV", "maxErrorV", "enableDivergenceSolver",
                 "stiffness", "exponent", "velocityUpdateMethod", "lambda", "pressureClamping"}

# non-pressure methods: material key -> {number: block name}
VISCOSITY = {1: "Standard viscosity", 2: "Bender and Koschier 2017", 3: "Peer et al. 2015", 4: "Peer et al. 2016",
             5: "Takahashi et al. 2015 (improved)", 6: "Weiler et al. 2018"}
VORTICITY = {1: "Bender et al. 2017", 2: "Vorticity confinement", 3: "Liu et al. 2021"}
DRAG = {1: "Macklin et al. 2014", 2: "Gissler et al. 2017"}
SURFACE_TENSION = {1: "Becker & Teschner 2007", 2: "Akinci et al. 2013", 3: "He et al. 2014", 4: "Jeske et al. 2023",
                   5: "Zorilla, Ritter, et al. 2020"}
ELASTICITY = {1: "Becker et al. 2009", 2: "Peer et al. 2018", 3: "Kugelstadt et al. 2021", 4: "Kee et al. 2023"}
METHOD_BLOCKS = {name for table in (VISCOSITY, VORTICITY, DRAG, SURFACE_TENSION, ELASTICITY) for name in table.values()}
# parameters of the non-pressure methods (flat in files before 2.16); what SPlisHSPlasH reads, per method
METHOD_PARAMS = {
    "XSPH": {"xsph": 0.0, "xsphBoundary": 0.0},
    "Standard viscosity": {"viscosity": 0.01, "viscosityBoundary": 0.0},
    "Bender et al. 2017": {"vorticity": 0.01, "viscosityOmega": 0.1, "inertiaInverse": 0.5},
    "Liu et al. 2021": {"vorticity": 1.0, "kinetmaticViscosity": 0.05},
}
FLAT_METHOD_PARAMS = {"viscosity", "viscosityBoundary", "viscoMaxIter", "viscoMaxError", "viscoMaxIterOmega",
                      "viscoMaxErrorOmega", "vorticity", "viscosityOmega", "inertiaInverse", "kinetmaticViscosity",
                      "drag", "surfaceTension", "surfaceTensionBoundary", "youngsModulus", "poissonsRatio", "alpha",
                      "fixedBoxMin", "fixedBoxMax", "xsph", "xsphBoundary"}
MATERIAL_NO_EFFECT = {"id", "colorField", "colorMapType", "renderMinValue", "renderMaxValue", "visible"}
MATERIAL_EMITTER = {"maxEmitterParticles", "emitterReuseParticles", "emitterBoxMin", "emitterBoxMax"}

BLOCK_KEYS = {"id", "start", "end", "translation", "scale", "denseMode", "initialVelocity", "initialAngularVelocity",
              "visMesh"}
MODEL_KEYS = {"id", "particleFile", "translation", "scale", "rotationAxis", "rotationAngle", "denseMode", "invert",
              "resolutionSDF", "initialVelocity", "initialAngularVelocity", "visMesh"}
EMITTER_KEYS = {"id", "width", "height", "translation", "velocity", "rotationAxis", "rotationAngle", "emitStartTime",
                "emitEndTime", "type"}
BODY_READ = {"geometryFile", "particleFile", "translation", "scale", "rotationAxis", "rotationAngle", "isDynamic",
             "isAnimated", "isWall", "mapInvert", "mapThickness", "density", "velocity", "angularVelocity"}
BODY_NO_EFFECT = {"color", "mapFile", "mapResolution", "samplingMode", "id", "tag", "comment"}
# read by PositionBasedDynamics, SPlisHSPlasH's rigid-body solver: contact between bodies and with the walls
BODY_PBD_CONTACT = {"friction", "restitution", "collisionObjectType", "collisionObjectScale", "collisionObjectFileName",
                    "testMesh", "invertSDF", "resolutionSDF", "thicknessSDF", "boundingBoxMin", "boundingBoxMax",
                    "tubeMapOrder"}
MOTOR = "TargetVelocityMotorHingeJoints"  # the joint warpsph maps (a kinematic body): PositionBasedDynamics' motor
MOTOR_KEYS = ("bodyID1", "bodyID2", "position", "axis")  # without one of them SPlisHSPlasH skips the joint
TOP_KNOWN = {"Configuration", "Materials", "FluidBlocks", "FluidModels", "Emitters", "RigidBodies", "AnimationFields",
             "Simulation", "warpsph"}


# --- where walls hold the fluid (lengths in particle radii r; both codes: cubic spline, support h = 4r) ---------


def _cubic(q):
    """The cubic spline kernel over its value at 0, at q = distance / h."""
    q = np.asarray(q, np.float64)
    return np.where(q <= 0.5, 6.0 * q**3 - 6.0 * q**2 + 1.0, np.where(q <= 1.0, 2.0 * (1.0 - q) ** 3, 0.0))


H = 4.0
W0 = 8.0 / (math.pi * H**3)  # W(0) in 3D


def _integral(values, x):
    return float(np.sum(values[1:] + values[:-1]) * (x[1] - x[0]) / 2.0)


def _rest_distance(boundary):
    """The distance d at which the first layer of a half-space of fluid on the lattice of spacing 2r (volume
    (2r)^3 a particle, in both codes) has rest density: sum_j V W_ij + boundary(d) = 1."""
    a = 2.0 * np.arange(-2, 3)
    x, y, z = np.meshgrid(a, 2.0 * np.arange(3), a, indexing="ij")
    fluid = 8.0 * W0 * float(_cubic(np.sqrt(x * x + y * y + z * z) / H).sum())
    lo, hi = 0.5, H
    for _ in range(60):  # the density falls with the distance
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fluid + boundary(mid) > 1.0 else (lo, mid)
    return 0.5 * (lo + hi)


@functools.lru_cache(maxsize=None)
def volume_map_standoff():
    """Where SPlisHSPlasH's volume maps (boundaryHandlingMethod 2, Bender et al. 2019) hold a fluid at rest:
    the distance from the wall surface, in r (2.40). The boundary adds Psi(d) W(max(d + r/2, 2r)) to rho/rho0:
    Psi(d) = integral over the ball |xi| < h of chi(d + xi_n), chi = 1 behind the surface and W(s)/W(0) at a
    distance s in front of it (SimulatorBase::initVolumeMap), the boundary point max(d + r/2, 2r) behind the
    particle (TimeStep::computeVolumeAndBoundaryX). SPlisHSPlasH 2.16 scales Psi and the fluid volume by 0.8;
    2.19 by 1 (fluid volume (2r)^3, and the boundary volumes its API returns are this Psi within the volume
    map's interpolation error, ~3 %)."""
    z = np.linspace(-H, H, 8001)

    def boundary(d):
        s = d + z
        chi = np.where(s <= 0.0, 1.0, _cubic(s / H))
        return _integral(math.pi * (H * H - z * z) * chi, z) * W0 * float(_cubic(max(d + 0.5, 2.0) / H))

    return _rest_distance(boundary)


@functools.lru_cache(maxsize=None)
def wall_layer_standoff():
    """Where warpsph's wall layer holds a fluid at rest: the distance from the layer, in r (2.20). The layer is a
    square lattice of spacing 2r with Akinci et al.'s volumes V_b = 1 / sum_k W_bk (kernels/boundary.py); its
    sum sum_b V_b W_ib is taken as a sheet of V_b / (2r)^2 per area (the fluid is not aligned with the layer)."""
    a = 2.0 * np.arange(-2, 3)
    x, z = np.meshgrid(a, a, indexing="ij")
    volume = 1.0 / (W0 * float(_cubic(np.sqrt(x * x + z * z) / H).sum()))
    rho = np.linspace(0.0, H, 8001)

    def boundary(d):
        return volume / 4.0 * _integral(W0 * _cubic(np.sqrt(rho * rho + d * d) / H) * 2.0 * math.pi * rho, rho)

    return _rest_distance(boundary)


def container_inset(boundary_method, map_thickness, radius):
    """How far inside SPlisHSPlasH's container surface warpsph's domain faces go [m] so that its fluid rests where
    SPlisHSPlasH's does, and how that was found. warpsph's fluid rests ``wall_layer_standoff`` r from its wall
    layer, which stands WALL_OFFSET r outside the faces. SPlisHSPlasH's boundary particles (method 0) lie on the
    mesh surface; a volume map (2) holds the fluid ``volume_map_standoff`` r from the surface, moved out by
    mapThickness (the map of an inverted mesh is thickness - distance)."""
    if boundary_method == 2:
        inset = (volume_map_standoff() - wall_layer_standoff() + WALL_OFFSET) * radius - map_thickness
        return inset, (f"a volume map holds the fluid {volume_map_standoff():.2f} r from its surface, warpsph's wall "
                       f"layer {wall_layer_standoff():.2f} r from itself, {WALL_OFFSET:g} r outside the domain's faces")
    why = ("boundary particles on the mesh surface, warpsph's wall layer " if boundary_method == 0 else
           f"boundaryHandlingMethod {boundary_method}: where it holds the fluid is not derived; warpsph's wall layer "
           "on the surface, as SPlisHSPlasH's boundary particles (method 0), ")
    return WALL_OFFSET * radius, why + f"{WALL_OFFSET:g} r outside the domain's faces"


def body_inset(boundary_method, map_thickness, radius):
    """Where warpsph samples an imported body so that its fluid rests where SPlisHSPlasH's does: the samples'
    distance inside the mesh surface [r] (negative: outside), and how that was found. warpsph's sample layer holds
    the fluid ``wall_layer_standoff`` r from itself; SPlisHSPlasH's boundary particles (method 0) lie on the
    surface; a volume map (2) holds the fluid ``volume_map_standoff`` r from the surface, mapThickness further
    out. (warpsph's own convention, BODY_INSET = 1.2 r inside, holds it 1.0 r from the surface.)"""
    if boundary_method == 2:
        inset = wall_layer_standoff() - volume_map_standoff() - map_thickness / radius
        return inset, (f"a volume map holds the fluid {volume_map_standoff():.2f} r from the surface"
                       + (f" and mapThickness {map_thickness:g} m further" if map_thickness else "")
                       + f", warpsph's samples {wall_layer_standoff():.2f} r from themselves")
    return 0.0, ("boundary particles on the surface" if boundary_method == 0 else
                 f"boundaryHandlingMethod {boundary_method}: mapped as boundary particles on the surface (method 0)")


class SplishSplashWarning(UserWarning):
    """A SPlisHSPlasH scene runs with approximations, or anyway with physics left out (listed)."""


@dataclass
class Conversion:
    """What became of each key of a SPlisHSPlasH scene."""

    file: str
    scene: dict = field(default_factory=dict)  # the warpsph scene (a dict for parse_dataclass)
    mapped: list = field(default_factory=list)  # "key -> warpsph key = value"
    refused: list = field(default_factory=list)  # "key: what it would have changed"
    errors: list = field(default_factory=list)  # what keeps the scene from running at all (even anyway)
    notes: list = field(default_factory=list)  # approximations; keys without effect
    splishsplash_particles: int | None = None  # fluid particles at t = 0 by SPlisHSPlasH's rules (None: unknown)
    body_insets: list = field(default_factory=list)  # per obstacle: its samples' depth inside its surface [r]
    # per obstacle: the thickness [m] of the volume map a dynamic body holds the fluid with (boundaryHandlingMethod 2,
    # warpsph.volume_maps), or None (its samples hold it)
    volume_maps: list = field(default_factory=list)
    run_anyway: bool = False

    def refusal_text(self):
        return "; ".join(self.refused)

    def their_key(self, ours):
        """The SPlisHSPlasH key that gave the warpsph key ``ours`` (as :attr:`mapped` records it), or None."""
        for line in self.mapped:
            theirs, _, rest = line.partition(" -> ")
            if rest.split(" = ", 1)[0] == ours:
                return theirs
        return None


_CONVERSIONS: dict = {}


def conversion_of(scene):
    """The :class:`Conversion` of a scene loaded from a SPlisHSPlasH file (None for other scenes):
    ``refused`` lists what a run-anyway scene leaves out, for the run's metadata."""
    source = getattr(scene, "source", scene)
    return _CONVERSIONS.get(str(source)) if source is not None else None


def dropped(scene) -> list:
    """What a SPlisHSPlasH scene run anyway leaves out, each "key: what it would have changed" (the run's
    metadata: the USD cache's ``warpsph:import_dropped``, OUT.stats.meta.json); [] for other scenes."""
    conversion = conversion_of(scene)
    return list(conversion.refused) if conversion is not None and conversion.run_anyway else []


def is_splishsplash(data) -> bool:
    return isinstance(data, dict) and "Configuration" in data


def _num(value, default):
    return default if value is None else value


def _fmt(value):
    return json.dumps(value) if not isinstance(value, float) else f"{value:g}"


def _vec(value, default, file, key):
    if value is None:
        return np.asarray(default, np.float64)
    if not isinstance(value, list) or len(value) != 3 or not all(isinstance(v, (int, float)) for v in value):
        raise SceneError(file, key, f"expected a list of 3 numbers, got {json.dumps(value)}")
    return np.asarray(value, np.float64)


def rotation(axis, angle):
    """SPlisHSPlasH's AngleAxis rotation matrix (columns: the rotated x, y, z axes)."""
    return sampling.rotation_matrix(axis, angle)


def _axis_of(vector):
    """(axis index, sign) when ``vector`` is a coordinate axis, else None."""
    k = int(np.argmax(np.abs(vector)))
    if abs(abs(vector[k]) - 1.0) > 1e-6 or np.sum(np.abs(vector)) - abs(vector[k]) > 1e-6:
        return None
    return k, (1.0 if vector[k] > 0 else -1.0)


def _filled_mesh_points(path, mesh, spacing):
    """The fluid a warpsph fluid mesh holds (scene_setup.fluid_mesh_points without the checks); None when the
    mesh cannot be read or is open (the scene is refused later, naming it)."""
    try:
        m = sampling.load_mesh(path)
    except SceneError:
        return None
    if not m.is_watertight:
        return None
    local = sampling.fill_mesh(np.asarray(m.vertices) * np.asarray(mesh["scale"]), m.faces, spacing)
    return local @ sampling.rotation_matrix(mesh["rotation_axis"], mesh["rotation_angle"]).T + np.asarray(mesh["translation"])


def _box_bounds(body, base, file, key):
    """World bounds of a (wall) body: its mesh's bounds, or SPlisHSPlasH's UnitBox when the file is absent."""
    path = base / body.get("geometryFile", "")
    if path.is_file():
        import trimesh

        lo, hi = trimesh.load(str(path), force="mesh").bounds
    elif Path(body.get("geometryFile", "")).name == "UnitBox.obj":
        lo, hi = np.full(3, -0.5), np.full(3, 0.5)
    else:
        raise SceneError(path, f"{key}.geometryFile", "mesh file not found")
    scale = _vec(body.get("scale"), [1, 1, 1], file, f"{key}.scale")
    translation = _vec(body.get("translation"), [0, 0, 0], file, f"{key}.translation")
    return (lo * scale + translation).tolist(), (hi * scale + translation).tolist()


class _Reader:
    def __init__(self, data, file):
        self.data, self.file, self.base = data, Path(file), Path(file).parent
        self.c = Conversion(file=str(file))
        self.ignored_flat = []  # pre-2.16 flat keys a block's default overrides (SPlisHSPlasH 2.19 ignores them)

    # bookkeeping
    def mapped(self, key, ours, value, flat=False, default=False):
        how = " (flat, the pre-2.16 form: SPlisHSPlasH 2.19 ignores it)" if flat else (
            " (SPlisHSPlasH's default)" if default else "")
        self.c.mapped.append(f"{key} -> {ours} = {_fmt(value)}{how}")

    def refuse(self, key, what):
        self.c.refused.append(f"{key}: {what}")

    def note(self, text):
        self.c.notes.append(text)

    def no_effect(self, where, keys, why):
        if keys:
            self.note(f"{why}: " + ", ".join(f"{where}.{k}" for k in keys))

    # ---------------------------------------------------------------------------------------------
    def run(self):
        d, c = self.data, self.c
        config = d.get("Configuration") or {}
        if not isinstance(config, dict):
            raise SceneError(self.file, "Configuration", "expected an object")
        scene = c.scene
        scene["name"] = self.file.stem
        radius = _num(config.get("particleRadius"), 0.025)
        if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not (math.isfinite(radius) and radius > 0):
            raise SceneError(self.file, "Configuration.particleRadius", f"expected a number > 0, got {_fmt(radius)}")
        self.radius = float(radius)
        scene["particle_radius"] = self.radius
        self.mapped("Configuration.particleRadius", "particle_radius", self.radius, default="particleRadius" not in config)
        self.sim2d = bool(config.get("sim2D", False))
        self.configuration(config)
        phases = self.phases()
        self.materials(phases)
        self.fluid_blocks()
        self.fluid_models()
        joints = [k for k in d if "Joint" in k]
        self.motors = self.motor_joints(joints)
        self.bodies()
        self.emitters()
        if "domain" not in scene:
            self.open_domain()
        else:
            self.fit_inside_walls()
        if d.get("AnimationFields"):
            self.refuse("AnimationFields", f"{len(d['AnimationFields'])} fields that set the particles' velocity (or "
                                           "other quantities) by expressions over time: the fluid would not be driven")
        for k in (k for k in joints if k != MOTOR):
            self.refuse(k, f"{len(d[k]) if isinstance(d[k], list) else ''} joints between rigid bodies (PositionBasedDynamics): "
                           "warpsph has no joints, the bodies would move freely")
        pbd_models = [k for k in d if k in ("TriangleModels", "TetModels")]
        for k in pbd_models:
            self.refuse(k, "cloth/deformable solids (PositionBasedDynamics): warpsph has none")
        if "Simulation" in d:
            self.note("Simulation (PositionBasedDynamics' solver settings for the rigid bodies: contact stiffness, "
                      "iterations) is not mapped: warpsph integrates its bodies itself")
        other = [k for k in d if k not in TOP_KNOWN and k not in joints and k not in pbd_models]
        self.no_effect("", other, "not read by SPlisHSPlasH either")
        if self.ignored_flat:
            self.note("flat (pre-2.16) parameters, which SPlisHSPlasH 2.19 ignores for its defaults, ignored too: "
                      + ", ".join(self.ignored_flat))
        return c

    # ---------------------------------------------------------------------------------------------
    def configuration(self, config):
        scene = self.c.scene
        method = config.get("simulationMethod", 4)
        runs = solver_methods()
        supported = method in runs
        if not supported:
            name = METHODS.get(method, f"method {method}")
            known = " and ".join(f"{METHODS.get(k, k)} ({k})" for k in sorted(runs, reverse=True))
            self.refuse("Configuration.simulationMethod",
                        f"{method} ({name}): warpsph runs {known}; run anyway, DFSPH with "
                        f"SPlisHSPlasH's DFSPH defaults")
        name = METHODS.get(method) if supported else None
        block = config.get(name) if supported else None
        block = block if isinstance(block, dict) else {}
        # IISPH reads minIterations, maxIterations and maxError (TimeStepIISPH); the divergence keys are DFSPH's own
        ours, owners = runs[method] if supported else DEFAULT_SOLVER, solver_keys()
        keys = {k: v for k, v in DFSPH_KEYS.items() if v[0] not in owners or ours in owners[v[0]]}
        solver = {}
        if supported and runs[method] != DEFAULT_SOLVER:
            solver["method"] = runs[method]
            self.mapped("Configuration.simulationMethod", "solver.method", runs[method])
        for theirs, (ours, default) in keys.items():
            if theirs in block:
                value, flat, dflt = block[theirs], False, False
            else:
                value, flat, dflt = default, False, True
                if supported and theirs in config:
                    self.ignored_flat.append(f"Configuration.{theirs} = {_fmt(config[theirs])}")
            if ours == "divergence_solver":
                value = bool(value)
            solver[ours] = value
            self.mapped(f"Configuration.{name or 'DFSPH'}.{theirs}" if not flat else f"Configuration.{theirs}",
                        f"solver.{ours}", value, flat=flat, default=dflt)
        if solver["min_iterations"] > solver["max_iterations"]:
            solver["min_iterations"] = solver["max_iterations"]
        scene["solver"] = solver
        self.no_effect(f"Configuration.{name or 'DFSPH'}", [k for k in block if k not in keys],
                       "not read by SPlisHSPlasH either")
        unused = [k for k in METHODS.values() if k in config and k != METHODS.get(method)]
        self.no_effect("Configuration", unused, "blocks of pressure solvers the scene does not use (SPlisHSPlasH ignores them too)")
        if not supported and METHODS.get(method) in config:
            self.note(f"Configuration.{METHODS[method]}: the parameters of the refused solver are not used")
        if not supported:
            self.no_effect("Configuration", [k for k in config if k in SOLVER_PARAMS and k not in DFSPH_KEYS],
                           "flat solver parameters of the refused solver")
        else:
            self.no_effect("Configuration", [k for k in config if k in SOLVER_PARAMS and k not in keys],
                           "flat parameters of other pressure solvers")

        if self.sim2d:
            self.refuse("Configuration.sim2D", "a 2D simulation (one particle layer, 2D kernels): warpsph runs 3D, "
                                               "the blocks would fill their full depth in z")
        if "gravitation" in config:
            scene["gravity"] = list(_vec(config["gravitation"], [0, -9.81, 0], self.file, "Configuration.gravitation"))
        else:
            scene["gravity"] = [0.0, -9.81, 0.0]
        self.mapped("Configuration.gravitation", "gravity", scene["gravity"], default="gravitation" not in config)
        time = {}
        cfl_method = config.get("cflMethod", 1)
        if cfl_method == 0:
            time["fixed_dt"] = float(_num(config.get("timeStepSize"), 0.001))
            self.mapped("Configuration.timeStepSize", "time.fixed_dt", time["fixed_dt"], default="timeStepSize" not in config)
        else:
            if cfl_method == 2:
                self.note("Configuration.cflMethod 2 (CFL and pressure-solver iterations): warpsph adapts dt by the "
                          "CFL condition only")
            if cfl_method not in (1, 2):
                self.refuse("Configuration.cflMethod", f"{cfl_method}: not a SPlisHSPlasH CFL method")
            for theirs, ours, default in (("cflFactor", "cfl", 0.5), ("cflMinTimeStepSize", "dt_min", 0.0001),
                                          ("cflMaxTimeStepSize", "dt_max", 0.005)):
                value = _num(config.get(theirs), default)
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
                    raise SceneError(self.file, f"Configuration.{theirs}", f"expected a number > 0, got {_fmt(value)}")
                time[ours] = float(value)
                self.mapped(f"Configuration.{theirs}", f"time.{ours}", time[ours], default=theirs not in config)
            if time["dt_min"] > time["dt_max"]:
                time["dt_min"] = time["dt_max"]
            if "timeStepSize" in config:
                self.note("Configuration.timeStepSize is only SPlisHSPlasH's first step with adaptive time stepping")
        scene["time"] = time
        # SPlisHSPlasH's step has no viscous limit (its CFL rule alone): the explicit viscosity runs as many sub-steps
        # within its limit as the step needs instead of shortening the step (docs/notes/time-step.md)
        scene["solver"]["viscosity_substeps"] = 0
        fps = float(_num(config.get("dataExportFPS"), 25.0))
        output = {"fps": fps}
        self.mapped("Configuration.dataExportFPS", "output.fps", fps, default="dataExportFPS" not in config)
        self.duration = None
        stop = config.get("stopAt")
        if stop is not None and stop > 0:
            output["frames"] = max(1, int(round(stop * fps)))
            self.duration = output["frames"] / fps
            self.mapped("Configuration.stopAt", "output.frames", output["frames"])
        else:
            self.note("no Configuration.stopAt: SPlisHSPlasH runs until stopped, warpsph its default frame count")
        scene["output"] = output
        boundary = config.get("boundaryHandlingMethod", 2)
        self.boundary_method = boundary
        if boundary != 0:
            self.note(f"Configuration.boundaryHandlingMethod {boundary} (volume/density maps): warpsph samples walls and "
                      "static bodies with boundary particles (Akinci et al. 2012, SPlisHSPlasH's method 0); the domain's "
                      "faces and the static bodies' samples stand where SPlisHSPlasH's boundary holds the fluid (a volume "
                      f"map {volume_map_standoff():.1f} r from its surface)"
                      + ("; dynamic bodies hold the fluid by volume maps (Bender et al. 2019), their samples serve "
                         "their contacts" if boundary == 2 else ""))
        for key in ("kernel", "gradKernel"):
            if config.get(key, 0) not in (0, 4, -1):
                self.note(f"Configuration.{key} {config[key]}: warpsph uses the cubic spline kernel (0)")
        if config.get("scriptFile"):
            self.refuse("Configuration.scriptFile", f"{config['scriptFile']!r}: a Python script that changes the "
                                                    "simulation while it runs: it would not run")
        self.no_effect("Configuration", [k for k in config if k in CONFIG_NO_EFFECT], "GUI, export and performance settings")
        known = CONFIG_READ | CONFIG_NO_EFFECT | SOLVER_PARAMS
        self.no_effect("Configuration", [k for k in config if k not in known], "not read by SPlisHSPlasH either")

    # ---------------------------------------------------------------------------------------------
    def phases(self):
        """The fluid ids in use (blocks, models, emitters; default "Fluid"), in SPlisHSPlasH's order."""
        ids = []
        for key in ("FluidBlocks", "FluidModels", "Emitters"):
            for item in self.data.get(key) or []:
                if isinstance(item, dict):
                    name = item.get("id", "Fluid")
                    if name not in ids:
                        ids.append(name)
        if len(ids) > 1:
            self.refuse("FluidBlocks/FluidModels/Emitters.id", f"{len(ids)} fluid phases ({', '.join(map(repr, ids))}), "
                        "each with its own material: warpsph has one fluid; run anyway, all are the first phase's")
        self.phase = ids[0] if ids else "Fluid"
        return ids

    def materials(self, phases):
        materials = self.data.get("Materials") or []
        fluid = {}
        models = []
        self.c.scene["fluid"] = fluid
        self.c.scene["models"] = models
        self.material = {}
        for n, m in enumerate(materials):
            name = m.get("id", "Fluid") if isinstance(m, dict) else None
            if name == self.phase and not self.material:
                self.material, self.material_key = m, f"Materials[{n}]"
            elif name not in phases:
                self.note(f"Materials[{n}] (id {name!r}) belongs to no fluid of the scene: SPlisHSPlasH does not use it either")
            elif name != self.phase:
                self.note(f"Materials[{n}] (id {name!r}): the material of a refused extra phase")
        m = self.material
        where = getattr(self, "material_key", "Materials")
        if not m:
            self.note(f"no material with id {self.phase!r}: SPlisHSPlasH's defaults (density 1000, no viscosity)")
        fluid["density"] = float(_num(m.get("density0"), 1000.0))
        self.mapped(f"{where}.density0", "fluid.density", fluid["density"], default="density0" not in m)
        used = {"density0"} | MATERIAL_NO_EFFECT | MATERIAL_EMITTER

        def params(block, defaults, methodkey):
            """A method's parameters: its block (2.16+), else flat (pre-2.16), else SPlisHSPlasH's defaults."""
            section = m.get(block) if isinstance(m.get(block), dict) else {}
            out = {}
            for p, default in defaults.items():
                if p in section:
                    out[p] = (section[p], f"{where}.{block}.{p}", False, False)
                else:
                    out[p] = (default, f"{where}.{block}.{p}", False, True)
                    if p in m:
                        self.ignored_flat.append(f"{where}.{p} = {_fmt(m[p])}")
                        used.add(p)
            self.no_effect(f"{where}.{block}", [k for k in section if k not in defaults], "not read by SPlisHSPlasH either")
            return out

        # XSPH is always on in SPlisHSPlasH (coefficients 0 by default)
        xsph = params("XSPH", METHOD_PARAMS["XSPH"], None)
        used.add("XSPH")
        for p, (value, key, flat, dflt) in xsph.items():
            if value:
                self.refuse(key, f"{_fmt(value)}: XSPH velocity smoothing, which warpsph does not have")

        method = m.get("viscosityMethod", 0)
        used.add("viscosityMethod")
        fluid["viscosity"], fluid["boundary_viscosity"] = 0.0, 0.0
        if method == 0:
            self.mapped(f"{where}.viscosityMethod", "fluid.viscosity", 0.0, default="viscosityMethod" not in m)
            if "viscosity" in m:
                used.add("viscosity")
                self.note(f"{where}.viscosity {_fmt(m['viscosity'])} with no viscosityMethod: SPlisHSPlasH (2.8 on) "
                          "runs this fluid without viscosity, and so does warpsph")
        elif method == 1:
            used.add("Standard viscosity")
            p = params("Standard viscosity", METHOD_PARAMS["Standard viscosity"], "viscosityMethod")
            for theirs, ours in (("viscosity", "viscosity"), ("viscosityBoundary", "boundary_viscosity")):
                value, key, flat, dflt = p[theirs]
                fluid[ours] = float(value)
                self.mapped(key, f"fluid.{ours}", fluid[ours], flat=flat, default=dflt)
        elif method in VISCOSITY:
            block = VISCOSITY[method]
            used.add(block)
            section = m.get(block) if isinstance(m.get(block), dict) else {}
            value = section.get("viscosity", m.get("viscosity"))
            self.refuse(f"{where}.viscosityMethod", f"{method} ({block}, an implicit viscosity solver"
                        + (f", viscosity {_fmt(value)}" if value is not None else "")
                        + "): warpsph has the standard explicit viscosity only; run anyway, the fluid is inviscid")
        else:
            self.refuse(f"{where}.viscosityMethod", f"{method}: not a SPlisHSPlasH viscosity method")

        method = m.get("vorticityMethod", 0)
        used.add("vorticityMethod")
        if method == 1:
            used.add("Bender et al. 2017")
            p = params("Bender et al. 2017", METHOD_PARAMS["Bender et al. 2017"], "vorticityMethod")
            model = {"type": "micropolar"}
            for theirs, ours in (("vorticity", "transfer_coefficient"), ("viscosityOmega", "viscosity_omega"),
                                 ("inertiaInverse", "inverse_inertia")):
                value, key, flat, dflt = p[theirs]
                model[ours] = float(value)
                self.mapped(key, f"models.micropolar.{ours}", model[ours], flat=flat, default=dflt)
            models.append(model)
        elif method == 3:
            used.add("Liu et al. 2021")
            p = params("Liu et al. 2021", METHOD_PARAMS["Liu et al. 2021"], "vorticityMethod")
            model = {"type": "vorticity_refinement"}
            for theirs, ours in (("vorticity", "alpha"), ("kinetmaticViscosity", "viscosity")):
                value, key, flat, dflt = p[theirs]
                model[ours] = float(value)
                self.mapped(key, f"models.vorticity_refinement.{ours}", model[ours], flat=flat, default=dflt)
            models.append(model)
        elif method == 2:
            used.add(VORTICITY[2])
            self.refuse(f"{where}.vorticityMethod", "2 (vorticity confinement): warpsph does not have it; run anyway, "
                                                    "no vorticity model")
        elif method != 0:
            self.refuse(f"{where}.vorticityMethod", f"{method}: not a SPlisHSPlasH vorticity method")

        for key, table, what in (("dragMethod", DRAG, "drag by the surrounding air"),
                                 ("surfaceTensionMethod", SURFACE_TENSION, "surface tension"),
                                 ("elasticityMethod", ELASTICITY, "an elastic solid, not a liquid")):
            used.add(key)
            method = m.get(key, 0)
            if method:
                name = table.get(method, f"method {method}")
                used.add(name)
                self.refuse(f"{where}.{key}", f"{method} ({name}): {what}; warpsph does not simulate it"
                            + ("; run anyway, the solid flows as a liquid" if key == "elasticityMethod" else ""))
        # blocks and flat parameters of methods that are not selected
        unused = [k for k in m if k not in used and (k in METHOD_BLOCKS or k in FLAT_METHOD_PARAMS)]
        self.no_effect(where, unused, "parameters of methods the material does not select (SPlisHSPlasH ignores them too)")
        self.no_effect(where, [k for k in m if k in MATERIAL_NO_EFFECT - {"id"}], "colouring")
        self.no_effect(where, [k for k in m if k not in used and k not in METHOD_BLOCKS and k not in FLAT_METHOD_PARAMS],
                       "not read by SPlisHSPlasH either")
        if m.get("emitterReuseParticles") and self.data.get("Emitters"):
            self.refuse(f"{where}.emitterReuseParticles", "emitted particles leaving the box emitterBoxMin..Max are "
                        "re-emitted: warpsph keeps them where they are")

    # ---------------------------------------------------------------------------------------------
    def fluid_blocks(self):
        blocks, self.block_keys = [], []
        total = 0
        for n, b in enumerate(self.data.get("FluidBlocks") or []):
            key = f"FluidBlocks[{n}]"
            scale = _vec(b.get("scale"), [1, 1, 1], self.file, f"{key}.scale")
            translation = _vec(b.get("translation"), [0, 0, 0], self.file, f"{key}.translation")
            lo = scale * _vec(b.get("start"), [0, 0, 0], self.file, f"{key}.start") + translation
            hi = scale * _vec(b.get("end"), [0, 0, 0], self.file, f"{key}.end") + translation
            mode = b.get("denseMode", 0)
            points = sampling.splishsplash_block(lo, hi, self.radius, mode, self.sim2d)
            total += len(points)
            if mode not in (0, 1, 2):
                raise SceneError(self.file, f"{key}.denseMode", f"expected 0, 1 or 2, got {json.dumps(mode)}")
            if not len(points):
                self.note(f"{key} holds no particle by SPlisHSPlasH's rule (it skips the block too)")
                continue
            if mode != 0:
                # no count: pysplishsplash 2.19.0 fills ReadWriteStateTest's block (0.5 x 1 x 0.5 m, r 0.025 m) with
                # 1120 (mode 1) and 1260 (mode 2) particles, not the 1408 and 1760 of createFluidBlocks' 2.x rule
                self.dense_blocks = True
                self.refuse(f"{key}.denseMode", f"{mode} (a staggered, denser lattice): warpsph fills blocks on the cubic "
                            "lattice (denseMode 0); run anyway, the cubic lattice")
                start, end = lo, hi
            else:
                # the warpsph block whose lattice (first point half a spacing in) is SPlisHSPlasH's
                counts = sampling.splishsplash_block_counts(lo, hi, self.radius, 0)
                start = lo + self.radius
                end = start + 2.0 * self.radius * np.asarray(counts, np.float64)
                if self.sim2d:  # run anyway: the full depth in 3D
                    start[2], end[2] = lo[2] + self.radius, lo[2] + self.radius + 2 * self.radius * counts[2]
            block = {"start": start.tolist(), "end": end.tolist()}
            self.mapped(f"{key}.start/end/translation/scale", "fluid_blocks", f"{len(points)} particles")
            velocity = b.get("initialVelocity")
            if velocity is not None:
                block["velocity"] = list(_vec(velocity, [0, 0, 0], self.file, f"{key}.initialVelocity"))
                self.mapped(f"{key}.initialVelocity", f"fluid_blocks[{len(blocks)}].velocity", block["velocity"])
            omega = _vec(b.get("initialAngularVelocity"), [0, 0, 0], self.file, f"{key}.initialAngularVelocity")
            if np.any(omega != 0):
                self.refuse(f"{key}.initialAngularVelocity", f"{omega.tolist()}: the block would start spinning; "
                                                             "warpsph blocks start with one velocity")
            self.no_effect(key, [k for k in b if k == "visMesh"], "meshes for rendering")
            self.no_effect(key, [k for k in b if k not in BLOCK_KEYS], "not read by SPlisHSPlasH either")
            blocks.append(block)
            self.block_keys.append(key)
        self.c.scene["fluid_blocks"] = blocks
        self.block_particles = total

    # ---------------------------------------------------------------------------------------------
    def fluid_models(self):
        """FluidModels: a closed OBJ/PLY mesh becomes a warpsph fluid mesh (SimulatorBase::createFluidModels
        samples it with VolumeSampling::sampleMesh: the mesh scaled, the lattice of spacing 2r from its bounding
        box's lower corner plus r, kept inside; then rotated and translated). Particle files are refused."""
        meshes, self.mesh_keys = [], []
        for n, m in enumerate(self.data.get("FluidModels") or []):
            key = f"FluidModels[{n}]"
            if not isinstance(m, dict):
                raise SceneError(self.file, key, f"expected an object, got {json.dumps(m)}")
            if m.get("id", "Fluid") != self.phase:
                continue  # the refused extra phase
            name = str(m.get("particleFile", ""))
            if Path(name).suffix.lower() not in (".obj", ".ply"):
                self.refuse(f"{key}.particleFile", f"{name!r}: fluid read from a particle file (partio), which "
                                                   "warpsph does not read; this body of fluid would be missing")
                continue
            mode = m.get("denseMode", 0)
            if mode not in (0, 1, 2):
                raise SceneError(self.file, f"{key}.denseMode", f"expected 0, 1 or 2, got {json.dumps(mode)}")
            if mode != 0:
                self.refuse(f"{key}.denseMode", f"{mode} (a staggered, denser lattice): warpsph fills meshes on the "
                                                "cubic lattice (denseMode 0); run anyway, the cubic lattice")
            if m.get("invert"):
                self.refuse(f"{key}.invert", "fluid filling the mesh's bounding box outside the mesh: warpsph fills "
                                             "the inside; run anyway, the inside")
            mesh = {"mesh": name,
                    "translation": list(_vec(m.get("translation"), [0, 0, 0], self.file, f"{key}.translation")),
                    "scale": list(_vec(m.get("scale"), [1, 1, 1], self.file, f"{key}.scale")),
                    "rotation_axis": list(_vec(m.get("rotationAxis"), [1, 0, 0], self.file, f"{key}.rotationAxis")),
                    "rotation_angle": float(_num(m.get("rotationAngle"), 0.0))}
            self.mapped(f"{key}.particleFile/translation/scale/rotationAxis/rotationAngle", f"fluid_meshes[{len(meshes)}]",
                        f"{name} filled at spacing 2r")
            if "initialVelocity" in m:
                mesh["velocity"] = list(_vec(m["initialVelocity"], [0, 0, 0], self.file, f"{key}.initialVelocity"))
                self.mapped(f"{key}.initialVelocity", f"fluid_meshes[{len(meshes)}].velocity", mesh["velocity"])
            omega = _vec(m.get("initialAngularVelocity"), [0, 0, 0], self.file, f"{key}.initialAngularVelocity")
            if np.any(omega != 0):
                self.refuse(f"{key}.initialAngularVelocity", f"{omega.tolist()}: the fluid would start spinning; "
                                                             "warpsph fluid meshes start with one velocity")
            self.note(f"{key}: SPlisHSPlasH keeps the lattice points where a signed distance field of resolution "
                      f"{m.get('resolutionSDF', [20, 20, 20])} is negative; warpsph tests each point against the mesh "
                      "itself (points within the field's error of the surface may differ)")
            self.no_effect(key, [k for k in m if k == "visMesh"], "meshes for rendering")
            self.no_effect(key, [k for k in m if k not in MODEL_KEYS], "not read by SPlisHSPlasH either")
            meshes.append(mesh)
            self.mesh_keys.append(key)
        if meshes:
            self.c.scene["fluid_meshes"] = meshes

    # ---------------------------------------------------------------------------------------------
    def bodies(self):
        obstacles, domain = [], None
        for n, body in enumerate(self.data.get("RigidBodies") or []):
            key = f"RigidBodies[{n}]"
            if not body.get("geometryFile"):
                if body.get("particleFile"):
                    self.refuse(f"{key}.particleFile", "a body given only as boundary particles (no geometryFile): "
                                                       "warpsph samples bodies from meshes; it would be missing")
                else:
                    self.note(f"{key} has neither geometryFile nor particleFile: SPlisHSPlasH skips it too")
                continue
            angle = float(body.get("rotationAngle", 0.0))
            container = body if body.get("mapInvert") and domain is None and not body.get("isDynamic") else None
            if container is not None:
                if angle != 0.0:
                    self.c.errors.append(f"{key}.rotationAngle: the container (mapInvert) is rotated: warpsph's "
                                         "domain is an axis-aligned box")
                    continue
                lo, hi = _box_bounds(body, self.base, self.file, key)
                thickness = float(_num(body.get("mapThickness"), 0.0)) if self.boundary_method == 2 else 0.0
                inset, why = container_inset(self.boundary_method, thickness, self.radius)
                domain = {"min": (np.asarray(lo) + inset).tolist(), "max": (np.asarray(hi) - inset).tolist()}
                self.mapped(f"{key} (mapInvert), Configuration.boundaryHandlingMethod"
                            + (f", {key}.mapThickness" if thickness else ""), "domain",
                            f"min {np.round(domain['min'], 6).tolist()}, max {np.round(domain['max'], 6).tolist()}: the "
                            f"box {np.round(lo, 6).tolist()}..{np.round(hi, 6).tolist()} less {inset / self.radius:.3f} r "
                            f"a face ({why})")
            else:
                obstacle = {"mesh": body["geometryFile"],
                            "translation": list(_vec(body.get("translation"), [0, 0, 0], self.file, f"{key}.translation")),
                            "scale": list(_vec(body.get("scale"), [1, 1, 1], self.file, f"{key}.scale")),
                            "rotation_axis": list(_vec(body.get("rotationAxis"), [1, 0, 0], self.file, f"{key}.rotationAxis")),
                            "rotation_angle": angle}
                kind = "static"
                if n in self.motors:
                    kind = "kinematic"
                    joint, obstacle["motion"], how = self.motors[n]
                    self.mapped(f"{joint} (bodyID1, bodyID2, position, axis, target/targetSequence/repeatSequence)",
                                f"obstacles[{len(obstacles)}].motion", how)
                    self.no_effect(key, [k for k in body if k in BODY_PBD_CONTACT | {"density", "velocity", "angularVelocity"}],
                                   f"rigid-body settings of a body {joint} drives (kinematic in warpsph)")
                elif body.get("isDynamic"):
                    kind = "dynamic"
                    density = float(_num(body.get("density"), 1.0))  # PositionBasedDynamics' default
                    dynamics = {"density": density}
                    for theirs, ours in (("velocity", "velocity"), ("angularVelocity", "angular_velocity")):
                        if theirs in body:
                            dynamics[ours] = list(_vec(body[theirs], [0, 0, 0], self.file, f"{key}.{theirs}"))
                    obstacle["dynamics"] = dynamics
                    self.mapped(f"{key}.density", f"obstacles[{len(obstacles)}].dynamics.density", density,
                                default="density" not in body)
                    self.contact(body, key, f"obstacles[{len(obstacles)}].dynamics", dynamics)
                    self.no_effect(key, [k for k in body if k in BODY_PBD_CONTACT - {"restitution", "friction"}],
                                   "PositionBasedDynamics contact parameters (warpsph's dynamic bodies have their own "
                                   "wall contact)")
                if body.get("isAnimated"):
                    self.refuse(f"{key}.isAnimated", "a body moved by a script or animation: it would stand still")
                thickness = float(_num(body.get("mapThickness"), 0.0)) if self.boundary_method == 2 else 0.0
                inset, why = body_inset(self.boundary_method, thickness, self.radius)
                self.c.body_insets.append(inset)
                self.c.volume_maps.append(thickness if self.boundary_method == 2 and kind == "dynamic" else None)
                if self.c.volume_maps[-1] is not None:
                    self.mapped(f"{key} volume map, Configuration.boundaryHandlingMethod"
                                + (f", {key}.mapThickness" if thickness else ""), f"obstacles[{len(obstacles)}]",
                                f"a volume map of the mesh (thickness {_fmt(thickness)} m) holds the fluid")
                self.mapped(f"{key} boundary, Configuration.boundaryHandlingMethod"
                            + (f", {key}.mapThickness" if thickness else ""),
                            f"obstacles[{len(obstacles)}] samples", f"{inset:+.3f} r inside the surface ({why})")
                obstacles.append(obstacle)
                self.mapped(key, f"obstacles[{len(obstacles) - 1}]", f"{kind} {body['geometryFile']}")
                if body.get("mapInvert"):
                    self.note(f"{key}.mapInvert: a second container; warpsph samples it as an obstacle's surface")
            if body.get("particleFile"):
                self.note(f"{key}.particleFile: warpsph samples the body from geometryFile instead")
            if body.get("mapThickness") and self.boundary_method != 2:
                self.note(f"{key}.mapThickness {_fmt(body['mapThickness'])}: the map thickness of boundaryHandlingMethod "
                          f"{self.boundary_method} is not modelled")
            if not body.get("isDynamic"):
                walls = container is not None and any(b.get("isDynamic") and m not in self.motors
                                                      for m, b in enumerate(self.data.get("RigidBodies") or []))
                used = {"restitution", "friction"} if walls else set()  # in the dynamic bodies' wall contact
                self.no_effect(key, [k for k in body if (k in BODY_PBD_CONTACT or k in ("density", "velocity", "angularVelocity"))
                                     and k not in used],
                               "rigid-body settings of a static body")
            self.no_effect(key, [k for k in body if k in BODY_NO_EFFECT], "rendering and boundary-map settings")
            self.no_effect(key, [k for k in body if k not in BODY_READ | BODY_NO_EFFECT | BODY_PBD_CONTACT],
                           "not read by SPlisHSPlasH either")
        if domain is not None:
            self.c.scene["domain"] = domain
        self.c.scene["obstacles"] = obstacles

    def motor_joints(self, joints):
        """The TargetVelocityMotorHingeJoints that spin a dynamic body against a static one, as warpsph motions:
        {RigidBodies index: (joint key, motion, how)}. PositionBasedDynamics holds the body on the hinge (``position``,
        ``axis``) and sets the relative spin omega2 - omega1 about the axis to the target every step, so the body
        spins kinematically at -target (bodyID1 dynamic) or +target (bodyID2 dynamic). The joints it cannot express
        are refused in one line with their count."""
        if MOTOR not in joints:
            return {}
        items = self.data[MOTOR] if isinstance(self.data[MOTOR], list) else []
        bodies = self.data.get("RigidBodies") or []
        ids = {}  # PositionBasedDynamics' body ids ("id", default 0) of the bodies it loads (those with a geometryFile)
        for n, b in enumerate(bodies):
            if isinstance(b, dict) and b.get("geometryFile"):
                ids.setdefault(b.get("id", 0), []).append(n)
        joined = {}  # body id -> the joints (of every type) it is in
        for k in joints:
            for j in self.data[k] if isinstance(self.data[k], list) else []:
                for name in ("bodyID1", "bodyID2", "rbID"):
                    if isinstance(j, dict) and isinstance(j.get(name), int):
                        joined[j[name]] = joined.get(j[name], 0) + 1
        motors, bad = {}, []
        for i, j in enumerate(items):
            where = f"{MOTOR}[{i}]"
            if not isinstance(j, dict) or any(k not in j for k in MOTOR_KEYS):
                self.note(f"{where} lacks one of {', '.join(MOTOR_KEYS)}: SPlisHSPlasH skips it too")
                continue
            found = self.motor(where, j, ids, joined, bodies)
            if isinstance(found, str):
                bad.append(f"[{i}] {found}")
            elif found is not None:
                n, motion, how = found
                motors[n] = (where, motion, how)
        if bad:
            self.refuse(MOTOR, f"{len(bad)} of {len(items)} motor joints warpsph cannot drive ({'; '.join(bad)}): warpsph "
                               "turns a body only about a hinge against a static body, the bodies would move freely")
        return motors

    def motor(self, where, j, ids, joined, bodies):
        """One motor joint: (RigidBodies index, motion, how), why it cannot be mapped (a str), or None (no effect)."""
        found = []
        for name in ("bodyID1", "bodyID2"):
            if isinstance(j[name], bool) or not isinstance(j[name], int):
                raise SceneError(self.file, f"{where}.{name}", f"expected an integer, got {json.dumps(j[name])}")
            named = ids.get(j[name], [])
            if len(named) != 1:
                return f"{name} {_fmt(j[name])} names " + (f"{len(named)} bodies (their id)" if named else "no body")
            found.append(named[0])
        if found[0] == found[1]:
            return f"joins RigidBodies[{found[0]}] to itself"
        dynamic = [n for n in found if bodies[n].get("isDynamic")]
        if len(dynamic) == 2:
            return f"joins two dynamic bodies (RigidBodies[{found[0]}] and [{found[1]}])"
        if not dynamic:
            self.note(f"{where} joins two static bodies: nothing moves (in SPlisHSPlasH neither)")
            return None
        n = dynamic[0]
        if joined.get(bodies[n].get("id", 0), 0) > 1:
            return f"RigidBodies[{n}] is in {joined[bodies[n].get('id', 0)]} joints: this motor alone does not move it"
        position = _vec(j["position"], [0, 0, 0], self.file, f"{where}.position")
        axis = _vec(j["axis"], [0, 1, 0], self.file, f"{where}.axis")
        if not np.any(axis):
            return "its axis is zero"
        sign = -1.0 if n == found[0] else 1.0  # the target is axis . (omega2 - omega1), the static body at rest
        spin = self.motor_spin(where, j, sign)
        if isinstance(spin, str):
            return spin
        motion, how = {"center": position.tolist(), "axis": axis.tolist(), **spin[0]}, spin[1]
        self.note(f"{where}: PositionBasedDynamics sets the spin to the target at each step's end, so a step late (a "
                  "sequence's target at the step's end); warpsph spins the body at the target from t = 0, the fluid's "
                  "torque on it does not act (PositionBasedDynamics lets it turn the body within a step)")
        return n, motion, (f"RigidBodies[{n}] kinematic: {how} about {_fmt(axis.tolist())} through {_fmt(position.tolist())}"
                           f" ({'-' if sign < 0 else '+'}target: the target is bodyID2's spin less bodyID1's)")

    def motor_spin(self, where, j, sign):
        """A motor's spin as the motion's keys and how, from its target times ``sign``: ``target`` (SPlisHSPlasH reads
        targetSequence only without it) or ``targetSequence`` / ``repeatSequence``; or why it cannot be mapped."""
        if "target" in j:
            if isinstance(j["target"], bool) or not isinstance(j["target"], (int, float)):
                raise SceneError(self.file, f"{where}.target", f"expected a number, got {json.dumps(j['target'])}")
            if "targetSequence" in j:
                self.note(f"{where}.targetSequence: not read when target is given (SPlisHSPlasH reads target)")
            rate = sign * float(j["target"])
            return {"angular_velocity": rate}, f"spins at {_fmt(rate)} rad/s"
        rates = self.motor_sequence(where, j)
        if isinstance(rates, str):
            return rates
        repeat = bool(j.get("repeatSequence", False)) and len(rates) > 1
        return ({"spin_rates": [{"time": t, "rate": sign * w} for t, w in rates], "spin_repeat": repeat},
                f"spins at {_fmt([[t, sign * w] for t, w in rates])} ([time s, rate rad/s], linear between"
                + (", repeated)" if repeat else ")"))

    def motor_sequence(self, where, j):
        """A motor's targetSequence [t0, w0, t1, w1, ...] as [(t, w)] (SPlisHSPlasH drops an odd last value; none:
        target 0), or why it cannot be mapped. PositionBasedDynamics' TimeStepController interpolates the target
        linearly between the pairs, holds the last, and with repeatSequence takes the time less the sequence's
        duration (last - first time) while it exceeds it."""
        seq = j.get("targetSequence", [])
        if not isinstance(seq, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in seq):
            raise SceneError(self.file, f"{where}.targetSequence", f"expected a list of numbers, got {json.dumps(seq)}")
        if len(seq) % 2:
            self.note(f"{where}.targetSequence has an odd number of values: the last, {_fmt(seq[-1])}, is dropped "
                      "(SPlisHSPlasH drops it too)")
        pairs = [(float(seq[k]), float(seq[k + 1])) for k in range(0, len(seq) - 1, 2)]
        if not pairs:
            return [(0.0, 0.0)]  # target 0: the body is held still
        times = [t for t, _ in pairs]
        if times[0] != 0.0:
            return f"targetSequence starts at {_fmt(times[0])} s, not 0 (SPlisHSPlasH reads before the sequence until then)"
        if any(b <= a for a, b in zip(times, times[1:])):
            return f"targetSequence times {_fmt(times)} do not increase"
        if j.get("repeatSequence") and len(pairs) == 1:
            return "repeatSequence of a single (time, target) pair: SPlisHSPlasH never finishes its step"
        return pairs

    def contact(self, body, key, ours, dynamics):
        """A dynamic body's restitution and friction (PositionBasedDynamics' defaults 0.6 and 0.2). Its contacts
        take the product of the two bodies' restitutions and the sum of their frictions; warpsph's walls are the
        container's, so the body's wall contact gets e_body e_container and mu_body + mu_container (between two
        dynamic bodies warpsph takes sqrt(e_a e_b) and the mean of the frictions: not PositionBasedDynamics'
        product and sum of the wall-contact values)."""
        container = next((b for b in self.data.get("RigidBodies") or []
                          if b.get("mapInvert") and not b.get("isDynamic") and b.get("geometryFile")), None)
        walls = container or {}
        e = float(_num(body.get("restitution"), 0.6)) * float(_num(walls.get("restitution"), 0.6))
        mu = float(_num(body.get("friction"), 0.2)) + float(_num(walls.get("friction"), 0.2))
        dynamics["restitution"], dynamics["friction"] = min(max(e, 0.0), 1.0), max(mu, 0.0)
        where = "the container's" if container else "no container: PositionBasedDynamics' defaults for"
        self.mapped(f"{key}.restitution x the container's", f"{ours}.restitution",
                    f"{_fmt(dynamics['restitution'])} (PositionBasedDynamics multiplies the two bodies'; {where} "
                    "restitution)", default="restitution" not in body)
        self.mapped(f"{key}.friction + the container's", f"{ours}.friction",
                    f"{_fmt(dynamics['friction'])} (PositionBasedDynamics adds the two bodies'; {where} friction)",
                    default="friction" not in body)

    def fit_inside_walls(self):
        """Fluid that SPlisHSPlasH starts closer to its container's walls than they hold it at rest (it pushes it
        there in its first steps) is moved into the warpsph domain, keeping its particles: a block, a filled mesh
        or an emitter is shifted; a block wider than the domain keeps the layers that fit."""
        scene, d = self.c.scene, 2.0 * self.radius
        lo, hi = np.asarray(scene["domain"]["min"]), np.asarray(scene["domain"]["max"])

        def shift(key, a, b, move):
            """The shift that brings [a, b] inside [lo, hi] (b - a fits), noted."""
            delta = np.where(a < lo, lo - a, np.where(b > hi, hi - b, 0.0))
            if np.any(delta != 0.0):
                move(delta)
                self.note(f"{key} starts inside the band where SPlisHSPlasH's walls push the fluid away: moved by "
                          f"{_fmt(np.round(delta, 6).tolist())} m into the domain")

        for key, block in zip(self.block_keys, scene.get("fluid_blocks", [])):
            a, b = np.asarray(block["start"]), np.asarray(block["end"])
            wide = [k for k in range(3) if b[k] - a[k] > hi[k] - lo[k] + 1e-9]
            if wide:
                before = int(np.prod(np.round((b - a) / d)))
                for k in wide:
                    layers = int(np.floor((hi[k] - lo[k]) / d + 1e-9))
                    a[k] = lo[k] + 0.5 * (hi[k] - lo[k] - layers * d)
                    b[k] = a[k] + layers * d
                after = int(np.prod(np.round((b - a) / d)))
                self.note(f"{key} is wider along {', '.join('xyz'[k] for k in wide)} than SPlisHSPlasH's walls hold "
                          f"fluid at rest (it starts it compressed): warpsph fills the layers that fit, {after} "
                          f"particles of {before}")
            block["start"], block["end"] = a.tolist(), b.tolist()

            def move(delta, block=block):
                block["start"] = (np.asarray(block["start"]) + delta).tolist()
                block["end"] = (np.asarray(block["end"]) + delta).tolist()

            shift(key, a, b, move)
        for key, mesh in zip(self.mesh_keys, scene.get("fluid_meshes", [])):
            points = _filled_mesh_points(self.base / mesh["mesh"], mesh, d)
            if points is None or not len(points):
                continue

            def move(delta, mesh=mesh):
                mesh["translation"] = (np.asarray(mesh["translation"]) + delta).tolist()

            shift(key, points.min(axis=0) - 0.5 * d, points.max(axis=0) + 0.5 * d, move)
        for key, emitter in zip(self.emitter_keys, scene.get("emitters", [])):
            def move(delta, emitter=emitter):
                emitter["min"] = (np.asarray(emitter["min"]) + delta).tolist()
                emitter["max"] = (np.asarray(emitter["max"]) + delta).tolist()

            shift(key, np.asarray(emitter["min"]), np.asarray(emitter["max"]), move)

    def open_domain(self):
        """A scene without a container (no body with mapInvert): an open domain (no walls; particles that leave
        it are removed and counted) around every body, fluid block and emitter, with a margin of a quarter of
        its extent (at least 8 particle radii) on each side."""
        scene = self.c.scene
        corners = []
        for block in scene.get("fluid_blocks", []):
            corners += [block["start"], block["end"]]
        for e in scene.get("emitters", []):
            corners += [e["min"], e["max"]]
        placed = [("RigidBodies", o) for o in scene.get("obstacles", [])]
        placed += [("FluidModels", m) for m in scene.get("fluid_meshes", [])]
        for where, o in placed:
            lo, hi = _box_bounds({"geometryFile": o["mesh"], "scale": [1, 1, 1], "translation": [0, 0, 0]},
                                 self.base, self.file, where)
            box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            rotated = (box * o["scale"]) @ rotation_matrix(o["rotation_axis"], o["rotation_angle"]).T + o["translation"]
            corners += rotated.tolist()
        if not corners:
            self.c.errors.append("RigidBodies: no container and nothing to bound an open domain with")
            return
        lo, hi = np.min(corners, axis=0), np.max(corners, axis=0)
        margin = np.maximum(0.25 * (hi - lo), 8.0 * self.radius)
        domain = {"min": (lo - margin).tolist(), "max": (hi + margin).tolist(), "walls": False}
        scene["domain"] = domain
        self.mapped("RigidBodies (no container)", "domain (open: no walls, particles leaving it removed)", domain)

    # ---------------------------------------------------------------------------------------------
    def emitters(self):
        emitters = self.data.get("Emitters") or []
        out, self.emitter_keys = [], []
        d = 2.0 * self.radius
        cap = int(_num(self.material.get("maxEmitterParticles"), 10000))
        events = []
        for n, e in enumerate(emitters):
            key = f"Emitters[{n}]"
            if e.get("id", "Fluid") != self.phase:
                continue  # the refused extra phase
            etype = e.get("type", 0)
            width, height = int(e.get("width", 5)), int(e.get("height", 5))
            velocity = float(e.get("velocity", 1.0))
            rot = rotation(_vec(e.get("rotationAxis"), [0, 0, 1], self.file, f"{key}.rotationAxis"),
                           float(e.get("rotationAngle", 0.0)))
            axes = [_axis_of(rot[:, k]) for k in range(3)]
            if etype != 0:
                self.refuse(f"{key}.type", f"{etype} (a circular emitter of diameter {width} particles): warpsph emits "
                                           "rectangular layers only")
                continue
            if any(a is None for a in axes):
                self.refuse(f"{key}.rotationAxis/rotationAngle", "an emitter not aligned with the coordinate axes: warpsph "
                                                                 "emits along x, y or z only")
                continue
            if velocity <= 0:
                self.refuse(f"{key}.velocity", f"{_fmt(velocity)}: an emitter that emits nothing forward")
                continue
            x = _vec(e.get("translation"), [0, 0, 0], self.file, f"{key}.translation")
            (k, sign), (b, _), (a, _) = axes  # emission along rotation.col(0), height col(1), width col(2)
            lo, hi = x.copy(), x.copy()
            if sign > 0:  # warpsph puts the first layer half a spacing inside the box's upstream face
                lo[k], hi[k] = x[k] - 0.5 * d, x[k] + 0.5 * d
            else:
                lo[k], hi[k] = x[k] - 0.5 * d, x[k] + 0.5 * d
            lo[a], hi[a] = x[a] - 0.5 * width * d, x[a] + 0.5 * width * d
            lo[b], hi[b] = x[b] - 0.5 * height * d, x[b] + 0.5 * height * d
            vel = [0.0, 0.0, 0.0]
            vel[k] = sign * velocity
            start = float(e.get("emitStartTime", 0.0))
            end = e.get("emitEndTime")
            end = None if end is None or end >= REAL_MAX else float(end)
            emitter = {"min": lo.tolist(), "max": hi.tolist(), "velocity": vel, "start": start}
            if end is not None:
                emitter["end"] = end
            self.mapped(key, f"emitters[{len(out)}]", f"{width}x{height} particles at {_fmt(velocity)} m/s along "
                        f"{'+' if sign > 0 else '-'}{'xyz'[k]}")
            self.note(f"{key}: the emitter housing SPlisHSPlasH adds (resources/emitter_boundary) is not modelled")
            stop = self.duration if self.duration is not None else 2.0
            last = min(end if end is not None else stop, stop)
            t, m = start, 0
            while t <= last + 1e-12 and m < 100000:
                events.append((t, len(out), width * height))
                t, m = start + (m + 1) * d / velocity, m + 1
            out.append(emitter)
            self.emitter_keys.append(key)
        # maxEmitterParticles: SPlisHSPlasH stops emitting when the material's count is reached
        events.sort()
        emitted = 0
        for t, i, count in events:
            if emitted + count > cap:
                if emitted < cap:
                    self.note(f"maxEmitterParticles {cap}: SPlisHSPlasH's last, partial layer is not emitted")
                e = out[i]
                cutoff = t - 0.5 * d / abs(sum(e["velocity"]))
                for j, f in enumerate(out):
                    if f.get("end") is None or f["end"] > cutoff:
                        if cutoff > f["start"]:
                            f["end"] = cutoff
                self.mapped(f"{getattr(self, 'material_key', 'Materials')}.maxEmitterParticles", "emitters[*].end",
                            round(cutoff, 6), default="maxEmitterParticles" not in self.material)
                break
            emitted += count
        self.c.scene["emitters"] = [e for e in out if e.get("end") is None or e["end"] > e["start"]]
        self.emitted = emitted


def translate(data, file) -> Conversion:
    """The :class:`Conversion` of a SPlisHSPlasH scene dict (raises nothing for refused keys)."""
    reader = _Reader(data, file)
    conversion = reader.run()
    if not any(conversion.scene.get(k) for k in ("fluid_blocks", "fluid_meshes", "emitters")):
        if not any("FluidModels" in r for r in conversion.refused):
            conversion.refused.append("FluidBlocks: no fluid block holds a particle by SPlisHSPlasH's rule")
    unknown = data.get("FluidModels") or getattr(reader, "dense_blocks", False)  # (see _Reader.fluid_blocks)
    conversion.splishsplash_particles = None if unknown else reader.block_particles
    return conversion


def _wants_run_anyway(data, run_anyway):
    if run_anyway is not None:
        return bool(run_anyway)
    own = data.get("warpsph")
    if isinstance(own, dict) and own.get("run_anyway"):
        return True
    return os.environ.get(RUN_ANYWAY_ENV, "").strip().lower() in ("1", "true", "yes")


def convert(data, file, run_anyway=None) -> dict:
    """A warpsph scene dict from a SPlisHSPlasH scene dict (paths stay relative to ``file``).

    Refused keys raise one :class:`SceneError` naming each, unless ``run_anyway`` (or the
    environment variable or the file's ``"warpsph": {"run_anyway": true}``); then they are listed
    in a :class:`SplishSplashWarning` and kept in :func:`conversion_of`."""
    conversion = translate(data, file)
    conversion.run_anyway = _wants_run_anyway(data, run_anyway)
    _CONVERSIONS[str(file)] = conversion
    if conversion.errors:
        items = "\n  - ".join(conversion.errors + conversion.refused)
        raise SceneError(file, "SPlisHSPlasH scene", f"warpsph cannot run this scene:\n  - {items}")
    if conversion.refused and not conversion.run_anyway:
        items = "\n  - ".join(conversion.refused)
        raise SceneError(file, "SPlisHSPlasH scene",
                         f"{len(conversion.refused)} part(s) of this scene are physics warpsph does not simulate:\n  - "
                         f"{items}\nTo run it anyway without them, set {RUN_ANYWAY_ENV}=1 or add "
                         '"warpsph": {"run_anyway": true} to the scene file (the list is then printed and kept)')
    lines = []
    if conversion.refused:
        lines.append("RUN ANYWAY, left out: " + "; ".join(conversion.refused))
    if conversion.notes:
        lines.append("approximations and keys without effect: " + "; ".join(conversion.notes))
    if lines:
        warnings.warn(f"{file}: " + "\n".join(lines), SplishSplashWarning, stacklevel=3)
    return conversion.scene
