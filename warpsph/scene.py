"""Scene schema: frozen pydantic dataclasses (strict, no unknown keys), validated once on load.

A scene is a JSON file. Every key is checked against the dataclasses below: an unknown
key, a wrong type or a value out of range raises :class:`SceneError` naming the file
and the key path (``fluid_blocks[1].end``), before anything is allocated or written.
Units are SI: metres, seconds, kilograms.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import math
import typing
import warnings
from pathlib import Path
from typing import Any, Literal, Optional, Tuple

from pydantic import TypeAdapter, ValidationError

from .errors import SceneError
from .keys import key, schema  # the schema's building blocks (warpsph.scene.key and .schema, as before)
from .solvers import DEFAULT_SOLVER, solver_class, solver_classes, solver_keys, solver_names

Vec3 = Tuple[float, float, float]

def walled_faces(domain):
    """(lo, hi) per axis: the faces that hold the particles in ``domain`` (a :class:`Box`, or anything with ``min``,
    ``max``, ``periodic`` and ``walls``): its min and max along a walled axis, -inf and +inf along a periodic one
    and in an open domain (``walls`` false)."""
    walled = [getattr(domain, "walls", True) and "xyz"[k] not in tuple(domain.periodic) for k in range(3)]
    return (tuple(float(domain.min[k]) if walled[k] else -math.inf for k in range(3)),
            tuple(float(domain.max[k]) if walled[k] else math.inf for k in range(3)))


@schema
class Box:
    """The domain: walls of boundary particles on its faces, except across ``periodic`` axes,
    where particles leaving one face enter at the opposite one. ``walls: false`` makes it open:
    no walls, and particles that leave it (across a non-periodic face) are removed and counted,
    so that a scene whose boundaries are its bodies can run."""

    min: Vec3 = key(doc="lower corner", unit="m")
    max: Vec3 = key(doc="upper corner", unit="m")
    periodic: Tuple[Literal["x", "y", "z"], ...] = key((), doc='axes across which the box wraps, e.g. ["x", "z"]')
    walls: bool = key(True, doc="false: an open domain (no walls; particles that leave are removed)")

    def validate(self, file, key):
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise SceneError(file, key, f"min {list(self.min)} must be below max {list(self.max)} on every axis")
        for n, axis in enumerate(self.periodic):
            if axis in self.periodic[:n]:
                raise SceneError(file, f"{key}.periodic[{n}]", f'expected distinct axes "x", "y" or "z", got {json.dumps(axis)} twice')

    @property
    def period(self):
        """Extent along each periodic axis, 0 along the others."""
        return tuple(hi - lo if "xyz"[k] in self.periodic else 0.0 for k, (lo, hi) in enumerate(zip(self.min, self.max)))

    @property
    def is_open(self):
        """Whether particles can leave it (no walls, and a face that is not periodic)."""
        return not self.walls and len(self.periodic) < 3


@schema
class Fluid:
    """The fluid's material."""

    density: float = key(1000.0, doc="rest density rho0", unit="kg/m^3", gt=0)
    viscosity: float = key(0.05, doc="kinematic viscosity nu of the artificial viscosity (VR paper eq 4)", unit="m^2/s", ge=0)
    boundary_viscosity: float = key(
        0.0, doc="nu between fluid and boundary samples (SPlisHSPlasH's viscosityBoundary): friction with walls and "
                 "bodies; the fluid drags moving bodies along and they feel it. Twice fluid.viscosity holds the fluid "
                 "at the samples (no slip; with the same value it slips by about half a particle spacing)",
        unit="m^2/s", ge=0)

    @property
    def viscous(self):
        """Whether the viscosity model runs: a viscosity in the fluid or against the boundary."""
        return self.viscosity > 0.0 or self.boundary_viscosity > 0.0


@schema
class FluidBlock:
    """An axis-aligned box filled with particles on a lattice of spacing 2r."""

    start: Vec3 = key(doc="lower corner", unit="m")
    end: Vec3 = key(doc="upper corner", unit="m")
    velocity: Vec3 = key((0.0, 0.0, 0.0), doc="initial velocity", unit="m/s")

    def validate(self, file, key):
        if any(lo >= hi for lo, hi in zip(self.start, self.end)):
            raise SceneError(file, key, f"start {list(self.start)} must be below end {list(self.end)} on every axis")


@schema
class FluidMesh:
    """A closed mesh (OBJ/STL/PLY) filled with fluid at t = 0: the lattice of spacing 2r over the scaled
    mesh's bounding box, its first point half a spacing inside the lower corner, kept inside the mesh; then
    rotated and translated with the mesh. An open mesh is refused."""

    mesh: str = key(doc="closed mesh file path, relative to the scene file")
    translation: Vec3 = key((0.0, 0.0, 0.0), doc="placement", unit="m")
    scale: Vec3 = key((1.0, 1.0, 1.0), doc="scale per axis")
    rotation_axis: Vec3 = key((0.0, 1.0, 0.0), doc="placement rotation axis")
    rotation_angle: float = key(0.0, doc="placement rotation angle", unit="rad")
    velocity: Vec3 = key((0.0, 0.0, 0.0), doc="initial velocity", unit="m/s")


@schema
class Keyframe:
    """A body's offset from its placement at one time; linear in between, held outside."""

    time: float = key(doc="time", unit="s")
    translation: Vec3 = key(doc="offset from the placement", unit="m")


@schema
class SpinRate:
    """A kinematic body's spin rate at one time; linear in between."""

    time: float = key(doc="time", unit="s")
    rate: float = key(doc="spin rate about the motion's axis (right-handed)", unit="rad/s")


