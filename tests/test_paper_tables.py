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


def test_vr_fig10_flowing_and_after_means_and_a_short_run():
    meta = {**META, "time": 20.0}
    base = _row("DFSPH", lambda t: 100 * np.exp(-t / 5) + 1, t_end=20.0)
    vr = _row("VR", lambda t: 0.9 * (100 * np.exp(-t / 5) + 1), [{"type": "vorticity_refinement", "alpha": 1.0}],
              t_end=20.0)
    late = _row("late", lambda t: (100 * np.exp(-t / 5) + 1) * np.where(t > 15, 3.0, 1.0), t_end=20.0)
    short = _row("short", lambda t: 100 * np.exp(-t / 5) + 1, t_end=12.0)
    rows = pt.vr_fig10(meta, [base, vr, late, short])
    assert rows[1]["E/E_DFSPH t=2.5"] == pytest.approx(0.9) and rows[1]["E/E_DFSPH t=15"] == pytest.approx(0.9)
    assert rows[1]["mean E/E_DFSPH [0,15]"] == pytest.approx(0.9)
    assert rows[1]["mean E/E_DFSPH [15,end]"] == pytest.approx(0.9)
    assert rows[1]["settled"] is True
    assert rows[2]["mean E/E_DFSPH [0,15]"] == pytest.approx(1)  # flowing: as DFSPH; after: 3x
    assert rows[2]["mean E/E_DFSPH [15,end]"] == pytest.approx(3, rel=0.01)
    assert rows[2]["E[19,20] / E_DFSPH[19,20]"] == pytest.approx(3) and rows[2]["settled"] is False
    assert rows[3]["E/E_DFSPH t=10"] == pytest.approx(1) and rows[3]["E/E_DFSPH t=12.5"] is None
    assert rows[3]["mean E/E_DFSPH [0,15]"] is None and rows[3]["mean E/E_DFSPH [15,end]"] is None
    assert rows[3]["settled"] is None


def test_table1_overheads_and_a_missing_file(tmp_path):
    import json

    def bench(scene, model, ms):
        (tmp_path / f"table1_{scene}_{model}.json").write_text(json.dumps(
            {"scene": scene, "model": model, "device": "GPU", "warp": "1.19.0", "commit": "abc1234",
             "fluid_particles": 1000, "ms_per_step": ms}))

    bench("dam_break_board", "none", 5.0)
    bench("dam_break_board", "micropolar", 6.0)
    bench("dam_break_board", "vorticity_refinement", 5.5)
    bench("propeller", "none", 4.0)
    bench("stirring_rod", "vorticity_refinement", 7.0)
    (tmp_path / "table1_stirring_rod_none.json").write_text(  # a "DFSPH" bench that ran the scene's VR
        (tmp_path / "table1_stirring_rod_vorticity_refinement.json").read_text())
    pt.main(["table1", str(tmp_path), "--json", str(tmp_path / "t1.json")])
    out = json.loads((tmp_path / "t1.json").read_text())
    board, propeller = out["rows"][0], out["rows"][4]
    assert (board["experiment"], board["figure"], board["particles"]) == ("Board", 3, 1000)
    assert board["MP overhead %"] == pytest.approx(20) and board["VR overhead %"] == pytest.approx(10)
    assert propeller["DFSPH ms/step"] == 4.0 and propeller["MP ms/step"] is None and propeller["VR overhead %"] is None
    assert out["rows"][1]["DFSPH ms/step"] is None and out["rows"][1]["VR ms/step"] == 7.0
    assert out["not used"] == ["table1_stirring_rod_none.json ran vorticity_refinement"]
    assert out["rows"][2]["experiment"] == "Sphere" and out["rows"][2]["particles"] is None
    assert [r["paper VR overhead %"] for r in out["rows"]] == [6.8, 12.2, 10.2, 39.7, 31.2]
    assert [r["paper MP overhead %"] for r in out["rows"]] == [6.9, 19.4, 3.5, 20.4, 29.6]
    assert (out["device"], out["warp"], out["commit"]) == ("GPU", "1.19.0", "abc1234")
    assert "| Board | 3 | 1000 | 5 | 6 | 5.5 | 20 | 10 |" in (tmp_path / "t1.md").read_text()
