"""``warpsph validate``: the rows of a tiny Taylor-Green run (8 across, 384 particles, about 2 s on one CPU
core) and the bad-input errors (exit 2, nothing written)."""

import json
import math

import pytest

from warpsph.cli import main

ROW_KEYS = {"case", "method", "resolution", "particles", "error_pct", "error_units", "wall_s", "steps", "setup_s"}


@pytest.mark.slow
def test_taylor_green_rows_and_metadata(tmp_path, capsys):
    out = tmp_path / "tg.json"
    assert main(["validate", "taylor-green", "--resolutions", "8", "--device", "cpu", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["case"] == "taylor-green" and data["complete"] and data["warp"] and data["device"]
    assert "commit" in data and data["solver"].startswith("default")
    assert "L1 error of |u|" in data["definitions"]["error_pct"]
    assert [(r["method"], r["resolution"]) for r in data["rows"]] == [("dfsph", 8)]
    row = data["rows"][0]
    assert ROW_KEYS <= set(row), set(row)
    assert row["case"] == "taylor-green" and row["particles"] == 8 * 8 * 6 and row["error_units"] == "%"
    assert math.isfinite(row["error_pct"]) and 0 < row["error_pct"] < 100
    assert row["steps"] > 0 and row["wall_s"] > 0 and abs(row["time"] - 0.3) < 1e-3
    assert row["pack_steps"] > 0 and math.isfinite(row["ke_error_pct"])
    assert not list(tmp_path.glob("*.tmp"))  # the temporary file was renamed
    table = capsys.readouterr().out
    assert "taylor-green" in table and "dfsph" in table and str(out) in table


@pytest.mark.parametrize("argv, option", [
    (["no-such-case", "--resolutions", "8"], "CASE"),
    (["taylor-green", "--resolutions", "3"], "--resolutions"),
    (["taylor-green", "--resolutions", "8", "8.5"], "--resolutions"),
    (["taylor-green", "--resolutions", "eight"], "--resolutions"),
    (["taylor-green", "--resolutions", "8", "--device", "tpu:7"], "--device"),
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, argv, option):
    out = tmp_path / "bad.json"
    device = [] if "--device" in argv else ["--device", "cpu"]
    assert main(["validate", *argv, *device, "--json", str(out)]) == 2
    assert option in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_unknown_method_and_json_directory(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:  # argparse names the option
        main(["validate", "taylor-green", "--resolutions", "8", "--methods", "sph2", "--json", str(tmp_path / "x.json")])
    assert exc.value.code == 2 and "--methods" in capsys.readouterr().err
    assert main(["validate", "taylor-green", "--resolutions", "8", "--device", "cpu", "--json", str(tmp_path)]) == 2
    assert "--json" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
