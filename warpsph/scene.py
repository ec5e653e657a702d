"""Scene schema: frozen dataclasses, validated once on load.

A scene is a JSON file. Every key is checked against the dataclasses below: an unknown
key, a wrong type or a value out of range raises :class:`SceneError` naming the file
and the key path (``fluid_blocks[1].end``), before anything is allocated or written.
Units are SI: metres, seconds, kilograms.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import typing
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from .errors import SceneError

Vec3 = typing.Tuple[float, float, float]


def _check(expect, test):
    """Field metadata: a range check and the words that say what it expects."""
    return {"expect": expect, "test": test}


def _positive():
    return _check("a number > 0", lambda v: v > 0)


@dataclass(frozen=True)
class Box:
    """The domain: walls of boundary particles on its faces, except across ``periodic`` axes,
    where particles leaving one face enter at the opposite one. ``walls: false`` makes it open:
    no walls, and particles that leave it (across a non-periodic face) are removed and counted,
    so that a scene whose boundaries are its bodies can run."""

    min: Vec3
    max: Vec3
    periodic: typing.Tuple[str, ...] = ()  # e.g. ["x", "z"]
    walls: bool = True  # false: an open domain

    def validate(self, file, key):
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise SceneError(file, key, f"min {list(self.min)} must be below max {list(self.max)} on every axis")
        for n, axis in enumerate(self.periodic):
            if axis not in ("x", "y", "z") or axis in self.periodic[:n]:
                raise SceneError(file, f"{key}.periodic[{n}]", f'expected distinct axes "x", "y" or "z", got {json.dumps(axis)}')

    @property
    def period(self):
        """Extent along each periodic axis, 0 along the others."""
        return tuple(hi - lo if "xyz"[k] in self.periodic else 0.0 for k, (lo, hi) in enumerate(zip(self.min, self.max)))

    @property
    def is_open(self):
        """Whether particles can leave it (no walls, and a face that is not periodic)."""
        return not self.walls and len(self.periodic) < 3


@dataclass(frozen=True)
class Fluid:
    density: float = field(default=1000.0, metadata=_positive())  # rest density [kg/m^3]
    viscosity: float = field(default=0.05, metadata=_check("a number >= 0", lambda v: v >= 0))  # nu [m^2/s], eq 4
    # nu between fluid and boundary samples [m^2/s] (friction with walls and bodies; SPlisHSPlasH's
    # viscosityBoundary, default 0 there too): the fluid drags along moving bodies and they feel it
    boundary_viscosity: float = field(default=0.0, metadata=_check("a number >= 0", lambda v: v >= 0))


@dataclass(frozen=True)
class FluidBlock:
    """An axis-aligned box filled with particles on a lattice of spacing 2r."""

    start: Vec3
    end: Vec3
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial velocity [m/s]

    def validate(self, file, key):
        if any(lo >= hi for lo, hi in zip(self.start, self.end)):
            raise SceneError(file, key, f"start {list(self.start)} must be below end {list(self.end)} on every axis")


@dataclass(frozen=True)
class Keyframe:
    """A body's offset from its placement at one time; linear in between, held outside."""

    time: float  # [s]
    translation: Vec3  # [m]


@dataclass(frozen=True)
class Motion:
    """Prescribed motion of a kinematic body: the sum of a keyframed path, a constant-acceleration
    drift (from ``start``: falling blocks) and a spin about ``axis`` through ``center``."""

    keyframes: typing.Tuple[Keyframe, ...] = ()
    velocity: Vec3 = (0.0, 0.0, 0.0)  # [m/s] from ``start`` on
    acceleration: Vec3 = (0.0, 0.0, 0.0)  # [m/s^2] from ``start`` on
    start: float = field(default=0.0, metadata=_check("a number >= 0", lambda v: v >= 0))  # [s]
    end: typing.Optional[float] = None  # [s] the drift stops here (a dropped block reaching the floor); null: never
    angular_velocity: float = 0.0  # [rad/s] about ``axis`` (right-handed)
    axis: Vec3 = (0.0, 1.0, 0.0)
    center: typing.Optional[Vec3] = None  # [m] a point on the axis at the placement; null: the mesh's centre
    spin_start: float = field(default=0.0, metadata=_check("a number >= 0", lambda v: v >= 0))  # [s]
    spin_up: float = field(default=0.0, metadata=_check("a number >= 0", lambda v: v >= 0))  # [s] ramp to full speed

    def validate(self, file, key):
        times = [k.time for k in self.keyframes]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise SceneError(file, f"{key}.keyframes", f"times must increase, got {times}")
        if self.end is not None and self.end <= self.start:
            raise SceneError(file, f"{key}.end", f"must be after start ({self.start:g} s), got {self.end:g}")
        if self.angular_velocity != 0.0 and not any(self.axis):
            raise SceneError(file, f"{key}.axis", "the spin axis is zero")


