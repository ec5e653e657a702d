"""warpsph/validation/paper_tables.py (#21): the figure tables from a sweep's per-frame series, on made-up series (no run)."""

from pathlib import Path

import numpy as np
import pytest

from warpsph.validation import paper_tables

pt = paper_tables


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
    spin["cells"] = [{"models": [], "obstacles[0].motion.spin_end": 6.0, "obstacles[0].motion.spin_down": 0.5}]
    assert pt.stop_time(spin) == pytest.approx(6.5)  # the spin stops by spin_end + spin_down
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


def test_vr_fig4_statistics_of_known_magnitudes():
    """|zeta| 1..100 on unit volumes: the mean, numpy's percentiles, the maximum and 1/2 sum V |zeta|^2."""
    mag = np.arange(1.0, 101.0)
    s = pt.vorticity_stats(mag, np.full(100, 2.0))
    assert s["particles"] == 100 and s["mean |zeta| (1/s)"] == pytest.approx(50.5)
    assert s["p90 |zeta|"] == pytest.approx(90.1) and s["p99 |zeta|"] == pytest.approx(99.01)
    assert s["max |zeta|"] == 100 and s["enstrophy"] == pytest.approx(np.sum(mag ** 2))
    assert pt.vorticity_stats([], [])["mean |zeta| (1/s)"] is None


def _rotating_lattice(omega, d=0.02, n=20, centre=0.2):
    """A cubic lattice with the vorticity of solid-body rotation v = Omega x r: zeta = 2 Omega everywhere."""
    g = (np.arange(n) + 0.5) * d
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return x, np.tile(2 * np.asarray(omega, float), (len(x), 1)), np.full(len(x), d ** 3)


def test_vr_fig4_table_on_solid_body_rotation():
    """Three 'methods' spinning at Omega, 1.5 Omega and 3 Omega: in the mid-plane slab (one layer of the lattice)
    and in all the fluid |zeta| = 2 Omega at every particle, so mean = p90 = p99, and the ratios to the first
    are 1.5 and 3 (9 for the enstrophy)."""
    from types import SimpleNamespace

    omega = np.array([0.0, 0.0, 1.5])
    scene = SimpleNamespace(domain=SimpleNamespace(min=(0, 0, 0), max=(0.4, 0.4, 0.4)), particle_radius=0.01)
    regions = pt.slab_regions([pt.parse_slab("z=mid"), pt.parse_slab("x=0.05:0.03")], scene)
    assert [r[0] for r in regions] == ["|z - 0.2| < 0.01", "|x - 0.05| < 0.03", "all fluid"]
    results = []
    for name, k in (("DFSPH", 1.0), ("VR", 1.5), ("MP", 3.0)):
        x, zeta, volume = _rotating_lattice(k * omega)
        x = x + [0, 0, 0.01]  # a layer on the mid-plane z = 0.2
        results.append((name, {"status": "done"}, {"1": (x, zeta, volume)}))
    rows = pt.vr_fig4(results, regions, [1.0])
    assert len(rows) == 9 and [r["region"] for r in rows[::3]] == [r[0] for r in regions]
    slab, band, fluid = rows[0:3], rows[3:6], rows[6:9]
    assert [r["particles"] for r in (slab[0], band[0], fluid[0])] == [400, 1200, 8000]  # one layer, three
    for group in (slab, band, fluid):
        for r, k in zip(group, (1.0, 1.5, 3.0)):
            assert r["mean |zeta| (1/s)"] == pytest.approx(2 * 1.5 * k)
            assert r["p90 |zeta|"] == pytest.approx(3 * k) and r["p99 |zeta|"] == pytest.approx(3 * k)
            assert r["mean / DFSPH"] == pytest.approx(k) and r["p99 / DFSPH"] == pytest.approx(k)
            assert r["enstrophy / DFSPH"] == pytest.approx(k ** 2)
            assert r["enstrophy"] == pytest.approx(0.5 * r["particles"] * 0.02 ** 3 * (3 * k) ** 2)
    with pytest.raises(ValueError):
        pt.parse_slab("w=1")


