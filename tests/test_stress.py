"""The stability stress matrix (``warpsph stress``, warpsph/validation/stress.py): a tiny matrix on cpu records
every cell, catches a blow-up with where and when it happened, and keeps going."""

import json

import pytest

from warpsph.cli import main

pytestmark = pytest.mark.slow  # a stress matrix of three runs


def test_stress_matrix_records_every_cell_and_the_blow_up(tmp_path):
    out = tmp_path / "stress"
    # plain DFSPH, VR alpha = 1 and a fixed step 30x the CFL step (blows up within a few steps at this scale)
    assert main(["stress", "--axes", "alpha", "fixed_dt", "--alpha", "1", "--fixed-dt", "30", "--scale", "0.05",
                 "--seconds", "0.5", "--device", "cpu", "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    cells = {c["name"]: c for c in report["cells"]}
    assert set(cells) == {"plain DFSPH", "alpha = 1", "fixed_dt = 30"}
    for c in cells.values():
        for key in ("blew_up", "steps", "time_reached", "max_density_error_pct", "density_iterations",
                    "divergence_iterations", "ke_end", "ke_end_rel_dfsph"):
            assert key in c, (c["name"], key)

    plain = cells["plain DFSPH"]
    assert not plain["blew_up"] and "instability" not in plain
    assert plain["time_reached"] >= 0.5 - 1e-6 and plain["steps"] > 50
    assert 0.0 < plain["max_density_error_pct"] < 5.0  # measured 2.1 % at 1 s
    assert 1.0 <= plain["density_iterations"] < 40  # signed bulk pressure, relaxed Jacobi: 23 (clamped solver: < 20)
    assert plain["ke_end"] > 0 and plain["ke_end_rel_dfsph"] == 1.0
    assert 0 < report["dt_cfl"] < report["dt_bounds"][1]  # the CFL rule, not dt_max, set the smallest step

    vr = cells["alpha = 1"]
    assert not vr["blew_up"] and 0.5 < vr["ke_end_rel_dfsph"] < 2.0

    bad = cells["fixed_dt = 30"]
    assert bad["fixed_dt_s"] == pytest.approx(30 * report["dt_cfl"])
    assert bad["blew_up"] and bad["ke_end_rel_dfsph"] is None
    i = bad["instability"]
    assert 1 <= i["step"] == bad["steps"] <= 20 and 0 < i["time"] < 0.5
    assert any(word in i["check"] for word in ("NaN", "left the domain", "density above", "max_iterations"))
    assert isinstance(i["particle_id"], int) and len(i["position"]) == 3

    table = out.with_suffix(".md").read_text()
    assert table.count("\n| ") == 1 + len(cells)  # header + a row per cell
    assert "**yes**: step" in table
    assert out.with_suffix(".png").stat().st_size > 1000