@dataclass(frozen=True)
class Dynamics:
    """A rigid body moved by the fluid (two-way coupling, Akinci et al. 2012) and gravity."""

    density: float = field(metadata=_positive())  # [kg/m^3]; mass and inertia come from the closed mesh
    velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [m/s]
    angular_velocity: Vec3 = (0.0, 0.0, 0.0)  # initial [rad/s]


@dataclass(frozen=True)
class Obstacle:
    """A body from a mesh file (OBJ/STL/PLY), surface-sampled once at the particle spacing: static,
    kinematic (``motion``) or dynamic (``dynamics``)."""

    mesh: str  # path, relative to the scene file
    translation: Vec3 = (0.0, 0.0, 0.0)  # [m]
    scale: Vec3 = (1.0, 1.0, 1.0)
    rotation_axis: Vec3 = (0.0, 1.0, 0.0)
    rotation_angle: float = 0.0  # [rad]
    name: typing.Optional[str] = None  # the USD prim name; default from the mesh file
    motion: typing.Optional[Motion] = None
    dynamics: typing.Optional[Dynamics] = None

    def validate(self, file, key):
        if self.motion is not None and self.dynamics is not None:
            raise SceneError(file, key, 'a body is either kinematic ("motion") or dynamic ("dynamics"), not both')
        if self.name is not None and not (self.name[:1].isalpha() and self.name.replace("_", "").isalnum()):
            raise SceneError(file, f"{key}.name", f"expected letters, digits and _ (a USD prim name), got {json.dumps(self.name)}")

    @property
    def moving(self):
        return self.motion is not None or self.dynamics is not None


@dataclass(frozen=True)
class Emitter:
    """Inflow: every time the last layer has moved one particle spacing, a new lattice layer of
    particles moving at ``velocity`` (along one axis) fills the cross-section of the box [min, max]
    at its upstream face. ``end`` null: until the run ends."""

    min: Vec3
    max: Vec3
    velocity: Vec3
    start: float = field(default=0.0, metadata=_check("a number >= 0", lambda v: v >= 0))  # [s]
    end: typing.Optional[float] = None  # [s]

    def validate(self, file, key):
        if any(lo > hi for lo, hi in zip(self.min, self.max)):
            raise SceneError(file, key, f"min {list(self.min)} must not exceed max {list(self.max)}")
        moving = [k for k, c in enumerate(self.velocity) if c != 0.0]
        if len(moving) != 1:
            raise SceneError(file, f"{key}.velocity", f"expected a velocity along one axis (e.g. [1.5, 0, 0]), got {list(self.velocity)}")
        if self.end is not None and self.end <= self.start:
            raise SceneError(file, f"{key}.end", f"must be after start ({self.start:g} s), got {self.end:g}")

    @property
    def axis(self):
        return next(k for k, c in enumerate(self.velocity) if c != 0.0)


@dataclass(frozen=True)
class Sink:
    """Outflow: fluid particles inside the box [min, max] are removed (checked every step)."""

    min: Vec3
    max: Vec3

    def validate(self, file, key):
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise SceneError(file, key, f"min {list(self.min)} must be below max {list(self.max)} on every axis")


DT_MAX_PER_RADIUS = 0.2  # [s/m]: the default dt_max is proportional to the particle radius


