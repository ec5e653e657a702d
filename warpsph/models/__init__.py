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
    """Class decorator that makes a model available to scenes under ``name``."""

    def wrap(cls):
        REGISTRY[name] = cls
        cls.name = name
        return cls

    return wrap


class Model:
    """Base class with the do-nothing parts of the interface."""

    name = "model"
    needs_vorticity = False
    scratch_columns = 0

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


from . import micropolar, rankine, viscosity, vorticity_refinement  # noqa: E402,F401  (register the models)