@schema
class Motion:
    """Prescribed motion of a kinematic body: the sum of a keyframed path, a constant-acceleration
    drift (from ``start``: falling blocks) and a spin about ``axis`` through ``center``, at
    ``angular_velocity`` with its ramps or following ``spin_rates``."""

    keyframes: Tuple[Keyframe, ...] = key((), doc="keyframed path, times increasing")
    velocity: Vec3 = key((0.0, 0.0, 0.0), doc="drift velocity from start on", unit="m/s")
    acceleration: Vec3 = key((0.0, 0.0, 0.0), doc="drift acceleration from start on", unit="m/s^2")
    start: float = key(0.0, doc="when the drift starts", unit="s", ge=0)
    end: Optional[float] = key(None, doc="when the drift stops (a dropped block reaching the floor); null: never", unit="s")
    angular_velocity: float = key(0.0, doc="spin about axis (right-handed)", unit="rad/s")
    axis: Vec3 = key((0.0, 1.0, 0.0), doc="spin axis")
    center: Optional[Vec3] = key(None, doc="a point on the spin axis at the placement; null: the mesh's centre", unit="m")
    spin_start: float = key(0.0, doc="when the spin starts", unit="s", ge=0)
    spin_up: float = key(0.0, doc="ramp to full spin speed", unit="s", ge=0)
    spin_end: Optional[float] = key(None, doc="when the spin starts to stop (the propeller of the Rankine paper's "
                                              "Fig 13); null: never", unit="s", ge=0)
    spin_down: float = key(0.0, doc="ramp from the rate at spin_end to rest", unit="s", ge=0)
    spin_rates: Tuple[SpinRate, ...] = key(
        (), doc="spin rate over time instead of angular_velocity and its ramps (SPlisHSPlasH's motor targetSequence): "
                "linear between entries, times increasing, held before the first and after the last")
    spin_repeat: bool = key(False, doc="spin_rates repeat from the first time on, with the period last time - first "
                                       "time (SPlisHSPlasH's repeatSequence)")

    def validate(self, file, key):
        times = [k.time for k in self.keyframes]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise SceneError(file, f"{key}.keyframes", f"times must increase, got {times}")
        self.validate_spin_rates(file, key)
        if self.end is not None and self.end <= self.start:
            raise SceneError(file, f"{key}.end", f"must be after start ({self.start:g} s), got {self.end:g}")
        if self.spin_end is not None and self.spin_end <= self.spin_start:
            raise SceneError(file, f"{key}.spin_end", f"must be after spin_start ({self.spin_start:g} s), "
                                                       f"got {self.spin_end:g}")
        if (self.angular_velocity != 0.0 or self.spin_rates) and not any(self.axis):
            raise SceneError(file, f"{key}.axis", "the spin axis is zero")

    def validate_spin_rates(self, file, key):
        times = [s.time for s in self.spin_rates]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise SceneError(file, f"{key}.spin_rates", f"times must increase, got {times}")
        ramps = {"angular_velocity": self.angular_velocity != 0.0, "spin_start": self.spin_start != 0.0,
                 "spin_up": self.spin_up != 0.0, "spin_end": self.spin_end is not None, "spin_down": self.spin_down != 0.0}
        if self.spin_rates and any(ramps.values()):
            given = next(k for k, v in ramps.items() if v)
            raise SceneError(file, f"{key}.spin_rates", f"give either spin_rates or {given} (angular_velocity and its "
                                                        "ramps), not both")
        if self.spin_repeat and len(times) < 2:
            raise SceneError(file, f"{key}.spin_repeat", f"repeats spin_rates over last - first time: needs two times "
                                                         f"or more, got {len(times)}")


@schema
class Dynamics:
    """A rigid body moved by the fluid (two-way coupling, Akinci et al. 2012) and gravity."""

    density: float = key(doc="body density; mass and inertia come from the closed mesh", unit="kg/m^3", gt=0)
    velocity: Vec3 = key((0.0, 0.0, 0.0), doc="initial velocity", unit="m/s")
    angular_velocity: Vec3 = key((0.0, 0.0, 0.0), doc="initial angular velocity", unit="rad/s")
    restitution: float = key(0.0, doc="coefficient of restitution e of its contacts with the walls and other bodies: a "
                                      "contact point approaching faster than 2 |g| dt leaves at -e times its normal "
                                      "speed, a slower one comes to rest; between two dynamic bodies sqrt(e_a e_b)",
                             ge=0, le=1)
    friction: Optional[float] = key(None, doc="Coulomb friction coefficient mu of its contacts: the tangential impulse "
                                              "at the contact point is at most mu times the normal one (sticking below "
                                              "it); between two dynamic bodies the mean of the given ones; null: no "
                                              "Coulomb law, the tangential velocity and the spin are halved every step "
                                              "in contact (the behaviour before this key)", ge=0)


@schema
class Obstacle:
    """A body from a mesh file (OBJ/STL/PLY), surface-sampled once at the particle spacing: static,
    kinematic (``motion``) or dynamic (``dynamics``)."""

    mesh: str = key(doc="mesh file path, relative to the scene file")
    translation: Vec3 = key((0.0, 0.0, 0.0), doc="placement", unit="m")
    scale: Vec3 = key((1.0, 1.0, 1.0), doc="scale per axis")
    rotation_axis: Vec3 = key((0.0, 1.0, 0.0), doc="placement rotation axis")
    rotation_angle: float = key(0.0, doc="placement rotation angle", unit="rad")
    name: Optional[str] = key(None, doc="the USD prim name; null: from the mesh file")
    motion: Optional[Motion] = key(None, doc="prescribed motion (kinematic body)")
    dynamics: Optional[Dynamics] = key(None, doc="two-way coupled rigid body (dynamic body)")

    def validate(self, file, key):
        if self.motion is not None and self.dynamics is not None:
            raise SceneError(file, key, 'a body is either kinematic ("motion") or dynamic ("dynamics"), not both')
        if self.name is not None and not (self.name[:1].isalpha() and self.name.replace("_", "").isalnum()):
            raise SceneError(file, f"{key}.name", f"expected letters, digits and _ (a USD prim name), got {shown(self.name)}")

    @property
    def moving(self):
        return self.motion is not None or self.dynamics is not None


