"""The studies through the public command line, at tiny scale on the CPU: ``warpsph bench steps|job``,
``warpsph stress``, ``warpsph pareto`` and ``warpsph plot results`` write their result files; a bad option
exits 2 naming it and writes nothing."""

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from warpsph.cli import main
from warpsph.validation.pareto import ERROR_KEY, TIME_KEY

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"  # result files as the studies write them
PNG = b"\x89PNG\r\n\x1a\n"
HAS_MATPLOTLIB = importlib.util.find_spec("matplotlib") is not None


@pytest.fixture(scope="module")
def steps(tmp_path_factory):
    """bench steps at ~1K and ~2K fluid particles, 2 warm-up and 2 + 2 timed steps."""
    out = tmp_path_factory.mktemp("bench") / "steps.json"
    assert main(["bench", "steps", "--device", "cpu", "--particles", "1000", "2000", "--warmup", "2", "--steps", "2",
                 "--out", str(out)]) == 0
    return out


def test_bench_steps_writes_ms_per_step_and_the_table(steps):
    runs = json.loads(steps.read_text())
    assert [r["benchmark"] for r in runs] == ["scene", "scene"]
    assert 500 < runs[0]["fluid_particles"] < runs[1]["fluid_particles"] < 4000
    for r in runs:
        assert r["device"] == "cpu" and r["model"] == "none" and "commit" in r and r["warp"]
        assert r["ms_per_step"] > 0 and r["steps_total"] == 6
        stages = r["ms_per_step_by_stage_synchronised"]
        assert stages and all(ms >= 0 for ms in stages.values()) and sum(stages.values()) > 0
        assert r["k_passes"] >= 6 and r["bytes_per_fluid_particle_arrays"] > 0
    table = steps.with_suffix(".md").read_text()
    assert table.count("\n| ") == 3 and "ms/step" in table  # header + a row per size


@pytest.mark.slow
def test_bench_steps_model_none_drops_the_scenes_own_models(tmp_path):
    """The papers' scenes run VR: --model none benchmarks plain DFSPH, no option keeps the scene's models."""
    scene = ROOT / "scenes" / "dam_break_pillars.json"
    assert json.loads(scene.read_text())["models"], "the scene runs a model of its own"
    models = {}
    for option in (["--model", "none"], []):
        out = tmp_path / f"steps{len(option)}.json"
        assert main(["bench", "steps", "--scene", str(scene), "--device", "cpu", "--particles", "800", "--warmup", "1",
                     "--steps", "1", "--out", str(out)] + option) == 0
        run = json.loads(out.read_text())
        models[tuple(option)] = (run[0] if isinstance(run, list) else run)["model"]
    assert models == {("--model", "none"): "none", (): "vorticity_refinement"}


