"""Plots: energy of several runs, a vorticity slab, and previews during a run (real PNG files)."""

import json

import pytest

from warpsph.cli import main
from conftest import tank_scene

matplotlib = pytest.importorskip("matplotlib", reason="plots need matplotlib (the test extra installs it)")


def png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


@pytest.mark.slow
def test_plot_energy_slice_and_preview(tmp_path):
    runs = []
    for name, models in (("dfsph", []), ("vr", [{"type": "vorticity_refinement"}])):
        scene = tmp_path / f"{name}.json"
        scene.write_text(json.dumps(tank_scene(radius=0.04, domain=(0.8, 0.4, 0.2), block=(0.2, 0.3, 0.2),
                                               models=models, output={"fps": 20, "frames": 4})))
        out = tmp_path / f"{name}.usdc"
        assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--quiet", "--preview", "2"]) == 0
        runs.append(str(out))
    assert sorted(p.name for p in tmp_path.glob("vr.preview.*.png")) == [
        "vr.preview.00000.png", "vr.preview.00002.png", "vr.preview.00004.png"]
    energy = tmp_path / "energy.png"
    assert main(["plot", "energy", *runs, "--labels", "DFSPH", "VR", "--out", str(energy)]) == 0
    assert png_size(energy) == (1320, 840)
    slab = tmp_path / "slice.png"
    assert main(["plot", "slice", runs[1], "--frame", "3", "--axis", "z", "--out", str(slab)]) == 0
    assert png_size(slab)[0] > 500
    from warpsph.plots import slice_from_cache

    assert slice_from_cache(runs[1], 3, "z", slab)[1] > 10  # the slab holds particles
    assert main(["plot", "slice", runs[1], "--frame", "99", "--out", str(slab)]) == 2  # no such frame
    assert main(["plot", "energy", str(tmp_path / "missing.usdc"), "--out", str(energy)]) == 2


def test_validation_figures_regenerate_from_the_committed_json(tmp_path):
    """The result PNGs are not kept: each validation report's JSON alone draws its figures again."""
    pytest.importorskip("matplotlib", reason="the PNG needs matplotlib (the test extra installs it)")
    import json
    from pathlib import Path

    from warpsph.plots import draw_figures
    from warpsph.validation import dam_front, hydrostatic, lamb_oseen, taylor_green

    results = Path(__file__).resolve().parent / "data"
    for name, module, count in (("taylor_green_cpu_res16", taylor_green, 1), ("lamb_oseen_cpu_res24", lamb_oseen, 2),
                                ("hydrostatic_cpu_r0.02", hydrostatic, 1), ("dam_front_martin_moyce_cpu_res10", dam_front, 1)):
        report = json.loads((results / f"{name}.json").read_text())
        pngs = draw_figures(tmp_path / f"{name}.json", module.figures(report))
        assert len(pngs) == count
        for png in pngs:
            assert Path(png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
