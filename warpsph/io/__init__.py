"""Readers and writers. Public: :class:`UsdWriter` (a USD point cache of a run, usable as the
``on_frame`` of :meth:`warpsph.Simulation.run`). USD needs usd-core (``pxr``), imported on first
use so that ``import warpsph.io`` stays cheap.

Example:

```python
import warpsph

sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
with warpsph.io.UsdWriter("out/dam_break.usdc", sim) as usd:
    sim.run(frames=5, on_frame=usd)
```
"""

__all__ = ["UsdWriter"]


def __getattr__(name):
    if name == "UsdWriter":
        from .recorder import UsdWriter

        return UsdWriter
    raise AttributeError(f"module 'warpsph.io' has no attribute {name!r}")