@schema
class Emitter:
    """Inflow: every time the last layer has moved one particle spacing, a new lattice layer of
    particles moving at ``velocity`` (along one axis) fills the cross-section of the box [min, max]
    at its upstream face. ``end`` null: until the run ends."""

    min: Vec3 = key(doc="lower corner", unit="m")
    max: Vec3 = key(doc="upper corner", unit="m")
    velocity: Vec3 = key(doc="inflow velocity, along one axis", unit="m/s")
    start: float = key(0.0, doc="first emission", unit="s", ge=0)
    end: Optional[float] = key(None, doc="last emission; null: until the run ends", unit="s")

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


@schema
class Sink:
    """Outflow: fluid particles inside the box [min, max] are removed (checked every step)."""

    min: Vec3 = key(doc="lower corner", unit="m")
    max: Vec3 = key(doc="upper corner", unit="m")

    def validate(self, file, key):
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise SceneError(file, key, f"min {list(self.min)} must be below max {list(self.max)} on every axis")


DT_MAX_PER_RADIUS = 0.2  # [s/m]: the default dt_max is proportional to the particle radius
MAX_VISCOSITY_SUBSTEPS = 64  # solver.viscosity_substeps: most sub-steps of the explicit viscosity in a step


@schema
class TimeStepping:
    """Adaptive time step (SPlisHSPlasH's CFL rule): dt = cfl x 0.4 x 2r / u within [dt_min, dt_max], u the largest of
    |v + g dt_last| over the fluid and |v| over moving bodies, and at most ``solver.viscosity_substeps`` explicit
    viscous limits 0.125 (2r)^2 / nu; or ``fixed_dt``."""

    cfl: float = key(0.5, doc="CFL number", gt=0, le=1)
    dt_min: Optional[float] = key(None, doc="smallest step; null: dt_max / 50 (SPlisHSPlasH's 0.1 ms at r = 25 mm)",
                                  unit="s", gt=0)
    # a fixed 5 ms let finer dam breaks crush their bottom layers before the pressure could build
    dt_max: Optional[float] = key(None, doc="largest step; null: 0.2 s/m x particle radius (SPlisHSPlasH's 5 ms at "
                                            "r = 25 mm)", unit="s", gt=0)
    fixed_dt: Optional[float] = key(None, doc="a fixed step instead of the adaptive one; null: adaptive", unit="s", gt=0)

    def validate(self, file, key):
        if self.dt_max is not None and self.dt_min is not None and self.dt_min > self.dt_max:
            raise SceneError(file, f"{key}.dt_min", f"{self.dt_min} must not exceed dt_max {self.dt_max}")


@schema
class Solver:
    """Pressure solver controls: the keys every pressure solver reads. The chosen solver's own keys (the
    Parameters of its class in warpsph.solvers) sit beside them in the same block; a key of another solver is
    refused. Errors in percent, as in SPlisHSPlasH."""

    method: str = key(DEFAULT_SOLVER, doc="pressure solver, a registered one (warpsph.solvers; the default dfsph): its own "
                                   "keys sit beside these")
    density_max_error: float = key(0.01, doc="average density error the density solve stops at", unit="% of rho0", gt=0)
    min_iterations: int = key(2, doc="density solve: fewest iterations", ge=0)
    max_iterations: int = key(100, doc="density solve: most iterations", ge=1)
    warm_start: bool = key(True, doc="start each solve from last step's pressure where it still acts (capped)")
    viscosity_substeps: int = key(
        1, doc="most sub-steps of the explicit viscosity in a step: the step is capped at this many times the explicit "
               "limit 0.125 (H/2)^2 / nu instead of at the limit, and the viscosity runs n sub-steps of dt / n "
               "(1: the step keeps the limit; 0: as many as the longest step needs, at most 64, so that the step "
               "follows the CFL rule alone, as SPlisHSPlasH's, which has no viscous limit)",
        ge=0, le=MAX_VISCOSITY_SUBSTEPS)
    sort_interval: int = key(16, doc="steps between re-sorting the particles by cell (0: never)", ge=0)

    # keys of earlier versions: a scene that has them loads with a warning naming the key
    OBSOLETE: typing.ClassVar[dict] = {
        "clamp_pressure": "the solver now finds the free surface per particle (p >= 0 there, signed in the "
                          "bulk) in every scene; the key is ignored",
        "transport_velocity": "the solver regularises the particles by shifting (solver.shifting) in every "
                              "scene; the key is ignored",
    }

    def validate(self, file, key):
        if self.method not in solver_names():
            raise _unknown_solver(self.method, file, key)
        if self.min_iterations > self.max_iterations:
            raise SceneError(file, f"{key}.min_iterations", "must not exceed max_iterations")

    def __reduce__(self):  # the class of a solver's block is made per solver (_solver_class): rebuilt by name
        return _solver_from_values, (dataclasses.asdict(self),)


def _unknown_solver(method, file, key):
    known = solver_names()
    close = difflib.get_close_matches(method, known, n=1)
    hint = f"; did you mean '{close[0]}'?" if close else f"; known: {', '.join(known)}"
    return SceneError(file, f"{key}.method", f"unknown pressure solver {json.dumps(method)}{hint}")


@functools.lru_cache(maxsize=None)
def _solver_class(params):
    """The class of a scene's solver block with the solver's ``Parameters`` ``params``: :class:`Solver`'s keys
    and then its own, one flat frozen dataclass (``scene.solver.shifting``; :func:`dataclasses.asdict` gives the
    block as a scene file has it). :class:`Solver` itself for a solver without parameters."""
    if params is None:
        return Solver

    def validate(self, file, key):
        Solver.validate(self, file, key)
        if hasattr(params, "validate"):
            params.validate(self, file, key)

    clash = set(_hints(params)) & set(_hints(Solver))
    if clash:
        raise TypeError(f"{params.__qualname__}: {', '.join(sorted(clash))} is a key of every solver (scene.Solver)")
    return schema(type("Solver", (params, Solver), {"__doc__": Solver.__doc__, "__module__": __name__,
                                                    "__qualname__": "Solver", "validate": validate}))


