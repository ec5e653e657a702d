"""File helpers of the writers."""

import os


def fsync(path):
    """Flushes the file ``path`` to the disk, or the folder ``path`` (a rename in it then survives a power cut)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