def test_vorticity_now_of_solid_body_rotation_without_a_model():
    """warpsph.diagnostics.vorticity_now on plain DFSPH (no model, no vorticity field): the curl of v = Omega x r
    is 2 Omega inside the bulk; the volumes are m / rho."""
    import warp as wp
    from conftest import make_sim, tank_scene

    from warpsph.diagnostics import vorticity_now

    wp.init()
    sim = make_sim(tank_scene(radius=0.02, domain=(0.4, 0.4, 0.4), block=(0.4, 0.4, 0.4), gravity=[0, 0, 0]))
    assert sim.vorticity_field is None
    omega = np.array([0.3, -1.2, 2.0])
    x0 = sim.fluid.x.numpy()[: sim.num_fluid]
    sim.fluid.v.assign(np.pad(np.cross(omega, x0 - 0.2), ((0, sim.capacity - sim.num_fluid), (0, 0))).astype(np.float32))
    x, zeta, volume = vorticity_now(sim)
    interior = np.all((x > sim.support_radius) & (x < 0.4 - sim.support_radius), axis=1)
    assert interior.sum() > 100 and len(x) == sim.num_fluid
    np.testing.assert_allclose(zeta[interior], np.tile(2 * omega, (interior.sum(), 1)), atol=0.02 * np.linalg.norm(2 * omega))
    np.testing.assert_allclose(volume, sim.particle_mass / sim.fluid.density.numpy()[: sim.num_fluid], rtol=1e-6)
    stats = pt.vorticity_stats(np.linalg.norm(zeta[interior], axis=1), volume[interior])
    # the SPH curl on the lattice reads 2 % high, the same at every interior particle
    assert stats["mean |zeta| (1/s)"] == pytest.approx(2 * np.linalg.norm(omega), rel=0.03)
    assert stats["p99 |zeta|"] == pytest.approx(stats["mean |zeta| (1/s)"], rel=1e-3)


def test_measuring_vorticity_leaves_the_run_unchanged():
    """vorticity_now between frames rebuilds lists and densities that the next step rebuilds anyway: a run
    measured half-way ends bit for bit where an unmeasured one does (CPU)."""
    from conftest import make_sim, tank_scene

    from warpsph.diagnostics import vorticity_now

    data = tank_scene(radius=0.025, domain=(0.6, 0.5, 0.3), block=(0.25, 0.4, 0.3))
    plain, measured = make_sim(data), make_sim(data)
    for k in range(20):
        plain.step()
        measured.step()
        if k % 5 == 4:
            vorticity_now(measured)
    assert np.array_equal(plain.fluid.x.numpy(), measured.fluid.x.numpy())
    assert np.array_equal(plain.fluid.v.numpy(), measured.fluid.v.numpy())


def test_vr_fig4_end_to_end_runs_then_reads_the_cells(tmp_path, monkeypatch):
    """The vr-fig4 kind on a tiny dam break (DFSPH and VR, two times): the JSON has a row per time, region and
    method, DFSPH's ratios are 1, and a second call reads the cell files instead of running."""
    import json

    from conftest import tank_scene

    scene = tmp_path / "dam.json"
    scene.write_text(json.dumps(tank_scene(radius=0.03, domain=(0.6, 0.4, 0.3), block=(0.2, 0.3, 0.3))))
    sweep = tmp_path / "fig4.json"
    sweep.write_text(json.dumps({"name": "fig4", "scene": str(scene), "scale": 1.0, "time": 0.08, "device": "cpu",
                                 "cells": [{"models": []}, {"models": [{"type": "vorticity_refinement", "alpha": 1.0}]}]}))
    args = ["vr-fig4", str(sweep), str(tmp_path / "out"), "--times", "0.04,0.08", "--json", str(tmp_path / "f4.json")]
    pt.main(args)
    out = json.loads((tmp_path / "f4.json").read_text())
    assert out["regions"] == ["|z - 0.15| < 0.03", "all fluid"] and out["times"] == [0.04, 0.08]
    assert len(out["rows"]) == 2 * 2 * 2 and out["device"] and out["warp"]
    assert [r["method"] for r in out["rows"][:2]] == ["DFSPH", "VR alpha = 1"]
    for r in out["rows"]:
        assert 0 < r["particles"] and r["mean |zeta| (1/s)"] > 0 and r["p99 |zeta|"] >= r["p90 |zeta|"]
        if r["method"] == "DFSPH":
            assert r["mean / DFSPH"] == pytest.approx(1) and r["enstrophy / DFSPH"] == pytest.approx(1)
    assert [r["time reached (s)"] >= 0.08 for r in out["runs"]] == [True, True]
    assert "| 0.08 | all fluid | VR alpha = 1 |" in (tmp_path / "f4.md").read_text()

    def no_run(*a, **k):
        raise AssertionError("ran again")
    monkeypatch.setattr(pt, "fig4_cell", no_run)
    pt.main(args[:4] + ["0.08"] + args[5:])  # a subset of the stored times
    again = json.loads((tmp_path / "f4.json").read_text())
    assert again["rows"] == [r for r in out["rows"] if r["t (s)"] == 0.08]
