"""Non-pressure models: viscosity and the turbulence models, each a plug-in.

Every model has the same small interface (after SPlisHSPlasH's ``NonPressureForceBase``); each call
gets a :class:`ModelContext` (``ctx``), not the simulation:

- ``__init__(ctx, params)`` allocates the model's own per-particle arrays through
  ``ctx.per_particle(owner, dtype)`` (accounted per model, sized for emitted particles too,
  and zeroed where an emitter adds particles);
- ``step(ctx)`` runs in the non-pressure phase of the step, after the divergence
  solve, adding to ``ctx.fluid.acceleration`` or refining ``ctx.fluid.v`` directly;
- ``emitted(ctx, first, count)`` marks rows ``first .. first + count - 1``, just added by an emitter
  (zeroed), as new to the model (``NO_HISTORY``), so it does not take their zeroed state for history;
- ``reorder(ctx, order)`` permutes the model's per-particle state when the fluid is
  re-sorted by cell;
- ``fields()`` returns the per-particle arrays it publishes for output, by name;
  ``state()`` the arrays a checkpoint must keep;
- ``scratch_columns`` (floats per particle) sizes the scratch pool that ``ctx.scratch(dtype,
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

A shipped model in a scene (writing a new one: :func:`register`'s example).

Example:

```python
import warpsph
from warpsph.models import scene_models

print(sorted(scene_models()))  # what a scene's "models" may name
scene = warpsph.scene_from_dict({
    "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.2]},
    "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.2, 0.2]}],
    "models": [{"type": "vorticity_refinement"}]})
warpsph.Simulation(scene).run(frames=2)
```
"""

from .base import NO_HISTORY, REGISTRY, Model, ModelContext, plugin_of, register, scene_models  # noqa: F401
from . import micropolar, rankine, viscosity, vorticity_refinement  # noqa: F401  (register the models)

__all__ = ["register", "Model", "ModelContext", "scene_models", "NO_HISTORY"]