@dataclass(frozen=True)
class TimeStepping:
    cfl: float = field(default=0.5, metadata=_check("a number in (0, 1]", lambda v: 0 < v <= 1))
    # [s]; null: dt_max / 50 (SPlisHSPlasH's 0.1 ms at r = 25 mm)
    dt_min: typing.Optional[float] = field(default=None, metadata=_check("null or a number > 0", lambda v: v is None or v > 0))
    # [s]; null: 0.2 s/m x particle radius (SPlisHSPlasH's 5 ms at r = 25 mm). A fixed 5 ms let
    # finer dam breaks crush their bottom layers before the pressure could build (r = 6.3 mm and
    # r = 2.9 mm exploded within 5 steps).
    dt_max: typing.Optional[float] = field(default=None, metadata=_check("null or a number > 0", lambda v: v is None or v > 0))
    fixed_dt: typing.Optional[float] = field(default=None, metadata=_check("null or a number > 0", lambda v: v is None or v > 0))

    def validate(self, file, key):
        if self.dt_max is not None and self.dt_min is not None and self.dt_min > self.dt_max:
            raise SceneError(file, f"{key}.dt_min", f"{self.dt_min} must not exceed dt_max {self.dt_max}")


@dataclass(frozen=True)
class Solver:
    """DFSPH controls; errors in percent, as in SPlisHSPlasH."""

    density_max_error: float = field(default=0.01, metadata=_positive())  # average, % of rho0
    divergence_max_error: float = field(default=0.1, metadata=_positive())  # average, % of rho0 per second
    min_iterations: int = field(default=2, metadata=_check("an integer >= 0", lambda v: v >= 0))
    max_iterations: int = field(default=100, metadata=_check("an integer >= 1", lambda v: v >= 1))
    divergence_solver: bool = True
    divergence_min_iterations: int = field(default=1, metadata=_check("an integer >= 0", lambda v: v >= 0))
    divergence_max_iterations: int = field(default=100, metadata=_check("an integer >= 1", lambda v: v >= 1))
    warm_start: bool = True
    # particle shifting (Lind et al. 2012): x += -D grad C after the position update in the bulk
    # (tangential near the free surface, off on it), D = shifting x h max|v| dt; 0: off
    shifting: float = field(default=2.0, metadata=_check("a number >= 0", lambda v: v >= 0))
    sort_interval: int = field(default=16, metadata=_check("an integer >= 0 (0: never)", lambda v: v >= 0))

    # keys of earlier versions: a scene that has them loads with a warning naming the key
    OBSOLETE = {
        "clamp_pressure": "the solver now finds the free surface per particle (p >= 0 there, signed in the "
                          "bulk) in every scene; the key is ignored",
        "transport_velocity": "the solver regularises the particles by shifting (solver.shifting) in every "
                              "scene; the key is ignored",
    }

    def validate(self, file, key):
        if self.min_iterations > self.max_iterations:
            raise SceneError(file, f"{key}.min_iterations", "must not exceed max_iterations")


@dataclass(frozen=True)
class Output:
    fps: float = field(default=25.0, metadata=_positive())
    frames: int = field(default=50, metadata=_check("an integer >= 1", lambda v: v >= 1))
    up_axis: str = field(default="Y", metadata=_check('"Y" or "Z"', lambda v: v in ("Y", "Z")))


def _within(lo, hi, null=False):
    """A model parameter's documented range [lo, hi]: beyond it a run blows up or means nothing."""
    return _check(("null or " if null else "") + f"a number in [{lo:g}, {hi:g}]",
                  lambda v: (null and v is None) or lo <= v <= hi)


MAX_MODEL_VISCOSITY = 1.0  # [m^2/s], 20x the fluid's default


@dataclass(frozen=True)
class VorticityRefinement:
    """Vorticity refinement (VR paper, Algorithm 2): v <- v~ + alpha dv (eq 17)."""

    # the VR paper uses 0 to 1.3; tools/stress.py found every alpha in [0, 2] stable
    alpha: float = field(default=1.0, metadata=_within(0.0, 2.0))
    viscosity: typing.Optional[float] = field(  # nu_v of eq 10 [m^2/s]; default: the fluid's
        default=None, metadata=_within(0.0, MAX_MODEL_VISCOSITY, null=True))


@dataclass(frozen=True)
class RankineFeedback:
    """Rankine vortex feedback (Rankine paper, Algorithm 1): r_c = beta sqrt(4 1.25643 nu dt)."""

    beta: float = field(default=1.0, metadata=_within(0.0, 1.0))
    viscosity: typing.Optional[float] = field(  # nu of eq 11 [m^2/s]; default: the fluid's
        default=None, metadata=_within(0.0, MAX_MODEL_VISCOSITY, null=True))


