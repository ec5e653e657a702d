"""warpsph: DFSPH fluids on NVIDIA Warp with turbulence refinement models.

``Simulation`` (which imports Warp) and ``io`` (USD needs usd-core) load on first use, so
``import warpsph`` stays fast. See ``examples/`` for runnable scripts.

Example:

```python
import warpsph

scene = warpsph.Scene.load("scenes/dam_break.json", scale=0.05)  # or warpsph.Scene.from_dict({...})
sim = warpsph.Simulation(scene, device="cpu")  # "cuda", "cuda:0" or None (Warp's default device)
with warpsph.io.UsdWriter("out/dam_break.usdc", sim) as usd:
    sim.run(frames=5, on_frame=usd)  # on_frame(sim, frame) after each frame
x, v = sim.positions(), sim.velocities()  # numpy copies; sim.fluid.x is the Warp array
```
"""

__version__ = "0.1.0"

import logging as _logging

from . import log as _log
from .errors import SceneError  # noqa: F401
from .scene import Scene, load_scene, scene_from_dict  # noqa: F401

_logging.getLogger(__name__).addHandler(_logging.NullHandler())  # the program decides what is shown (warpsph.log)
_log.quiet_warp_on_import()  # and Warp prints no banner unless asked (warpsph.log.quiet_warp)

__all__ = ["Scene", "Simulation", "DecomposedSimulation", "InstabilityError", "SceneError", "load_scene", "scene_from_dict", "io",
           "__version__"]

_LAZY = {"Simulation": "warpsph.simulation", "InstabilityError": "warpsph.simulation",
         "DecomposedSimulation": "warpsph.decomposition"}


def __getattr__(name):
    """Lazy attributes: ``Simulation`` imports Warp, ``io`` the writers, on first use."""
    import importlib

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    if name == "io":
        return importlib.import_module("warpsph.io")
    raise AttributeError(f"module 'warpsph' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
