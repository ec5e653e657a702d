"""Sweep functions for tests/test_reliability.py (imported by name in the cells' spawned processes)."""

import os
import signal


def die_or_square(device, x):
    """x * x, except x = 2, whose process kills itself with SIGKILL (as the out-of-memory killer would), unless
    the file named by SWEEP_TEST_SURVIVE exists."""
    if x == 2 and not os.path.exists(os.environ.get("SWEEP_TEST_SURVIVE", "/nonexistent")):
        os.kill(os.getpid(), signal.SIGKILL)
    return {"square": x * x}