@dataclass(frozen=True)
class Micropolar:
    """Micropolar turbulence (Bender et al. 2017/2018), the papers' baseline (SPlisHSPlasH's defaults:
    nu_t 0.1, Theta^-1 0.5, zeta 0.1; tools/stress.py ran nu_t up to 0.4)."""

    transfer_coefficient: float = field(default=0.05, metadata=_within(0.0, 1.0))  # nu_t
    inverse_inertia: float = field(default=0.5, metadata=_check("a number in (0, 10]", lambda v: 0 < v <= 10))  # Theta^-1
    viscosity_omega: float = field(default=0.1, metadata=_within(0.0, MAX_MODEL_VISCOSITY))  # zeta [m^2/s]


# scene "models" entries: {"type": NAME, ...parameters}
MODEL_TYPES = {"vorticity_refinement": VorticityRefinement, "rankine": RankineFeedback, "micropolar": Micropolar}


class ModelConfig:
    """Marker type of a "models" entry: one of MODEL_TYPES, chosen by its "type" key."""


@dataclass(frozen=True)
class InitialPacking:
    """A particle packing before t = 0 (set-up, not simulated time): the sampled lattice jittered by up to
    ``jitter`` particle spacings, then ``steps`` steps of the scene's own pressure solver at rest (no gravity,
    models, emitters or body motion; velocities zeroed before each step). A periodic box started on the cubic
    lattice collapses to a disordered state after ~20 steps and the released noise pumps energy into the
    flow (Taylor-Green, 128 across: KE 12-30 % above the analytic curve); from the packing it does not."""

    steps: int = field(default=40, metadata=_check("an integer >= 1", lambda v: v >= 1))
    jitter: float = field(default=0.1, metadata=_check("a number in [0, 0.5] (particle spacings)", lambda v: 0 <= v <= 0.5))
    seed: int = 1


@dataclass(frozen=True)
class Scene:
    particle_radius: float = field(metadata=_positive())  # [m]; support radius is 4r
    domain: Box
    fluid_blocks: typing.Tuple[FluidBlock, ...] = ()
    name: str = "scene"
    fluid: Fluid = Fluid()
    gravity: Vec3 = (0.0, -9.81, 0.0)  # [m/s^2]
    obstacles: typing.Tuple[Obstacle, ...] = ()
    emitters: typing.Tuple[Emitter, ...] = ()
    sinks: typing.Tuple[Sink, ...] = ()
    time: TimeStepping = TimeStepping()
    solver: Solver = Solver()
    output: Output = Output()
    models: typing.Tuple[ModelConfig, ...] = ()  # turbulence models, e.g. [{"type": "rankine", "beta": 0.6}]
    initial_packing: typing.Optional[InitialPacking] = None  # e.g. {"steps": 40}; null: start on the lattice
    source: typing.Optional[str] = None  # the file it was read from (set by load_scene)

    @property
    def particle_diameter(self):
        return 2.0 * self.particle_radius

    @property
    def support_radius(self):
        return 4.0 * self.particle_radius

    @property
    def time_step_bounds(self):
        """(dt_min, dt_max) in seconds, resolved from the radius where the file leaves them null."""
        dt_max = self.time.dt_max if self.time.dt_max is not None else DT_MAX_PER_RADIUS * self.particle_radius
        dt_min = self.time.dt_min if self.time.dt_min is not None else dt_max / 50.0
        return min(dt_min, dt_max), dt_max

    def validate(self, file, key):
        if not self.fluid_blocks and not self.emitters:
            raise SceneError(file, "fluid_blocks", "the scene has no fluid: give at least one block or emitter")
        for n, e in enumerate(self.emitters):
            if any(s < a - 1e-9 or t > b + 1e-9 for s, t, a, b in zip(e.min, e.max, self.domain.min, self.domain.max)):
                raise SceneError(file, f"emitters[{n}]", f"box {list(e.min)}..{list(e.max)} lies outside the domain")
        lo, hi = self.domain.min, self.domain.max
        for n, block in enumerate(self.fluid_blocks):
            if any(s < a - 1e-9 or e > b + 1e-9 for s, e, a, b in zip(block.start, block.end, lo, hi)):
                raise SceneError(file, f"fluid_blocks[{n}]",
                                 f"block {list(block.start)}..{list(block.end)} lies outside the domain {list(lo)}..{list(hi)}")
        for k, p in enumerate(self.domain.period):
            if 0 < p < 3 * self.support_radius:
                raise SceneError(file, "domain.periodic", f"the domain is {p:g} m along {'xyz'[k]}: a periodic axis "
                                                          f"needs at least 3 support radii ({3 * self.support_radius:g} m)")
        kinds = [type(m) for m in self.models]
        for n, kind in enumerate(kinds):
            if kinds.index(kind) != n:
                raise SceneError(file, f"models[{n}]", "this model is already enabled")
        base = Path(file).parent if file else Path(".")
        for n, obstacle in enumerate(self.obstacles):
            path = base / obstacle.mesh
            if not path.is_file():
                raise SceneError(path, f"obstacles[{n}].mesh", "mesh file not found")

    def mesh_path(self, obstacle: Obstacle) -> Path:
        base = Path(self.source).parent if self.source else Path(".")
        return base / obstacle.mesh

    @classmethod
    def load(cls, path, scale: float = 1.0) -> "Scene":
        """Reads and validates a scene file (warpsph JSON or SPlisHSPlasH); ``scale`` multiplies the
        particle count (see :func:`load_scene`).

        >>> scene = Scene.load("scenes/dam_break.json", scale=0.1)
        """
        return load_scene(path, scale=scale)

    @classmethod
    def from_dict(cls, data: dict, base_dir=None, scale: float = 1.0) -> "Scene":
        """Builds and validates a scene from a dict with the keys of a scene file; mesh paths
        resolve against ``base_dir`` (see :func:`scene_from_dict`)."""
        return scene_from_dict(data, base_dir=base_dir, scale=scale)