def _split_solver(block, file, key="solver"):
    """(the keys of ``block``, a scene's solver block, that every solver reads, the chosen solver's own keys): a
    key of another registered solver, or of none, is a SceneError naming it. A block that is not an object, or
    whose method is not a string, is left whole to the schema's errors."""
    if not isinstance(block, dict):
        return block, {}
    method = block.get("method", DEFAULT_SOLVER)
    owners = solver_keys()
    if not isinstance(method, str):
        return {k: v for k, v in block.items() if k not in owners}, {}
    classes = solver_classes()
    if method not in classes:
        raise _unknown_solver(method, file, key)
    params = classes[method].Parameters
    own_keys = list(_hints(params)) if params is not None else []
    common_keys = list(_hints(Solver))
    common, own = {}, {}
    for name, value in block.items():
        if name in own_keys:
            own[name] = value
        elif name in common_keys:
            common[name] = value
        elif name in owners:
            theirs = owners[name]
            raise SceneError(file, f"{key}.{name}",
                             f"a key of the {' and '.join(theirs)} pressure solver{'s' if len(theirs) > 1 else ''}, "
                             f"not of {json.dumps(method)} ({key}.method): remove it, or set {key}.method to "
                             f"{json.dumps(theirs[0])}")
        else:
            known = common_keys + own_keys
            close = difflib.get_close_matches(str(name), known, n=1)
            raise SceneError(file, f"{key}.{name}", "unknown key" + (
                f"; did you mean '{close[0]}'?" if close else f"; known keys: {', '.join(known)}"))
    return common, own


def _with_parameters(common, own, file, key="solver"):
    """The solver block of :class:`Solver` ``common`` with the chosen solver's own keys ``own`` (validated
    against its ``Parameters``)."""
    params = solver_class(common.method).Parameters
    if params is None:
        return common
    values = parse_dataclass(params, own, file, key)
    return _solver_class(params)(**{f.name: getattr(common, f.name) for f in dataclasses.fields(Solver)},
                                 **{f.name: getattr(values, f.name) for f in dataclasses.fields(params)})


def parse_solver(block: dict, file=None, key="solver"):
    """A scene's solver block (a dict of a scene file's ``"solver"``): what ``scene.solver`` is, the keys of
    :class:`Solver` and the chosen solver's own as attributes; :class:`SceneError` naming a bad key."""
    common, own = _split_solver(block, file, key)
    return _with_parameters(parse_dataclass(Solver, common, file, key), own, file, key)


def _solver_from_values(values):
    return parse_solver(values)


def replace_solver(solver, **changes):
    """``solver`` (a scene's ``solver``) with the keys of ``changes`` set. A change of ``method`` keeps the keys
    every solver reads and drops the old solver's own (the new solver's own keys take their defaults, or
    ``changes``')."""
    values = {**dataclasses.asdict(solver), **changes}
    if values["method"] != solver.method:
        values = {k: v for k, v in values.items() if k in _hints(Solver) or k in changes}
    return parse_solver(values)


MAX_FRAMES = 10_000_000  # output.frames: 4.6 days of simulated time at 25 frames a second


@schema
class Output:
    """The USD cache's frames."""

    fps: float = key(25.0, doc="frames per simulated second", unit="1/s", gt=0)
    frames: int = key(50, doc="frames to write (the run's length)", ge=1, le=MAX_FRAMES)
    up_axis: Literal["Y", "Z"] = key("Y", doc="the USD stage's up axis")


@schema
class InitialPacking:
    """A particle packing before t = 0 (set-up, not simulated time): the sampled lattice jittered by up to
    ``jitter`` particle spacings, then ``steps`` steps of the scene's own pressure solver at rest (no gravity,
    models, emitters or body motion; velocities zeroed before each step). A periodic box started on the cubic
    lattice collapses to a disordered state after ~20 steps and the released noise pumps energy into the
    flow (Taylor-Green, 128 across: KE 12-30 % above the analytic curve); from the packing it does not."""

    steps: int = key(40, doc="packing steps at rest", ge=1)
    jitter: float = key(0.1, doc="lattice jitter", unit="particle spacings", ge=0, le=0.5)
    seed: int = key(1, doc="random seed of the jitter")


