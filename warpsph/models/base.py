"""The model plug-in interface (:class:`Model`, :class:`ModelContext`) and the registry (:func:`register`),
described in ``warpsph.models``, which re-exports them (a plug-in imports them from there) and then imports its
own models. Those import this module, not the package: no import cycle (tests/test_imports.py)."""

from __future__ import annotations

import math

import warp as wp

REGISTRY: dict = {}

# History of a particle an emitter just added: the models read NaN in their carried vector (``wp.isnan``
# of its first component) as "none yet" and skip the particle's first correction, as they skip everyone's
# on the first step. The marker travels with the particle through re-sorting, sinks and checkpoints.
NO_HISTORY = wp.vec3(math.nan, math.nan, math.nan)
"""The carried vector of a particle with no history yet (NaN): :meth:`Model.emitted` marks new rows with it.

Example:

```python
import warp as wp
from warpsph.models import NO_HISTORY

@wp.kernel
def has_history(carried: wp.array(dtype=wp.vec3), out: wp.array(dtype=int)):
    out[wp.tid()] = int(not wp.isnan(carried[wp.tid()][0]))  # skip a new particle's first correction

carried, out = wp.array([NO_HISTORY, wp.vec3(0.0)], dtype=wp.vec3), wp.zeros(2, dtype=int)
wp.launch(has_history, 2, [carried, out])
assert out.numpy().tolist() == [0, 1]
```
"""


def register(name):
    """Class decorator that makes a model available to scenes under ``name``: ``{"type": name, ...}``
    in a scene's "models" is validated against ``cls.Parameters``. Re-registering a name replaces it.

    Example:

    ```python
    import warp as wp
    import warpsph
    from warpsph.models import Model, register
    from warpsph.scene import key, schema

    @wp.kernel
    def damp(v: wp.array(dtype=wp.vec3), rate: float, dt: wp.array(dtype=float)):
        v[wp.tid()] = v[wp.tid()] * (1.0 - rate * dt[0])

    @schema
    class Damping:  # a linear drag: the scene entry {"type": "damping", "rate": ...}
        rate: float = key(2.0, doc="drag rate", unit="1/s", ge=0.0)

    @register("damping")
    class DampingModel(Model):
        Parameters = Damping

        def step(self, ctx):
            ctx.launch(damp, ctx.num_fluid, [ctx.fluid.v, self.params.rate, ctx.dt])

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "damping", "rate": 5.0}]})
    warpsph.Simulation(scene).run(frames=2)
    ```
    """

    def wrap(cls):
        if cls.Parameters is not None:
            cls.Parameters.plugin_name = name
        REGISTRY[name] = cls
        cls.name = name
        return cls

    return wrap


def scene_models():
    """{name: plug-in class} of the models a scene can name (those with ``Parameters``).

    Example:

    ```python
    from warpsph.models import scene_models

    print(sorted(scene_models()))  # ['micropolar', 'rankine', 'vorticity_refinement', ...]
    print(scene_models()["rankine"].Parameters)  # the scene entry's parameters
    ```
    """
    return {name: cls for name, cls in REGISTRY.items() if cls.Parameters is not None}


def plugin_of(params):
    """The registered plug-in class of a scene's model entry (a ``Parameters`` instance)."""
    return REGISTRY[type(params).plugin_name]


