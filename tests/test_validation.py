"""Validation against experiment, small enough for CI: the Martin & Moyce (1952) dam-break front."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))

from validate_dam_front import MARTIN_MOYCE, compare, dam_front  # noqa: E402


def test_dam_front_follows_martin_and_moyce():
    T, Z, sim = dam_front(resolution=8, device="cpu", T_end=5.0)
    assert np.all(np.diff(Z) > -0.05)  # the front only advances
    result = compare(T, Z)
    assert result["shifted_points"] >= 8
    # the front runs ahead of the experiment by the gate-release delay, about a quarter of T
    assert -0.6 < result["time_shift_T"] < 0.0
    assert result["shifted_rms"] < 0.25  # in units of the column width a
    assert result["raw_rms"] < 0.6
    assert len(MARTIN_MOYCE) == 12