@schema
class Scene:
    """A scene file's top level.

    Example:

    ```python
    import warpsph

    scene = warpsph.Scene.load("scenes/dam_break.json", scale=0.05)  # a 5 % version (larger radius)
    print(scene.name, scene.particle_radius, scene.domain.max, scene.output.fps)
    ```
    """

    particle_radius: float = key(doc="particle radius r; the spacing is 2r and the kernel support 4r", unit="m", gt=0)
    domain: Box = key(doc="the domain box")
    fluid_blocks: Tuple[FluidBlock, ...] = key((), doc="boxes of fluid at t = 0")
    fluid_meshes: Tuple[FluidMesh, ...] = key((), doc="closed meshes filled with fluid at t = 0")
    name: str = key("scene", doc="the scene's name (USD prim and log lines)")
    fluid: Fluid = key(Fluid(), doc="the fluid's material")
    gravity: Vec3 = key((0.0, -9.81, 0.0), doc="gravity", unit="m/s^2")
    obstacles: Tuple[Obstacle, ...] = key((), doc="bodies from mesh files")
    emitters: Tuple[Emitter, ...] = key((), doc="inflow")
    sinks: Tuple[Sink, ...] = key((), doc="outflow")
    time: TimeStepping = key(TimeStepping(), doc="time stepping")
    solver: Solver = key(Solver(), doc="pressure solver")
    output: Output = key(Output(), doc="output frames")
    models: Tuple[Any, ...] = key((), doc='turbulence models, each {"type": NAME, ...its parameters}, e.g. '
                                          '[{"type": "rankine", "beta": 0.6}]')
    initial_packing: Optional[InitialPacking] = key(None, doc='a particle packing before t = 0, e.g. {"steps": 40}; '
                                                              'null: start on the lattice')
    source: Optional[str] = key(None, doc="the file it was read from (set on load; not a scene-file key)")

    @property
    def particle_diameter(self):
        """The particle spacing 2r [m].

        Example:

        ```python
        import warpsph

        scene = warpsph.Scene.load("scenes/dam_break.json")
        assert scene.particle_diameter == 2 * scene.particle_radius
        ```
        """
        return 2.0 * self.particle_radius

    @property
    def support_radius(self):
        """The kernel's support 4r [m].

        Example:

        ```python
        import warpsph

        scene = warpsph.Scene.load("scenes/dam_break.json")
        assert scene.support_radius == 4 * scene.particle_radius
        ```
        """
        return 4.0 * self.particle_radius

    @property
    def time_step_bounds(self):
        """(dt_min, dt_max) in seconds, resolved from the radius where the file leaves them null.

        Example:

        ```python
        import warpsph

        dt_min, dt_max = warpsph.Scene.load("scenes/dam_break.json", scale=0.05).time_step_bounds
        ```
        """
        dt_max = self.time.dt_max if self.time.dt_max is not None else DT_MAX_PER_RADIUS * self.particle_radius
        dt_min = self.time.dt_min if self.time.dt_min is not None else dt_max / 50.0
        return min(dt_min, dt_max), dt_max

    def validate(self, file, key):
        if (not self.name or self.name in (".", "..") or any(c in self.name for c in '/\\\0')
                or len(self.name) > 200):
            raise SceneError(file, "name", f"expected a file name (the default output is out/NAME.usdc): no / or \\, "
                                           f"not . or .., at most 200 characters; got {shown(self.name)}")
        if not self.fluid_blocks and not self.fluid_meshes and not self.emitters:
            raise SceneError(file, "fluid_blocks", "the scene has no fluid: give at least one block, mesh or emitter")
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
        for where, items in (("obstacles", self.obstacles), ("fluid_meshes", self.fluid_meshes)):
            for n, item in enumerate(items):
                path = base / item.mesh
                if not path.is_file():
                    raise SceneError(path, f"{where}[{n}].mesh", "mesh file not found")

    def mesh_path(self, obstacle) -> Path:
        """An obstacle's or fluid mesh's file, relative to the scene file.

        Example:

        ```python
        import warpsph

        scene = warpsph.Scene.load("scenes/dam_break_pillars.json", scale=0.05)
        paths = [scene.mesh_path(o) for o in scene.obstacles]  # scenes/meshes/...
        assert all(p.is_file() for p in paths)
        ```
        """
        base = Path(self.source).parent if self.source else Path(".")
        return base / obstacle.mesh

    @classmethod
    def load(cls, path, scale: float = 1.0) -> "Scene":
        """Reads and validates a scene file (warpsph JSON or SPlisHSPlasH); ``scale`` multiplies the
        particle count (see :func:`load_scene`).

        Example:

        ```python
        import warpsph

        scene = warpsph.Scene.load("scenes/dam_break.json", scale=0.1)  # 10 % of the particles
        ```
        """
        return load_scene(path, scale=scale)

    @classmethod
    def from_dict(cls, data: dict, base_dir=None, scale: float = 1.0) -> "Scene":
        """Builds and validates a scene from a dict with the keys of a scene file; mesh paths
        resolve against ``base_dir`` (see :func:`scene_from_dict`).

        Example:

        ```python
        import warpsph

        scene = warpsph.Scene.from_dict({
            "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}]})
        ```
        """
        return scene_from_dict(data, base_dir=base_dir, scale=scale)


# ---------------------------------------------------------------------------------------
# parsing: pydantic validates, and its errors become SceneErrors naming the file and key path


def _unwrap(tp):
    """The type inside Optional[...]."""
    if typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _type_name(tp):
    tp = _unwrap(tp)
    if tp is Any:  # a models entry, validated against its plug-in's Parameters
        return 'an object with a "type"'
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
    if typing.get_origin(tp) is Literal:
        words = [json.dumps(a) for a in typing.get_args(tp)]
        return ", ".join(words[:-1]) + " or " + words[-1] if len(words) > 1 else words[0]
    if typing.get_origin(tp) is tuple:
        return f"a list, each {_type_name(typing.get_args(tp)[0])}"
    if dataclasses.is_dataclass(tp):
        return "an object"
    return str(tp)


def _hints(cls):
    return {n: h for n, h in typing.get_type_hints(cls).items() if n in cls.__pydantic_fields__}


def _expect(cls, name):
    """What a field expects, in words, from its type and range (e.g. 'a number in (0, 1]')."""
    tp = _hints(cls)[name]
    nullable = _unwrap(tp) is not tp
    info = cls.__pydantic_fields__[name]
    bounds = {k: getattr(m, k) for m in info.metadata for k in ("gt", "ge", "lt", "le") if getattr(m, k, None) is not None}
    words = _type_name(tp)
    lo = next(((k, v) for k, v in bounds.items() if k in ("gt", "ge")), None)
    hi = next(((k, v) for k, v in bounds.items() if k in ("lt", "le")), None)
    if lo and hi:
        words += f" in {'(' if lo[0] == 'gt' else '['}{lo[1]:g}, {hi[1]:g}{')' if hi[0] == 'lt' else ']'}"
    elif lo or hi:
        op, v = lo or hi
        words += f" {dict(gt='>', ge='>=', lt='<', le='<=')[op]} {v:g}"
    return f"null or {words}" if nullable else words


