"""Readers and writers. Public: :class:`UsdWriter` (a USD point cache of a run, usable as the
``on_frame`` of :meth:`warpsph.Simulation.run`). USD needs usd-core (``pxr``), imported on first
use so that ``import warpsph.io`` stays cheap."""

__all__ = ["UsdWriter"]


def __getattr__(name):
    if name == "UsdWriter":
        from .recorder import UsdWriter

        return UsdWriter
    raise AttributeError(f"module 'warpsph.io' has no attribute {name!r}")
