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


def test_calm_times_of_an_exponential_decay_against_the_baseline():
    t_s, tau = 5.0, 0.5
    decay = lambda tau: lambda t: 50 * np.exp(-np.clip(t - t_s, 0, None) / tau)  # noqa: E731
    rows = [_row("DFSPH", decay(tau)),
            _row("Rankine", lambda t: 2 * decay(2 * tau)(t), [{"type": "rankine", "beta": 0.6}],
                 rot=lambda t: 0.01 * decay(tau)(t)),  # twice the energy at the stop: 10 % of DFSPH's later
            _row("slow", decay(1.5)),  # 1 % after 6.9 s, past the run's end
            _row("blew up", decay(tau), t_end=4.0)]
    rows[3]["status"], rows[3]["unstable"] = "unstable", "NaN at step 9"
    out = pt.calm({**META, "stop_time": t_s}, rows)
    frame = 1 / 25
    assert out[0]["E_s (J)"] == pytest.approx(50, rel=1e-3)
    assert out[0]["calm 10% (s)"] == pytest.approx(tau * np.log(10), abs=frame)
    assert out[0]["calm 1% (s)"] == pytest.approx(tau * np.log(100), abs=frame)
    assert out[0]["calm 10% (s)"] >= tau * np.log(10)  # the first frame below, not one before
    assert out[1]["calm 1% (s)"] == pytest.approx(2 * tau * np.log(100), abs=frame)
    assert out[1]["calm 10% / DFSPH"] == pytest.approx(2, abs=2 * frame / (tau * np.log(10)))
    assert out[1]["E_s (J)"] == pytest.approx(100, rel=1e-3) and out[1]["E_rot,s (J)"] == pytest.approx(0.5, rel=1e-3)
    assert out[0]["E_end / E_s"] == pytest.approx(np.exp(-4.8 / tau), rel=0.2)
    assert out[1]["calm 10% of DFSPH's E_s (s)"] == pytest.approx(2 * tau * np.log(20), abs=frame)  # 100 -> 5 J
    assert out[1]["E stirring (J)"] == pytest.approx(100)
    assert out[2]["calm 10% (s)"] == pytest.approx(1.5 * np.log(10), abs=frame)
    assert out[2]["calm 1% (s)"] is None and out[2]["calm 1% / DFSPH"] is None
    assert out[3]["E_s (J)"] is None and out[3]["calm 10% (s)"] is None and out[3]["unstable"] == "NaN at step 9"


def test_calm_stop_time_from_the_scene_and_the_table(tmp_path):
    import json

    sweep = Path(__file__).resolve().parent.parent / "sweeps" / "rankine_fig3_cpu.json"
    assert pt.stop_time(sweep) == pytest.approx(5.0)  # the rod's last keyframe: pulled out by 5 s
    spin = {"scene": str(Path(__file__).resolve().parent.parent / "scenes" / "propeller_rankine.json"),
            "scale": 0.001, "time": 1.0, "cells": [{"models": []}]}
    assert pt.stop_time(spin) is None  # spins to the end: --stop needed
    rows = [_row("DFSPH", lambda t: np.exp(-np.clip(t - 2.0, 0, None)))]
    md = pt.markdown("calm", {**META, "device": "cpu", "warp": "1.19.0"}, pt.calm({**META, "stop_time": 2.0}, rows),
                     pt.NOTES["calm"])
    assert "| DFSPH | 100 | 10 | 1 | 1 | 1 | 0 | 2.32 | 4.64 | 1 | 1 | 2.32 | 0.000413 | 10 |" in md
    json.dumps(pt.calm({**META, "stop_time": 2.0}, rows))  # the JSON result takes it


def test_calm_from_cell_files_with_the_scene_stop_and_with_stop(tmp_path):
    """The calm kind end to end on made-up cell files of a stirring-rod sweep: t_s from the rod's keyframes (5 s),
    then --stop 6; an unstable cell is listed as such."""
    import json

    from warpsph.sweep import _cell_path, cells, load_sweep

    sweep = tmp_path / "fig3.json"
    sweep.write_text(json.dumps({
        "name": "fig3", "scene": str(Path(__file__).resolve().parent.parent / "scenes" / "stirring_rod_rankine.json"),
        "scale": 0.001, "time": 10.0, "device": "cpu",
        "cells": [{"models": []}, {"models": [{"type": "rankine", "beta": 0.6}]}]}))
    t = np.arange(0, 251) / 25 + 1e-4
    for cell, tau, status in zip(cells(load_sweep(sweep)), (0.5, 1.0), ("done", "unstable")):
        ke = 10 * np.exp(-np.clip(t - 5.0, 0, None) / tau)
        row = {"particles": 1000, "steps": 500, "time_reached": 10.0, "wall_s": 3.0, "frame_times": t.tolist(),
               "kinetic_energy": ke.tolist(), "rotational_energy": (0.1 * ke).tolist(),
               "unstable": "NaN at 9.9 s" if status == "unstable" else None}
        path = _cell_path(tmp_path / "out", cell)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"params": cell["params"], "case": cell["case"], "status": status, "row": row,
                                    "device": "cpu", "warp": "1.19.0"}))
    pt.main(["calm", str(sweep), str(tmp_path / "out"), "--json", str(tmp_path / "calm.json")])
    out = json.loads((tmp_path / "calm.json").read_text())
    assert out["stop_time"] == 5.0 and out["stop_from"] == "the scene's last keyframe"
    dfsph, rankine = out["rows"]
    assert dfsph["calm 10% (s)"] == pytest.approx(0.5 * np.log(10), abs=0.04)
    assert rankine["calm 1% / DFSPH"] == pytest.approx(2, abs=0.04) and rankine["status"] == "unstable"
    assert rankine["E_rot,s (J)"] == pytest.approx(1, rel=1e-3)
    assert "Rankine beta = 0.6: unstable (NaN at 9.9 s)" in (tmp_path / "calm.md").read_text()
    pt.main(["calm", str(sweep), str(tmp_path / "out"), "--json", str(tmp_path / "calm6.json"), "--stop", "6"])
    out = json.loads((tmp_path / "calm6.json").read_text())
    assert out["stop_time"] == 6.0 and out["command"].endswith("--stop 6")
    assert out["rows"][0]["E_s (J)"] == pytest.approx(10 * np.exp(-2), rel=1e-3)  # one tau of 0.5 s later
    assert out["rows"][0]["calm 10% (s)"] == pytest.approx(0.5 * np.log(10), abs=0.04)