def _path(prefix, loc):
    out = prefix
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _walk(cls, data, loc):
    """(type, raw value) at ``loc`` below ``cls`` and ``data``; (None, None) past what the schema knows."""
    tp, value = cls, data
    for part in loc:
        tp = _unwrap(tp)
        if dataclasses.is_dataclass(tp) and isinstance(part, str):
            tp = _hints(tp).get(part)
            value = value.get(part) if isinstance(value, dict) else None
        elif typing.get_origin(tp) is tuple and isinstance(part, int):
            args = typing.get_args(tp)
            tp = args[0] if args[-1] is Ellipsis else (args[part] if part < len(args) else None)
            value = value[part] if isinstance(value, list) and part < len(value) else None
        else:
            return None, None
        if tp is None:
            return None, None
    return tp, value


SHOWN_CHARACTERS = 120  # an error message shows at most this much of the offending value


def shown(value):
    """``value`` as JSON for an error message, cut to SHOWN_CHARACTERS (a 40 MB array is not echoed back)."""
    text = json.dumps(value, default=str)
    return text if len(text) <= SHOWN_CHARACTERS else f"{text[:SHOWN_CHARACTERS]}... ({len(text):,} characters)"


def _scene_error(cls, data, error, file, prefix):
    """The SceneError for pydantic's first error: the key path, what was expected and what was there."""
    loc, kind = list(error["loc"]), error["type"]
    got = shown(error.get("input"))
    # a wrong element of a fixed-length list (Vec3): name the list
    for n in range(len(loc), 0, -1):
        tp, value = _walk(cls, data, loc[:n])
        if tp is not None and _unwrap(tp) == Vec3 and (n < len(loc) or kind in ("missing", "too_long", "too_short")):
            return SceneError(file, _path(prefix, loc[:n]), f"expected a list of 3 numbers, got {shown(value)}")
    where = _path(prefix, loc) or "scene"
    parent, _ = _walk(cls, data, loc[:-1])
    parent = _unwrap(parent) if parent is not None else None
    name = loc[-1] if loc else None
    if kind in ("unexpected_keyword_argument", "extra_forbidden"):
        known = list(_hints(parent)) if dataclasses.is_dataclass(parent) else []
        known = [k for k in known if k != "source"]
        close = difflib.get_close_matches(str(name), known, n=1)
        return SceneError(file, where, "unknown key" + (f"; did you mean '{close[0]}'?" if close else
                                                        f"; known keys: {', '.join(known)}"))
    if kind == "missing":
        tp = _hints(parent).get(name) if dataclasses.is_dataclass(parent) else None
        return SceneError(file, where, f"missing required key ({_type_name(tp) if tp else 'a value'})")
    if dataclasses.is_dataclass(parent) and name in parent.__pydantic_fields__:
        expect = _expect(parent, name)
    else:
        tp, _ = _walk(cls, data, loc)
        expect = _type_name(tp) if tp is not None else error["msg"].lower()
    if kind in ("float_type", "finite_number", "float_parsing"):
        expect = expect.replace("a number", "a finite number", 1)
    return SceneError(file, where, f"expected {expect}, got {got}")


@functools.lru_cache(maxsize=None)
def _adapter(cls):
    return TypeAdapter(cls)


