"""An open domain ("walls": false): no wall samples, particles that leave the box are removed and counted."""

import csv
import json

import numpy as np
from pxr import Usd, UsdGeom

from conftest import SCENES_DIR, make_sim
from warpsph.cli import main
from warpsph.diagnostics import Diagnostics
from warpsph.simulation import count_particles
from warpsph.scene import scene_from_dict


def falling_block(walls=False, frames=12):
    """A 5 x 5 x 5 block (r = 20 mm) 0.3 m above the floor of a 0.4 x 0.6 x 0.4 m box."""
    return {"name": "fall", "particle_radius": 0.02,
            "domain": {"min": [0, 0, 0], "max": [0.4, 0.6, 0.4], "walls": walls},
            "fluid_blocks": [{"start": [0.1, 0.3, 0.1], "end": [0.3, 0.5, 0.3]}], "output": {"fps": 20, "frames": frames}}


def test_open_domain_has_no_walls_and_removes_what_falls_out():
    sim = make_sim(falling_block())
    assert sim.num_boundary == 0 and count_particles(sim.scene)[1] == 0
    assert sim.num_fluid == 125
    seen = []

    def on_frame(s, frame):
        ids = s.host(s.fluid.ids)
        assert len(np.unique(ids)) == len(ids) == s.num_fluid
        assert s.num_fluid + s.inflow.removed_outside == 125  # every particle is either here or counted
        row = Diagnostics().measure(s, frame)
        assert row["particles"] == s.num_fluid and row["removed"] == s.inflow.removed_outside
        seen.append((s.time, s.num_fluid))

    sim.run(frames=7, on_frame=on_frame)  # no InstabilityError: leaving an open domain is no failure
    # the bottom layer passes y = 0 after sqrt(2 * 0.32 / g) = 0.26 s, the top one after 0.33 s
    assert [n for t, n in seen if t < 0.25] == [125] * 5
    assert sim.num_fluid < 125 and sim.inflow.removed_outside > 0
    x = sim.host(sim.fluid.x)
    assert (x[:, 1] > -0.1).all()  # removed each step: none lingers far below the box
    stats = sim.statistics()
    assert stats["removed_outside"] == 125 - sim.num_fluid and stats["removed_in_sinks"] == 0


def test_open_domain_runs_on_with_no_fluid_left(tmp_path):
    """Once every particle has left, the run goes on (empty frames) to its end, and says what it removed."""
    scene = tmp_path / "fall.json"
    scene.write_text(json.dumps(falling_block(frames=10)))
    out = tmp_path / "fall.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out)]) == 0
    with open(tmp_path / "fall.stats.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 11
    assert rows[0]["particles"] == "125" and rows[0]["removed"] == "0"
    assert rows[-1]["particles"] == "0" and rows[-1]["removed"] == "125"
    assert all(int(r["particles"]) + int(r["removed"]) == 125 for r in rows)
    stage = Usd.Stage.Open(str(out))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    assert len(points.GetPointsAttr().Get(0)) == 125 and len(points.GetPointsAttr().Get(10) or []) == 0


def test_block_on_an_obstacle_in_an_open_domain_keeps_its_particles():
    data = {"name": "table", "particle_radius": 0.02,
            "domain": {"min": [0, 0, 0], "max": [1.0, 0.6, 1.0], "walls": False},
            # a 0.8 x 0.1 x 0.8 m slab, top at y = 0.15, far wider than the block on it
            "obstacles": [{"mesh": "meshes/unit_box.obj", "scale": [0.8, 0.1, 0.8], "translation": [0.5, 0.1, 0.5]}],
            "fluid_blocks": [{"start": [0.4, 0.16, 0.4], "end": [0.6, 0.32, 0.6]}], "output": {"fps": 20, "frames": 4}}
    sim = make_sim(data, base_dir=SCENES_DIR)
    n = sim.num_fluid
    assert n == 100 and sim.num_boundary > 0
    sim.run(frames=4)
    assert sim.num_fluid == n and sim.inflow.removed_outside == 0
    y = sim.host(sim.fluid.x)[:, 1]
    assert y.min() > 0.13 and np.isfinite(y).all()  # resting on the slab, not through it


def test_closed_domain_is_unchanged():
    scene = scene_from_dict(falling_block(walls=True))
    assert scene.domain.walls and not scene.domain.is_open
    assert not scene_from_dict({k: v for k, v in falling_block().items()}).domain.walls
    sim = make_sim(falling_block(walls=True, frames=10))
    assert sim.num_boundary > 0 and sim.inflow is None
    sim.run(frames=10)  # the block lands on the floor: nothing leaves, nothing is removed
    assert sim.num_fluid == 125 and sim.statistics()["removed_outside"] == 0
    assert sim.host(sim.fluid.x)[:, 1].min() > -0.02  # held by the floor (its samples stand 1.2 r below y = 0)


def test_open_periodic_axes_wrap_instead_of_removing():
    data = falling_block()
    data["domain"]["periodic"] = ["x", "z"]
    data["fluid_blocks"][0]["velocity"] = [3.0, 0, 0]  # crosses the periodic x faces within the first frames
    sim = make_sim(data)
    sim.run(frames=4)  # t = 0.2 s: above the open floor still
    assert sim.num_fluid == 125 and sim.inflow.removed_outside == 0
