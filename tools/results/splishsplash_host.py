"""What the SPlisHSPlasH reference scripts beside this file record about the machine and SPlisHSPlasH's version."""

import os
import platform
import subprocess

SPLISH_PY = "/work/splish-venv/bin/python"  # the interpreter with pysplishsplash 2.19 (its own virtual environment)


def machine():
    """The CPU model, core count and platform."""
    model = ""
    try:
        model = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": model, "cores": os.cpu_count(), "platform": platform.platform()}


def splish_version(python=SPLISH_PY):
    """pysplishsplash's version in ``python``'s environment."""
    p = subprocess.run([python, "-m", "pip", "show", "pysplishsplash"], capture_output=True, text=True)
    return next((l.split(":", 1)[1].strip() for l in p.stdout.splitlines() if l.startswith("Version")), "unknown")
