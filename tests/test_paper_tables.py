"""tools/paper_tables.py (#21): the figure tables from a sweep's per-frame series, on made-up series (no run)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location("paper_tables", Path(__file__).resolve().parent.parent / "tools" / "paper_tables.py")
pt = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(pt)


def _row(label, ke, models=(), t_end=10.0, fps=25, rot=None):
    t = np.arange(0, int(t_end * fps) + 1) / fps + 1e-4  # frame times end a little after the frame's time
    return {"label": label, "params": {"models": list(models)}, "status": "done", "particles": 100, "steps": 10,
            "wall_s": 1.0, "t": t, "ke": ke(t), "rot": rot(t) if rot else np.zeros_like(t), "ens": np.zeros_like(t),
            "particles_end": 100, "unstable": None}


META = {"time": 10.0, "scene": "x.json", "scale": 0.01, "fixed": {}}


def test_vr_fig7_ratios_and_the_settled_criterion():
    base = _row("DFSPH", lambda t: 100 * np.exp(-t))
    same = _row("same", lambda t: 100 * np.exp(-t), [{"type": "vorticity_refinement", "alpha": 1.0}])
    double = _row("double late", lambda t: 100 * np.exp(-t) * np.where(t > 8.5, 2.0, 1.0))
    rows = pt.vr_fig7(META, [base, same, double])
    assert rows[1]["E/E_DFSPH t=2"] == pytest.approx(1) and rows[1]["mean E/E_DFSPH [2,8]"] == pytest.approx(1)
    assert rows[1]["settled"] is True
    assert rows[2]["E[9,10] / E_DFSPH[9,10]"] == pytest.approx(2) and rows[2]["settled"] is False  # > 1.5x
    assert rows[2]["E/E_DFSPH t=8"] == pytest.approx(1) and rows[2]["E/E_DFSPH t=10"] == pytest.approx(2)


def test_blocks_peak_time_and_each_solver_its_own_baseline():
    peak = lambda t: np.exp(-((t - 1.6) / 0.3) ** 2)  # noqa: E731
    rows = [_row("DFSPH", peak, t_end=8.0), _row("IISPH", lambda t: 2 * peak(t), t_end=8.0),
            _row("Rankine (IISPH)", lambda t: 2 * peak(t), [{"type": "rankine", "beta": 0.6}], t_end=8.0,
                 rot=lambda t: 0.1 * peak(t))]
    rows[1]["params"]["solver.method"] = rows[2]["params"]["solver.method"] = "iisph"
    out = pt.blocks(META, rows)
    assert [r["peak time (s)"] for r in out] == pytest.approx([1.6] * 3, abs=0.02)
    assert out[2]["peak / baseline peak"] == pytest.approx(1)  # against IISPH, not DFSPH
    assert out[2]["E_rot peak (J)"] == pytest.approx(0.1, rel=1e-3)


def test_thin_picks_the_frames_nearest_each_step():
    t = np.arange(0, 51) / 25 + 3e-5
    picked = pt.thin(t, t, step=0.2)
    assert [p[0] for p in picked] == pytest.approx([0.2 * k for k in range(11)], abs=1e-3)