@pytest.mark.skipif(importlib.util.find_spec("pxr") is None, reason="the job writes USD (usd-core)")
def test_bench_job_times_the_start_up_the_solver_and_the_job(tmp_path):
    out, keep = tmp_path / "job.json", tmp_path / "caches"
    assert main(["bench", "job", "--device", "cpu", "--particles", "1000", "--frames", "1", "--modes", "sync",
                 "--keep", str(keep), "--out", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["device"] == "cpu" and r["frames"] == 1 and "commit" in r and r["warp"]
    assert r["startup"]["time_to_first_step_s"] > 0 and r["startup"]["particles"] > 500
    assert "first step (kernel loading)" in r["startup"]["stages_s"]
    assert r["solver_only"]["ms_per_step"] > 0 and r["solver_only"]["steps"] > 0
    [job] = r["jobs"]  # frames written: 0 and 1
    assert job["mode"] == "sync" and job["frames"] == 2 and job["loop_over_solver"] > 0 and job["disk_bytes"] > 0
    assert (keep / "job_sync.usdc").is_file()


@pytest.mark.slow
def test_stress_matrix_of_two_cells(tmp_path):
    out = tmp_path / "stress"
    assert main(["stress", "--axes", "alpha", "--alpha", "1", "--scale", "0.02", "--seconds", "0.05",
                 "--device", "cpu", "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert [c["name"] for c in report["cells"]] == ["plain DFSPH", "alpha = 1"]
    assert report["device"] == "cpu" and report["axes"] == {"alpha": [1.0]} and report["dt_cfl"] > 0
    for c in report["cells"]:
        assert not c["blew_up"] and c["steps"] > 0 and c["time_reached"] >= 0.05 - 1e-6
        assert c["ke_end_rel_dfsph"] > 0 and c["max_density_error_pct"] >= 0
    assert out.with_suffix(".md").read_text().count("\n| ") == 3
    if HAS_MATPLOTLIB:
        assert out.with_suffix(".png").read_bytes()[:8] == PNG


@pytest.mark.slow
def test_pareto_at_its_smallest_and_plot_only(tmp_path):
    out = tmp_path / "pareto.json"
    assert main(["pareto", "--device", "cpu", "--methods", "dfsph", "--resolutions", "8", "--tolerances", "0.05",
                 "--T", "0.05", "--frames", "2", "--no-plot", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    [point] = report["points"]
    assert report["benchmark"] == "pareto" and report["setup"]["T"] == 0.05
    assert point["method"] == "dfsph" and point["resolution"] == 8 and point["pareto"] is True
    assert point[TIME_KEY] > 0 and 0 < point[ERROR_KEY] < 100
    assert out.with_suffix(".md").is_file() and not out.with_suffix(".png").exists()
    if HAS_MATPLOTLIB:
        assert main(["pareto", "--plot-only", str(out)]) == 0
        assert out.with_suffix(".png").read_bytes()[:8] == PNG


@pytest.mark.slow
def test_plot_results_regenerates_the_pngs(steps, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the PNGs need matplotlib (the test extra installs it)")
    files = [steps, DATA / "stress_cpu_falling_blocks.json", DATA / "pareto_h100_res400.json",
             DATA / "taylor_green_cpu_res16.json", DATA / "bench_job_h100.json"]
    figs = tmp_path / "figs"
    assert main(["plot", "results", *map(str, files), "--out-dir", str(figs)]) == 0
    for name in ("steps", "stress_cpu_falling_blocks", "pareto_h100_res400", "taylor_green_cpu_res16"):
        assert (figs / f"{name}.png").read_bytes()[:8] == PNG, name
    assert "bench_job_h100.json: no figure for this kind of file" in capsys.readouterr().out
    beside = tmp_path / "scaling.json"  # without --out-dir: beside the JSON
    shutil.copy(steps, beside)
    assert main(["plot", "results", str(beside)]) == 0
    assert beside.with_suffix(".png").read_bytes()[:8] == PNG


@pytest.mark.parametrize("argv, option", [
    (["bench", "steps", "--device", "cpu", "--particles", "0"], "--particles"),
    (["bench", "steps", "--device", "cpu", "--steps", "0"], "--steps"),
    (["bench", "steps", "--device", "tpu:7"], "--device"),
    (["bench", "steps", "--device", "cpu", "--scene", "no_such_scene.json"], "--scene"),
    (["bench", "job", "--device", "tpu:7"], "--device"),
    (["bench", "job", "--device", "cpu", "--frames", "0"], "--frames"),
    (["stress", "--device", "cpu", "--seconds", "0"], "--seconds"),
    (["stress", "--device", "cpu", "--fixed-dt", "-2"], "--fixed-dt"),
    (["pareto", "--device", "cpu", "--resolutions", "2"], "--resolutions"),
    (["pareto", "--device", "cpu", "--tolerances", "0"], "--tolerances"),
    (["pareto", "--device", "cpu"], "--out"),
    (["plot", "results", "no_such_result.json"], "no_such_result.json"),
])
def test_bad_options_exit_2_naming_the_option(tmp_path, capsys, argv, option):
    out = ["--out", str(tmp_path / "out.json")] if "--out" != option and argv[0] in ("bench", "stress", "pareto") else []
    assert main([*argv, *out]) == 2
    assert option in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_an_unknown_choice_is_refused_by_name(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["stress", "--axes", "gamma"])
    assert exc.value.code == 2 and "--axes" in capsys.readouterr().err
