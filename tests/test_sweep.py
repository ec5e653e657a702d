"""``warpsph sweep`` (#20): a 4-cell Taylor-Green sweep (6 and 8 across, dfsph and vr, no warm-up: a few
seconds a cell on one CPU core) through the local executor and a local Ray instance (identical tables but for
the timings), resumed without rerunning finished cells, finished after a SIGKILL of its driver, a blow-up
recorded as a result, and bad sweep files naming the key (exit 2, nothing written)."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from warpsph.cli import main
from warpsph.errors import SceneError
from warpsph.sweep import comparable, load_sweep, run_sweep

SWEEP = {"base": "taylor-green", "axes": {"method": ["dfsph", "vr"], "resolution": [6, 8]}, "warm_up": False,
         "measures": ["particles", "error_pct", "steps", "ke_ratio", "wall_s"]}
EXPECTED = [("dfsph", 6, 216), ("dfsph", 8, 384), ("vr", 6, 216), ("vr", 8, 384)]


def _mtimes(out):
    return {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "local"
    lines = []
    table = run_sweep(SWEEP, out, executor="local", workers=2, log=lines.append)
    return out, table, lines


def test_local_sweep_table(local):
    out, table, lines = local
    assert table["complete"] and table["counts"] == {"done": 4, "unstable": 0, "failed": 0, "missing": 0}
    assert [(r["method"], r["resolution"], r["particles"]) for r in table["rows"]] == EXPECTED
    for r in table["rows"]:
        assert r["status"] == "done" and 0 < r["error_pct"] < 100 and r["steps"] > 0 and r["wall_s"] > 0
        assert 0 < r["ke_ratio"] < 1 and r["device"] == "cpu"
    assert json.loads((out / "table.json").read_text())["rows"] == table["rows"]
    md = (out / "table.md").read_text()
    assert "| method | resolution | particles | error_pct | steps | ke_ratio | wall_s | status |" in md
    assert md.count("| done |") == 4
    assert len(list((out / "cells").glob("*.json"))) == 4 and not list(out.rglob("*.tmp"))
    assert any("4/4 done" in line and "ETA" in line for line in lines), lines


def test_rerun_skips_finished_cells(local, tmp_path):
    out, table, _ = local
    before = _mtimes(out)
    lines = []
    again = run_sweep(SWEEP, out, workers=2, log=lines.append)
    assert _mtimes(out) == before and "[0 to run" in lines[0]
    assert again["rows"] == table["rows"]
    # a failed cell and a missing one are run again, the others are not
    cells = sorted((out / "cells").glob("*.json"))
    record = json.loads(cells[0].read_text())
    record.update(status="failed", error="RuntimeError: lost")
    cells[0].write_text(json.dumps(record))
    cells[1].unlink()
    before = _mtimes(out)
    lines = []
    run_sweep(SWEEP, out, workers=2, log=lines.append)
    after = _mtimes(out)
    assert "[2 to run" in lines[0]
    assert {name for name in after if after[name] != before.get(name)} == {cells[0].name, cells[1].name}


def test_ray_gives_the_same_table(local, tmp_path):
    ray = pytest.importorskip("ray")
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"ray cannot start here: {exc}")
    try:
        table = run_sweep(SWEEP, tmp_path / "ray", executor="ray", max_retries=1, log=lambda line: None)
    finally:
        ray.shutdown()
    assert table["complete"]
    assert comparable(table) == comparable(local[1])


def test_killed_driver_rerun_finishes_the_missing_cells(tmp_path):
    sweep = tmp_path / "sweep.json"
    sweep.write_text(json.dumps(SWEEP))
    out = tmp_path / "out"
    driver = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "sweep", str(sweep), "--out", str(out),
                               "--workers", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    try:
        deadline = time.time() + 60
        while time.time() < deadline and not list((out / "cells").glob("*.json")):
            time.sleep(0.05)
        os.killpg(driver.pid, signal.SIGKILL)  # the driver and the cell in flight
    finally:
        driver.wait()
    first = _mtimes(out)
    assert 1 <= len(first) < 4 and not (out / "table.json").exists()
    lines = []
    table = run_sweep(sweep, out, workers=2, log=lines.append)
    assert f"[{4 - len(first)} to run" in lines[0]
    after = _mtimes(out)
    assert len(after) == 4 and all(after[name] == first[name] for name in first)
    assert table["complete"] and [(r["method"], r["resolution"], r["particles"]) for r in table["rows"]] == EXPECTED


def test_blow_up_is_a_result(tmp_path):
    # dam-front 4 across with a fixed 50 ms step and two solver iterations leaves the domain at step 2
    sweep = {"base": "dam-front", "axes": {"resolution": [4]}, "warm_up": False,
             "fixed": {"time.fixed_dt": 0.05, "solver.max_iterations": 2}}
    table = run_sweep(sweep, tmp_path, log=lambda line: None)
    row = table["rows"][0]
    assert table["complete"] and table["counts"]["unstable"] == 1
    assert row["status"] == "unstable" and "unstable at step" in row["unstable"] and row["error_pct"] is None
    assert "unstable: unstable at step" in (tmp_path / "table.md").read_text()
    lines = []
    run_sweep(sweep, tmp_path, log=lines.append)  # a result: not run again
    assert "[0 to run" in lines[0]


@pytest.mark.parametrize("change, key", [
    ({"base": "no-such-case"}, "base"),
    ({"base": "scenes/dam_break.json"}, "base"),
    ({"axes": {}}, "axes"),
    ({"axes": {"method": ["sph2"], "resolution": [8]}}, "axes.method[0]"),
    ({"axes": {"method": ["dfsph"], "resolution": [3]}}, "axes.resolution[0]"),
    ({"axes": {"method": ["dfsph"], "resolution": 8}}, "axes.resolution"),
    ({"axes": {"resolution": [8], "cfl": [1.5]}}, "axes.cfl[0]"),
    ({"axes": {"resolution": [8], "solver.bogus": [1]}}, "axes.solver.bogus[0]"),
    ({"axes": {"resolution": [8], "gravity": [0]}}, "axes.gravity"),
    ({"axes": {"method": ["dfsph"]}}, "axes"),
    ({"measures": ["error_pct", "speed"]}, "measures[1]"),
    ({"workers": 2}, "workers"),
])
def test_bad_sweep_file_names_the_key(tmp_path, capsys, change, key):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**SWEEP, **change}))
    with pytest.raises(SceneError) as exc:
        load_sweep(path)
    assert exc.value.key == key, str(exc.value)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out)]) == 2
    assert f"{path}: {key}:" in capsys.readouterr().err
    assert not out.exists()