def _plain(value):
    """numpy scalars and arrays, tuples: JSON values."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not a JSON value: {value!r}")


def _drop_obsolete(cls, data, file, prefix):
    """``data`` without the keys ``cls.OBSOLETE`` names (at any depth), each with a warning naming it."""
    cls = _unwrap(cls)
    if not (dataclasses.is_dataclass(cls) and isinstance(data, dict)):
        return data
    obsolete = getattr(cls, "OBSOLETE", {})
    hints = _hints(cls)
    out = {}
    for name, value in data.items():
        if name in obsolete and name not in hints:
            warnings.warn(f"{file}: {_path(prefix, [name])}: obsolete key: {obsolete[name]}")
            continue
        tp = _unwrap(hints.get(name))
        if typing.get_origin(tp) is tuple and dataclasses.is_dataclass(typing.get_args(tp)[0]) and isinstance(value, list):
            value = [_drop_obsolete(typing.get_args(tp)[0], v, file, _path(prefix, [name, n])) for n, v in enumerate(value)]
        elif dataclasses.is_dataclass(tp):
            value = _drop_obsolete(tp, value, file, _path(prefix, [name]))
        out[name] = value
    return out


def _check_tree(obj, file, key):
    """Runs the cross-field ``validate(file, key)`` checks, children first."""
    if not dataclasses.is_dataclass(obj):
        return
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, tuple):
            for n, item in enumerate(value):
                _check_tree(item, file, f"{key}.{f.name}[{n}]" if key else f"{f.name}[{n}]")
        else:
            _check_tree(value, file, f"{key}.{f.name}" if key else f.name)
    if hasattr(obj, "validate"):
        obj.validate(file, key)


SCHEMA_KEY = "$schema"  # a scene file's pointer to its JSON Schema, for editors; not a scene setting


def _without_schema_key(data, file):
    """The scene dict without its ``"$schema"`` key (a string: the JSON Schema's path or URL, read by editors)."""
    if SCHEMA_KEY not in data:
        return data
    if not isinstance(data[SCHEMA_KEY], str):
        raise SceneError(file, SCHEMA_KEY, f"expected the path or URL of the JSON Schema (a string), got "
                                           f"{shown(data[SCHEMA_KEY])}")
    return {k: v for k, v in data.items() if k != SCHEMA_KEY}


def parse_dataclass(cls, data, file=None, key=""):
    """Builds the schema class ``cls`` from a JSON object, checking every key; raises :class:`SceneError`
    naming ``file`` and the key path below ``key``."""
    if not isinstance(data, dict):
        raise SceneError(file, key or "scene", f"expected an object, got {shown(data)}")
    if cls is Scene:
        data = _without_schema_key(data, file)
    data = _drop_obsolete(cls, data, file, key)
    if cls is Scene and "source" in data:
        raise SceneError(file, "source", "unknown key (it is set on load)")
    own = {}
    if cls is Scene and "solver" in data:  # the chosen solver's own keys apart (_with_parameters)
        common, own = _split_solver(data["solver"], file)
        data = {**data, "solver": common}
    try:
        text = json.dumps(data, default=_plain)
    except (TypeError, ValueError) as exc:
        raise SceneError(file, key or "scene", f"not JSON data: {exc}") from None
    data = json.loads(text)
    try:
        obj = _adapter(cls).validate_json(text)
    except ValidationError as exc:
        raise _scene_error(cls, data, exc.errors()[0], file, key) from None
    if cls is Scene:
        obj = dataclasses.replace(obj, models=tuple(parse_model(m, file, f"models[{n}]") for n, m in enumerate(obj.models)),
                                  solver=_with_parameters(obj.solver, own, file))
    _check_tree(obj, file, key)
    return obj


def parse_model(value, file=None, key="models[0]"):
    """A scene's model entry {"type": NAME, ...}: the registered plug-in's ``Parameters``."""
    from .models import scene_models

    known = scene_models()
    if not isinstance(value, dict) or "type" not in value:
        raise SceneError(file, key, f'expected an object with a "type" ({", ".join(known)}), got {shown(value)}')
    name = value["type"]
    if name not in known:
        close = difflib.get_close_matches(str(name), known, n=1)
        hint = f"; did you mean '{close[0]}'?" if close else f"; known: {', '.join(known)}"
        raise SceneError(file, f"{key}.type", f"unknown model {json.dumps(name)}{hint}")
    return parse_dataclass(known[name].Parameters, {k: v for k, v in value.items() if k != "type"}, file, key)


def model_types():
    """{name: Parameters class} of the models a scene can name."""
    from .models import scene_models

    return {name: cls.Parameters for name, cls in scene_models().items()}


def _solver_json_schema(block):
    """Completes the JSON Schema of the solver block, ``block`` (:class:`Solver`'s keys): the registered solvers in
    ``method``'s enum and description, their own keys (each description starts with the solvers that have it), and
    per solver an if/then that refuses the keys of the others, as the loader does."""
    classes, names, owners = solver_classes(), solver_names(), solver_keys()
    method = block["properties"]["method"]
    method["enum"] = names
    method["description"] += "; " + "; ".join(f"{n}: {classes[n].summary}" if classes[n].summary else n for n in names)
    for name in names:
        params = classes[name].Parameters
        for k, sub in (_adapter(params).json_schema()["properties"].items() if params is not None else ()):
            if k not in block["properties"]:
                block["properties"][k] = {**sub, "description": f"({', '.join(owners[k])}) {sub.get('description', '')}"}
    rules = []
    for name in names:
        theirs = [k for k, owned in owners.items() if name not in owned]
        if theirs:  # the default solver's rule applies where method is left out
            condition = {"properties": {"method": {"const": name}}}
            if name != DEFAULT_SOLVER:
                condition["required"] = ["method"]
            rules.append({"if": condition, "then": {"properties": {k: False for k in theirs}}})
    if rules:
        block["allOf"] = rules


def scene_json_schema() -> dict:
    """The JSON Schema (draft 2020-12) of a scene file, models included (``warpsph schema``)."""
    out = _adapter(Scene).json_schema()
    out["properties"].pop("source", None)
    entries = []
    for name, params in model_types().items():
        sub = _adapter(params).json_schema()
        sub["properties"] = {"type": {"const": name, "description": "the model"}, **sub["properties"]}
        sub["required"] = ["type"] + sub.get("required", [])
        entries.append(sub)
    out["properties"]["models"]["items"] = {"oneOf": entries}
    _solver_json_schema(out["$defs"]["Solver"])
    out["properties"] = {SCHEMA_KEY: {"type": "string", "description": "the path or URL of this JSON Schema, for "
                                                                       "editors (warpsph ignores it)"},
                         **out["properties"]}
    out["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    out["title"] = "warpsph scene"
    return out


def read_text(path, what):
    """The UTF-8 text of the ``what`` file ``path`` (a BOM is dropped); a :class:`SceneError` that says why not."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise SceneError(path, "", f"cannot read the {what} file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise SceneError(path, "", f"not UTF-8 text (byte {exc.start}): save the {what} file as UTF-8") from None


def parse_json(text, path, what):
    """``text`` parsed as JSON; a :class:`SceneError` for invalid or too deeply nested JSON."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneError(path, "", f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise SceneError(path, "", f"not a {what}: its JSON is nested too deeply") from None


def load_scene(path, scale: float = 1.0, run_anyway=None) -> Scene:
    """Reads and validates a scene file.

    ``scale`` multiplies the particle count: the particle radius is divided by
    ``scale ** (1/3)``, so ``scale=0.01`` runs a 1 % version of the scene and the
    scene file keeps the paper's full-size radius. ``run_anyway``: a SPlisHSPlasH scene
    runs without the physics warpsph refuses (see :mod:`warpsph.io.splishsplash`).

    Example:

    ```python
    import warpsph

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.01)  # a 1 % version: 4.6x the radius
    sim = warpsph.Simulation(scene)
    ```
    """
    path = Path(path)
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise SceneError(path, "--scale", f"expected a number > 0, got {scale}")
    data = parse_json(read_text(path, "scene"), path, "scene")
    from .io.splishsplash import convert, is_splishsplash

    conversion = None
    if is_splishsplash(data):  # a SPlisHSPlasH scene file
        from .io.splishsplash import conversion_of

        data = convert(data, path, run_anyway=run_anyway)
        conversion = conversion_of(path)
    try:
        scene = parse_dataclass(Scene, data, path)
    except SceneError as exc:  # a SPlisHSPlasH value warpsph cannot take: name the user's key, not ours
        theirs = conversion.their_key(exc.key) if conversion is not None else None
        if theirs is None:
            raise
        raise SceneError(path, theirs, f"{exc.reason} (as warpsph's {exc.key})") from None
    return rescale(dataclasses.replace(scene, source=str(path)), scale)


def key_path(path: str) -> list:
    """The steps of a dotted key path with list indices: "models[0].beta" -> ["models", 0, "beta"];
    ValueError for a malformed one."""
    steps = []
    for part in path.split("."):
        name, _, rest = part.partition("[")
        if not name.isidentifier() or (rest and not rest.endswith("]")):
            raise ValueError(f"'{path}': expected NAME or NAME[K] parts joined by dots, e.g. models[0].beta")
        steps.append(name)
        for index in rest[:-1].split("][") if rest else ():
            if not index.isdigit():
                raise ValueError(f"'{path}': expected an index [K] with K an integer >= 0, got [{index}]")
            steps.append(int(index))
    return steps


def with_overrides(data: dict, overrides=None) -> dict:
    """A copy of the scene dict ``data`` with the key paths of ``overrides`` set, in their order, e.g.
    {"solver.density_max_error": 0.05, "time.cfl": 0.4, "models[0].beta": 0.6} (studies and sweeps change
    keys of a scene). A missing object on the way is created; a list index must exist (ValueError)."""
    data = json.loads(json.dumps(data))
    for path, value in (overrides or {}).items():
        node, steps = data, key_path(path)
        for k, step in enumerate(steps):
            where = path if k == len(steps) - 1 else _path_text(steps[:k + 1])
            if isinstance(step, int):
                if not isinstance(node, list) or step >= len(node):
                    size = f"a list of {len(node)}" if isinstance(node, list) else "not a list"
                    raise ValueError(f"'{where}': no such item ({_path_text(steps[:k]) or 'the scene'} is {size})")
            elif not isinstance(node, dict):
                raise ValueError(f"'{where}': {_path_text(steps[:k])} is not an object")
            if k == len(steps) - 1:
                node[step] = value
            else:
                node = node[step] if isinstance(step, int) else node.setdefault(step, {})
    return data


def _path_text(steps):
    return "".join(f"[{s}]" if isinstance(s, int) else ("." if i else "") + s for i, s in enumerate(steps))


def scene_from_dict(data: dict, base_dir=None, scale: float = 1.0) -> Scene:
    """Builds a scene from a dict (for scripts and tests); mesh paths resolve against ``base_dir``.

    Example:

    ```python
    import warpsph

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}], "output": {"fps": 30}})
    ```
    """
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


def _default_text(info):
    from pydantic_core import PydanticUndefined

    if info.default is PydanticUndefined:
        return "required"
    value = info.default
    if dataclasses.is_dataclass(value):
        return "{}"
    return json.dumps(value, default=list)


def _reference_rows(cls, prefix, seen, sections, title=None):
    """Appends (title, doc, rows) for ``cls`` and the schema classes below it, depth first."""
    rows, below = [], []
    for name, tp in _hints(cls).items():
        if cls is Scene and name == "source":
            continue
        info = cls.__pydantic_fields__[name]
        inner = _unwrap(tp)
        if typing.get_origin(inner) is tuple and typing.get_args(inner)[-1] is Ellipsis:
            inner = typing.get_args(inner)[0]
            path = f"{prefix}{name}[]"
        else:
            path = f"{prefix}{name}"
        unit = (info.json_schema_extra or {}).get("unit", "") if isinstance(info.json_schema_extra, dict) else ""
        rows.append((f"`{path}`", _expect(cls, name), unit, f"`{_default_text(info)}`", info.description or ""))
        if dataclasses.is_dataclass(inner) and inner not in seen:
            seen.add(inner)
            below.append((inner, f"{path}."))
    sections.append((title or prefix.rstrip(".") or "top level", (cls.__doc__ or "").strip(), rows))
    for inner, path in below:
        _reference_rows(inner, path, seen, sections)


def reference_markdown() -> str:
    """Every scene-file key with its type and range, unit, default and meaning, as markdown (the docs'
    scene reference; ``warpsph schema --markdown``). Generated from the schema classes."""
    sections = []
    _reference_rows(Scene, "", {Scene}, sections)
    classes = solver_classes()
    names = [json.dumps(n) for n in solver_names()]
    for _, _, rows in sections:  # solver.method: the registered solvers
        for n, row in enumerate(rows):
            if row[0] == "`solver.method`":
                rows[n] = (row[0], ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else names[0], *row[2:])
    for name in solver_names():
        params = classes[name].Parameters
        if params is not None:
            _reference_rows(params, "solver.", {params}, sections, title=f'solver: "method": "{name}"')
    for name, params in model_types().items():
        _reference_rows(params, "models[].", {params}, sections, title=f'models[]: "type": "{name}"')
    out = ["# Scene reference", "",
           "Every key of a scene file (JSON; SI units). Generated from the schema in `warpsph/scene.py`, the "
           "pressure solvers' and the models' `Parameters` (a solver's own keys sit in the `solver` block beside the "
           "keys every solver reads, and only with that solver); `warpsph schema` prints the same as JSON Schema for editors (a scene file may name "
           'it in a top-level `"$schema"` key, which warpsph ignores: see the '
           "[user guide](guide.md#completion-and-checking-in-an-editor)).", ""]
    for title, doc, rows in sections:
        out += [f"## {title}", "", " ".join(doc.split()), "", "| key | expects | unit | default | meaning |",
                "|---|---|---|---|---|"]
        out += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
        out.append("")
    return "\n".join(out)