# ---------------------------------------------------------------------------------------
# generic parser driven by the dataclass fields


def _type_name(tp):
    if tp is float:
        return "a number"
    if tp is int:
        return "an integer"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if tp == Vec3:
        return "a list of 3 numbers"
    if dataclasses.is_dataclass(tp):
        return "an object"
    return str(tp)


def _convert(tp, value, file, key):
    origin = typing.get_origin(tp)
    if origin is typing.Union:  # Optional[X]
        (inner,) = [a for a in typing.get_args(tp) if a is not type(None)]
        return None if value is None else _convert(inner, value, file, key)
    if tp == Vec3:
        if not isinstance(value, list) or len(value) != 3:
            raise SceneError(file, key, f"expected a list of 3 numbers, got {json.dumps(value)}")
        return tuple(_convert(float, x, file, f"{key}[{n}]") for n, x in enumerate(value))
    if origin is tuple:  # Tuple[Dataclass, ...]
        (inner, _) = typing.get_args(tp)
        if not isinstance(value, list):
            raise SceneError(file, key, f"expected a list, got {json.dumps(value)}")
        return tuple(_convert(inner, x, file, f"{key}[{n}]") for n, x in enumerate(value))
    if tp is ModelConfig:
        return _parse_model(value, file, key)
    if dataclasses.is_dataclass(tp):
        return parse_dataclass(tp, value, file, key)
    if tp is bool:
        if not isinstance(value, bool):
            raise SceneError(file, key, f"expected true or false, got {json.dumps(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(file, key, f"expected an integer, got {json.dumps(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SceneError(file, key, f"expected a finite number, got {json.dumps(value)}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise SceneError(file, key, f"expected a string, got {json.dumps(value)}")
        return value
    raise TypeError(f"unsupported schema type {tp}")


def _parse_model(value, file, key):
    if not isinstance(value, dict) or "type" not in value:
        raise SceneError(file, key, f'expected an object with a "type" ({", ".join(MODEL_TYPES)})')
    name = value["type"]
    if name not in MODEL_TYPES:
        close = difflib.get_close_matches(str(name), MODEL_TYPES, n=1)
        hint = f"; did you mean '{close[0]}'?" if close else f"; known: {', '.join(MODEL_TYPES)}"
        raise SceneError(file, f"{key}.type", f"unknown model {json.dumps(name)}{hint}")
    params = {k: v for k, v in value.items() if k != "type"}
    return parse_dataclass(MODEL_TYPES[name], params, file, key)


def parse_dataclass(cls, data, file=None, key=""):
    """Builds ``cls`` from a JSON object, checking every key; raises :class:`SceneError`."""
    where = key or "scene"
    if not isinstance(data, dict):
        raise SceneError(file, where, f"expected an object, got {json.dumps(data)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.name != "source"}
    obsolete = getattr(cls, "OBSOLETE", {})
    for name in [n for n in data if n in obsolete and n not in fields]:
        warnings.warn(f"{file}: {key}.{name}: obsolete key: {obsolete[name]}" if key else f"{file}: {name}: obsolete key: {obsolete[name]}")
        data = {n: v for n, v in data.items() if n != name}
    for name in data:
        if name not in fields:
            close = difflib.get_close_matches(name, fields, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else f"; known keys: {', '.join(fields)}"
            raise SceneError(file, f"{key}.{name}" if key else name, f"unknown key{hint}")
    values = {}
    for name, f in fields.items():
        path = f"{key}.{name}" if key else name
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SceneError(file, path, f"missing required key ({_type_name(hints[name])})")
            continue
        value = _convert(hints[name], data[name], file, path)
        check = f.metadata.get("test")
        if check is not None and value is not None and not check(value):
            raise SceneError(file, path, f"expected {f.metadata['expect']}, got {json.dumps(data[name])}")
        values[name] = value
    obj = cls(**values)
    if hasattr(obj, "validate"):
        obj.validate(file, where if key else "")
    return obj


def load_scene(path, scale: float = 1.0) -> Scene:
    """Reads and validates a scene file.

    ``scale`` multiplies the particle count: the particle radius is divided by
    ``scale ** (1/3)``, so ``scale=0.01`` runs a 1 % version of the scene and the
    scene file keeps the paper's full-size radius.
    """
    path = Path(path)
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise SceneError(path, "--scale", f"expected a number > 0, got {scale}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise SceneError(path, "", f"cannot read the scene file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise SceneError(path, "", f"not UTF-8 text (byte {exc.start}): save the scene file as UTF-8 JSON") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneError(path, "", f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise SceneError(path, "", "not a scene: its JSON is nested too deeply") from None
    from .io.splishsplash import convert, is_splishsplash

    if is_splishsplash(data):  # a SPlisHSPlasH scene file
        data = convert(data, path)
    scene = parse_dataclass(Scene, data, path)
    return rescale(dataclasses.replace(scene, source=str(path)), scale)


def with_overrides(data: dict, overrides=None) -> dict:
    """A copy of the scene dict ``data`` with the dotted keys of ``overrides`` set, e.g.
    {"solver.density_max_error": 0.05, "time.cfl": 0.4} (studies and sweeps change one key of a scene)."""
    data = json.loads(json.dumps(data))
    for path, value in (overrides or {}).items():
        node = data
        *parents, last = path.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[last] = value
    return data


def scene_from_dict(data: dict, base_dir=None, scale: float = 1.0) -> Scene:
    """Builds a scene from a dict (for scripts and tests); mesh paths resolve against ``base_dir``."""
    file = Path(base_dir or ".") / "<dict>"
    scene = parse_dataclass(Scene, data, file)
    return rescale(dataclasses.replace(scene, source=str(file)), scale)


def rescale(scene: Scene, scale: float) -> Scene:
    """The scene at ``scale`` times its particle count: radius / scale^(1/3).

    When the particles get smaller, the time-step bounds shrink in proportion (dt ~ r, as in
    the CFL condition): a 1M-particle dam break with the 16K-particle scene's dt_max of 5 ms
    crushed its bottom layers in the first steps and exploded; at dt_max ~ 1.3 ms it ran.
    Coarser versions keep the file's bounds."""
    if scale == 1.0:
        return scene
    factor = scale ** (-1.0 / 3.0)
    t = scene.time
    shrink = min(1.0, factor)
    time = dataclasses.replace(t, dt_min=None if t.dt_min is None else t.dt_min * shrink,
                               dt_max=None if t.dt_max is None else t.dt_max * shrink,
                               fixed_dt=None if t.fixed_dt is None else t.fixed_dt * shrink)
    return dataclasses.replace(scene, particle_radius=scene.particle_radius * factor, time=time)