class ModelContext:
    """What a model plug-in sees of the simulation: the fluid's arrays and count, the neighbour lists, the
    boundary samples, the shared vorticity field, the constants and the clock, and the allocation and
    launch calls. Nothing else (no solver, no bodies, no writers): the interface is this class.

    Example:

    ```python
    import warpsph
    from warpsph.models import Model, register
    from warpsph.scene import schema

    @schema
    class Probe:
        pass  # no parameters

    @register("probe")
    class ProbeModel(Model):  # {"type": "probe"}: reads the context each step
        Parameters = Probe

        def step(self, ctx):
            self.last = (ctx.num_fluid, ctx.particle_radius, ctx.device, ctx.host(ctx.fluid.v).shape)

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "probe"}]})
    sim = warpsph.Simulation(scene)
    sim.step()
    print(sim.turbulence_models[0].last)
    ```
    """

    __slots__ = ("_sim",)

    def __init__(self, sim):
        self._sim = sim

    device = property(lambda self: self._sim.device)
    """The simulation's Warp device."""
    scene = property(lambda self: self._sim.scene, doc="The scene (read-only data).")
    """The scene (read-only data)."""
    fluid = property(lambda self: self._sim.fluid, doc="x, v, ids, density, factor, acceleration (per particle).")
    """The fluid's per-particle arrays: x, v, ids, density, factor, acceleration."""
    num_fluid = property(lambda self: self._sim.num_fluid, doc="Rows that hold particles now.")
    """Rows that hold particles now."""
    neighbour_lists = property(lambda self: self._sim.neighbours.lists, doc="The kernels' Neighbours struct.")
    """The neighbour lists (the kernels' ``Neighbours`` struct)."""
    boundary_samples = property(lambda self: self._sim.boundary.samples, doc="The kernels' Boundary struct.")
    """The boundary samples (the kernels' ``Boundary`` struct)."""
    particle_mass = property(lambda self: self._sim.particle_mass)
    """A fluid particle's mass [kg]."""
    particle_radius = property(lambda self: self._sim.scene.particle_radius)
    """The particle radius r [m]."""
    support_radius = property(lambda self: self._sim.support_radius)
    """The kernel's support 4r [m]."""
    dt = property(lambda self: self._sim.dt, doc="This step's dt [s], a device array of one.")
    """This step's dt [s], a device array of one."""

    @property
    def viscous_substeps(self):
        """(n, dt / n, left): this step's viscosity sub-steps, their dt and a loop counter, device arrays of one; None
        when the scene takes none (``solver.viscosity_substeps`` 1)."""
        sim = self._sim
        return (*sim.viscous_substeps, sim.substeps_left) if sim.max_viscous_substeps > 1 else None

    @property
    def surface_flags(self):
        """Per particle, this step: BULK, BAND, SURFACE or WALL (kernels/free_surface.py), or None where the
        pressure solver does not detect the free surface (IISPH)."""
        return getattr(self._sim.pressure_solver, "surface", None)

    @property
    def detects_free_surface(self) -> bool:
        """Whether the pressure solver classifies the free surface (DFSPH; IISPH does not): :attr:`surface_flags`."""
        return bool(type(self._sim.pressure_solver).detects_free_surface)

    @property
    def vorticity(self):
        """The shared vorticity of v~ (eq 6) this step, or None when no model asked for it."""
        field = self._sim.vorticity_field
        return None if field is None else field.vorticity

    def launch(self, kernel, dim, inputs):
        """Launches ``kernel`` over ``dim`` threads with ``inputs`` on the simulation's device (counted per kernel)."""
        self._sim.launch(kernel, dim, inputs)

    def exchange(self, *arrays):
        """After a pass that wrote per-particle ``arrays`` which a later pass reads at the neighbours: the
        ghost rows of a decomposed simulation get their owners' values (a no-op on one domain)."""
        self._sim.exchange(*arrays)

    def per_particle(self, owner, dtype=float):
        """A zeroed per-particle array of ``capacity`` rows, counted under ``owner``."""
        return self._sim.per_particle(owner, dtype)

    def scratch(self, dtype, column=0):
        """A view of the shared scratch pool (values that live within one model's step)."""
        return self._sim.scratch(dtype, column)

    def permute(self, array, order):
        """array[:] = array[order] over the particles' rows (re-sorting)."""
        self._sim.permute(array, order)

    def active(self, array):
        """The rows of a per-particle array that hold particles (a view)."""
        return self._sim.active(array)

    def host(self, array):
        """The particles' rows of a per-particle array, copied to the host (a sync: not in a step)."""
        return self._sim.host(array)


