"""Readers and writers. Public: :class:`UsdWriter` (a USD point cache of a run, usable as the
``on_frame`` of :meth:`warpsph.Simulation.run`). USD needs usd-core (``pxr``), imported on first
use so that ``import warpsph.io`` stays cheap."""

__all__ = ["UsdWriter"]


def fsync(path):
    """Flushes the file ``path`` to the disk, or the folder ``path`` (a rename in it then survives a power cut)."""
    import os

    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def __getattr__(name):
    if name == "UsdWriter":
        from .usd import UsdWriter

        return UsdWriter
    raise AttributeError(f"module 'warpsph.io' has no attribute {name!r}")
