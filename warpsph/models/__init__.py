"""Non-pressure models: viscosity and the turbulence models, each a plug-in.

Every model has the same small interface (after SPlisHSPlasH's ``NonPressureForceBase``):

- ``__init__(sim, params)`` allocates the model's own per-particle arrays through
  ``sim.per_particle(owner, dtype)`` (accounted per model, sized for emitted particles too,
  and zeroed where an emitter adds particles);
- ``step(sim)`` runs in the non-pressure phase of the step, after the divergence
  solve, adding to ``sim.fluid.acceleration`` or refining ``sim.fluid.v`` directly;
- ``emitted(sim, first, count)`` marks rows ``first .. first + count - 1``, just added by an emitter
  (zeroed), as new to the model (``NO_HISTORY``), so it does not take their zeroed state for history;
- ``reorder(sim, order)`` permutes the model's per-particle state when the fluid is
  re-sorted by cell;
- ``fields()`` returns the per-particle arrays it publishes for output, by name;
  ``state()`` the arrays a checkpoint must keep;
- ``scratch_columns`` (floats per particle) sizes the scratch pool that ``sim.scratch(dtype,
  column)`` hands out for values living within the model's step; models share it;
- ``needs_vorticity`` asks the stepper for the shared vorticity field, computed once per
  step after the divergence solve.

A model is one module here plus its kernels in ``kernels/``: the module declares the scene
parameters (``Parameters``, a frozen pydantic dataclass whose fields carry their units, ranges and
docs; the scene's ``{"type": NAME, ...}`` entries are validated against it), the registration name,
``bytes_per_particle`` (what ``per_particle`` allocates, for the memory check before a run) and the
parts of the interface above. Nothing else in warpsph names a model: ``@register("name")`` is the
whole registration (tests/test_plugins.py defines one inside the test file).

A scene names its models; a scene without one launches none of their kernels and
allocates none of their arrays.
"""

from __future__ import annotations

import math

import warp as wp

REGISTRY: dict = {}

# History of a particle an emitter just added: the models read NaN in their carried vector (``wp.isnan``
# of its first component) as "none yet" and skip the particle's first correction, as they skip everyone's
# on the first step. The marker travels with the particle through re-sorting, sinks and checkpoints.
NO_HISTORY = wp.vec3(math.nan, math.nan, math.nan)


def register(name):
    """Class decorator that makes a model available to scenes under ``name``: ``{"type": name, ...}``
    in a scene's "models" is validated against ``cls.Parameters``. Re-registering a name replaces it."""

    def wrap(cls):
        if cls.Parameters is not None:
            cls.Parameters.plugin_name = name
        REGISTRY[name] = cls
        cls.name = name
        return cls

    return wrap


def scene_models():
    """{name: plug-in class} of the models a scene can name (those with ``Parameters``)."""
    return {name: cls for name, cls in REGISTRY.items() if cls.Parameters is not None}


def plugin_of(params):
    """The registered plug-in class of a scene's model entry (a ``Parameters`` instance)."""
    return REGISTRY[type(params).plugin_name]


class Model:
    """Base class with the do-nothing parts of the interface."""

    name = "model"
    Parameters = None  # the scene entry's pydantic dataclass; None: not named by scenes (viscosity)
    bytes_per_particle = 0  # device bytes per fluid particle of its per_particle arrays (memory check)
    needs_vorticity = False  # the stepper computes the shared vorticity field of v~ for it
    computes_vorticity = False  # it fills the shared vorticity field itself (one pass fewer)
    scratch_columns = 0
    output_fields = {}  # name: bytes per particle of what fields() publishes (USD primvars, disk estimate)
    flag_names = ()  # host-side ints a checkpoint keeps (e.g. whether a history exists yet)

    def __init__(self, sim, params=None):
        self.params = params

    def step(self, sim):
        raise NotImplementedError

    def emitted(self, sim, first, count):
        pass

    def reorder(self, sim, order):
        pass

    def fields(self):
        return {}

    def state(self):
        return {}

    def flags(self):
        """Host-side state for a checkpoint, by name (``flag_names``)."""
        return {k: int(getattr(self, k)) for k in self.flag_names}

    def restore_flags(self, flags):
        for k, v in flags.items():
            setattr(self, k, int(v))

    def spin(self):
        """(per-particle angular velocity array [rad/s], micro-inertia per unit mass [m^2]) when the model
        carries its own spin (micropolar): the frame diagnostics' rotational energy; None: it does not."""
        return None


from . import micropolar, rankine, viscosity, vorticity_refinement  # noqa: E402,F401  (register the models)