class Model:
    """Base class with the do-nothing parts of the interface.

    Example:

    ```python
    import warpsph
    from warpsph.models import Model, register
    from warpsph.scene import schema

    @schema
    class Speed:
        pass  # no parameters

    @register("max_speed")
    class MaxSpeed(Model):  # {"type": "max_speed"}: publishes a per-particle field, keeps a flag
        Parameters = Speed
        output_fields = {"speed": 4}  # bytes per particle
        flag_names = ("steps",)

        def __init__(self, ctx, params):
            super().__init__(ctx, params)
            self.speed, self.steps = ctx.per_particle(self.name, float), 0

        def step(self, ctx):
            self.steps += 1

        def fields(self):
            return {"speed": self.speed}

    scene = warpsph.scene_from_dict({
        "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
        "models": [{"type": "max_speed"}]})
    sim = warpsph.Simulation(scene)
    sim.run(frames=1)
    print(sim.field_values("speed").shape, sim.turbulence_models[0].flags())
    ```
    """

    name = "model"
    """The registration name (set by :func:`register`)."""
    Parameters = None  # the scene entry's pydantic dataclass; None: not named by scenes (viscosity)
    """The scene entry's pydantic dataclass; None: scenes do not name the model (viscosity)."""
    bytes_per_particle = 0  # device bytes per fluid particle of its per_particle arrays (memory check)
    """Device bytes per fluid particle of its ``per_particle`` arrays (the memory check before a run)."""
    needs_vorticity = False  # the stepper computes the shared vorticity field of v~ for it
    """Whether the stepper computes the shared vorticity field of v~ for it."""
    computes_vorticity = False  # it fills the shared vorticity field itself (one pass fewer)
    """Whether it fills the shared vorticity field itself (one pass fewer)."""
    scratch_columns = 0
    """Floats per particle it takes from the shared scratch pool (``ctx.scratch``)."""
    kernel_modules = None  # names of the Warp modules of its kernels (warpsph.warmup); None: found from its module
    """Names of the Warp modules whose kernels it launches, compiled before the first step (:mod:`warpsph.warmup`);
    None: those of the kernels its Python module defines or imports."""
    output_fields = {}  # name: bytes per particle of what fields() publishes (USD primvars, disk estimate)
    """{name: bytes per particle} of what :meth:`fields` publishes (USD primvars; the disk estimate)."""
    flag_names = ()  # host-side ints a checkpoint keeps (e.g. whether a history exists yet)
    """Host-side ints a checkpoint keeps (e.g. whether a history exists yet)."""

    def __init__(self, ctx, params=None):
        """Allocates the model's arrays through ``ctx.per_particle``; ``params``: its ``Parameters``."""
        self.params = params

    def step(self, ctx):
        """The model's work in the non-pressure phase of a step (after the divergence solve)."""
        raise NotImplementedError

    def emitted(self, ctx, first, count):
        """Marks rows ``first .. first + count - 1``, just added by an emitter, as new (``NO_HISTORY``)."""

    def reorder(self, ctx, order):
        """Permutes the model's per-particle state when the fluid is re-sorted (``ctx.permute``)."""

    def fields(self):
        """The per-particle arrays it publishes for output, by name."""
        return {}

    def state(self):
        """The device arrays a checkpoint must keep, by name."""
        return {}

    def flags(self):
        """Host-side state for a checkpoint, by name (``flag_names``)."""
        return {k: int(getattr(self, k)) for k in self.flag_names}

    def restore_flags(self, flags):
        """Sets the host-side state of a checkpoint (:meth:`flags`)."""
        for k, v in flags.items():
            setattr(self, k, int(v))

    def spin(self):
        """(per-particle angular velocity array [rad/s], micro-inertia per unit mass [m^2]) when the model
        carries its own spin (micropolar): the frame diagnostics' rotational energy; None: it does not."""
        return None
