"""warpsph/validation/bench_vs_splishsplash.py's comparison (the #24 result): the window is warpsph's last frame that
SPlisHSPlasH also reached, both timed over exactly that simulated time."""

import json

import pytest

from warpsph.validation import bench_vs_splishsplash


def test_compare_takes_the_last_common_frame_and_both_loop_walls(tmp_path):
    bench = bench_vs_splishsplash
    progress = tmp_path / "pss.jsonl"
    rows = [{"particles": 1000, "radius": 0.005, "process_s_to_first_step": 3.0}]
    rows += [{"t": 0.01 * k, "wall_s": 2.0 * k, "density_iterations": 3, "divergence_iterations": 1} for k in range(1, 10)]
    progress.write_text("\n".join(json.dumps(r) for r in rows))  # stopped at 0.09 s, no "done" line
    log = tmp_path / "warpsph.log"
    log.write_text("\n".join([
        "debug: frame 0: 0.020 s wall, 0 steps, t=0.0000s, 1000 fluid particles",
        "debug: frame 1: 0.300 s wall, 10 steps (30.0 ms per step), t=0.0400s, 1000 fluid particles",
        "debug: frame 2: 0.100 s wall, 11 steps (9.1 ms per step), t=0.0800s, 1000 fluid particles",
        "debug: frame 3: 0.100 s wall, 12 steps (8.3 ms per step), t=0.1200s, 1000 fluid particles",
        "done: frame 3, 33 steps, 0.120 s simulated, 0.5 s wall",
    ]))
    result = bench.compare(progress, log)
    assert result["frame"] == 2 and result["window_s"] == pytest.approx(0.08)
    assert result["warpsph"]["loop_wall_s"] == pytest.approx(0.42)  # frames 0-2
    assert result["splishsplash"]["loop_wall_s"] == pytest.approx(16.0)  # its first step at t >= 0.08
    assert result["splishsplash"]["steps"] == 8 and not result["splishsplash"]["finished"]
    assert result["ratio_per_simulated_second"] == pytest.approx(16.0 / 0.42)
    assert result["warpsph"]["done_line"].startswith("done: frame 3")


def test_compare_refuses_a_splishsplash_run_short_of_warpsphs_first_frame(tmp_path):
    bench = bench_vs_splishsplash
    progress = tmp_path / "pss.jsonl"
    progress.write_text(json.dumps({"particles": 1, "radius": 0.005, "process_s_to_first_step": 1.0}) + "\n"
                        + json.dumps({"t": 0.01, "wall_s": 0.0, "density_iterations": 2, "divergence_iterations": 1}))
    log = tmp_path / "warpsph.log"
    log.write_text("debug: frame 1: 0.300 s wall, 10 steps (30.0 ms per step), t=0.0400s, 1 fluid particles\n")
    with pytest.raises(SystemExit, match="did not reach"):
        bench.compare(progress, log)
