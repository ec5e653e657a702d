"""Validation against experiment, small enough for CI: the Martin & Moyce (1952) dam-break front."""

import numpy as np
import pytest

from warpsph.validation.dam_front import MARTIN_MOYCE, compare, dam_front

pytestmark = pytest.mark.slow  # the dam front and the Lamb-Oseen vortex run to the end of the experiment


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


def test_lamb_oseen_vortex_decays_like_the_analytic_solution():
    """A Lamb-Oseen vortex (2,400 particles, nu = 0.01, T = 0.5 s, plain DFSPH) against
    u_theta(r, t) = Gamma / (2 pi r) (1 - exp(-r^2 / (4 nu (t0 + t)))), from the lattice (no packing). Measured
    (cpu): peak vorticity 1.017 of the same fit of the analytic field, its decay 0.551 (exact 0.527), L1 error of
    u_theta 3.0 % of the peak speed (before the full tank's corrected operators: 1.18 and 4.2 %), u_theta peaking
    0.16 spacings inside the analytic radius. A simulation with nu = 0.02 (or 0.001) instead of 0.01 fails the
    vorticity bounds (0.55, 1.56)."""
    from warpsph.validation.lamb_oseen import lamb_oseen, summary

    rows, sim, p = lamb_oseen([], resolution=20, nu=0.01, T=0.5, frames=10, device="cpu")
    d, s = p["spacing"], summary(rows, 0.01)
    assert sim.num_fluid == 2400 and abs(rows[-1]["time"] - 0.5) < 0.01
    omega = [r["omega_fit"] for r in rows]
    assert np.all(np.diff(omega) < 0)  # the peak vorticity decays, every frame
    assert 0.7 < s["omega_decay"] / s["omega_decay_exact"] < 1.35  # default solver, 20 across: 1.045
    # against the same fit of the analytic field (goal of #16: within 5 %, no overshoot)
    assert abs(s["omega_ratio_end"] - 1) < 0.05
    assert 0.7 < rows[-1]["omega_curl_ratio"] < 1.1  # the simulator's own SPH curl agrees
    assert s["l1_relative_end"] < 0.05
    # the u_theta peak moves out with the core, and sits where the analytic one does
    assert s["r_peak_end"] - rows[0]["r_peak"] > 0.5 * d
    assert abs(s["r_peak_end"] - s["r_peak_exact_end"]) < 0.5 * d
    assert s["centre_offset_end"] < 0.2 * d  # the vortex stays at the box centre
