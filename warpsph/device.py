"""Warp's start and the ``--device`` choice, shared by the command line, sweeps and the studies (Warp itself is
imported by the calls, not by this module)."""

from __future__ import annotations

import os
import sys

from .errors import SceneError

CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


def init_warp():
    """wp.init() without the warning Warp's native library prints on a machine without a CUDA
    driver (for --device cuda the CLI says so itself); its other messages pass through."""
    import tempfile

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        text = captured.read().decode(errors="replace")
    sys.stderr.write("".join(line for line in text.splitlines(True) if CUDA_DRIVER_WARNING not in line))
    return wp


def pick_device(name):
    """The device ``name`` (auto, cpu, cuda, cuda:N) after :func:`init_warp`: auto is cuda:0 where CUDA is present, else
    cpu; a :class:`SceneError` (key --device) naming the devices there are when ``name`` is not one."""
    wp = init_warp()
    if name == "auto":
        return "cuda:0" if wp.is_cuda_available() else "cpu"
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise SceneError("", "--device", f"'{name}' was asked for but this machine has no CUDA device; use --device cpu")
    try:
        wp.get_device(name)
    except (ValueError, RuntimeError, TypeError):
        known = ", ".join(["auto", "cpu"] + [f"cuda:{n}" for n in range(wp.get_cuda_device_count())])
        raise SceneError("", "--device", f"unknown device '{name}'; this machine has {known}") from None
    return name
