"""Scene files: every bad input is a SceneError naming the key or file, and nothing is written."""

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from warpsph import SceneError, load_scene
from warpsph.cli import main
from conftest import SCENES_DIR, make_sim, tank_scene


def write(tmp_path, data, name="scene.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "mutate, key, words",
    [
        (lambda d: d.update(partcle_radius=0.02), "partcle_radius", "did you mean 'particle_radius'"),
        (lambda d: d["domain"].update(maxx=[1, 1, 1]), "domain.maxx", "did you mean 'max'"),
        (lambda d: d.update(particle_radius="small"), "particle_radius", "expected a finite number"),
        (lambda d: d.update(particle_radius=-0.01), "particle_radius", "expected a number > 0"),
        (lambda d: d.update(particle_radius=0), "particle_radius", "expected a number > 0"),
        (lambda d: d["fluid_blocks"].append({"start": [0, 0, 0], "end": [0.2, 0.2, 9.0]}), "fluid_blocks[1]",
         "outside the domain"),
        (lambda d: d["fluid_blocks"][0].update(end=[0.1, 0.1]), "fluid_blocks[0].end", "list of 3 numbers"),
        (lambda d: d.update(fluid_blocks=[]), "fluid_blocks", "no fluid"),
        (lambda d: d.update(time={"cfl": 1.5}), "time.cfl", "(0, 1]"),
        (lambda d: d.update(time={"dt_min": 0.01, "dt_max": 0.001}), "time.dt_min", "dt_max"),
        (lambda d: d.update(solver={"warm_start": "yes"}), "solver.warm_start", "true or false"),
        (lambda d: d.update(solver={"shifting": -1}), "solver.shifting", ">= 0"),
        (lambda d: d.pop("domain"), "domain", "missing required key"),
        (lambda d: d.update(obstacles=[{"mesh": "nowhere.obj"}]), "obstacles[0].mesh", "not found"),
    ],
)
def test_bad_scene_names_the_key_and_writes_nothing(tmp_path, mutate, key, words, capsys):
    data = tank_scene()
    mutate(data)
    path = write(tmp_path, data)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message or "nowhere.obj" in message
    assert key in message and words in message
    out = tmp_path / "out.usdc"
    assert main(["run", str(path), "--device", "cpu", "--out", str(out), "--frames", "1"]) == 2
    assert not out.exists()
    assert key in capsys.readouterr().err


def test_invalid_json_and_missing_file(tmp_path):
    bad = tmp_path / "broken.json"
    bad.write_text("{ not json")
    with pytest.raises(SceneError, match="broken.json.*not valid JSON"):
        load_scene(bad)
    with pytest.raises(SceneError, match="missing.json.*cannot read"):
        load_scene(tmp_path / "missing.json")


def test_unreadable_mesh_names_the_file(tmp_path):
    (tmp_path / "junk.obj").write_text("this is not a mesh\n")
    data = tank_scene(obstacles=[{"mesh": "junk.obj"}])
    path = write(tmp_path, data)
    scene = load_scene(path)
    from warpsph.simulation import Simulation

    with pytest.raises(SceneError, match="junk.obj"):
        Simulation(scene, device="cpu")


def test_absurd_particle_counts_are_refused_before_sampling(tmp_path):
    from warpsph.simulation import Simulation

    scene = load_scene(write(tmp_path, tank_scene(radius=1e-6)))
    with pytest.raises(SceneError, match="particle_radius.*over the"):
        Simulation(scene, device="cpu")
    scene = load_scene(write(tmp_path, tank_scene(radius=0.05, fluid_blocks=[{"start": [0, 0, 0], "end": [0.05, 0.4, 0.4]}])))
    with pytest.raises(SceneError, match="fluid_blocks.*thinner"):
        Simulation(scene, device="cpu")


def test_default_scene_loads_and_scales(tmp_path):
    path = Path(SCENES_DIR) / "dam_break.json"
    full = load_scene(path)
    small = load_scene(path, scale=0.125)
    assert small.particle_radius == pytest.approx(2 * full.particle_radius)
    assert full.time_step_bounds == pytest.approx((1e-4, 5e-3))  # SPlisHSPlasH's bounds at r = 25 mm
    fine = load_scene(path, scale=8)
    assert fine.time_step_bounds[1] == pytest.approx(full.time_step_bounds[1] / 2)  # finer: dt ~ r
    # explicit bounds: kept when coarser, shrunk with r when finer
    explicit = load_scene(write(tmp_path, tank_scene(radius=0.02, time={"dt_max": 0.004})), scale=8)
    assert explicit.time.dt_max == pytest.approx(0.002)
    with pytest.raises(SceneError, match="--scale"):
        load_scene(path, scale=0)


@pytest.mark.parametrize("fmt", ["obj", "stl", "ply"])
def test_mesh_obstacle_is_sampled_once_on_its_surface(tmp_path, fmt):
    box = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    box.export(tmp_path / f"cube.{fmt}")
    data = tank_scene(radius=0.02, domain=(0.6, 0.6, 0.4), block=(0.2, 0.3, 0.4),
                      obstacles=[{"mesh": f"cube.{fmt}", "translation": [0.45, 0.05, 0.2]}])
    sim = make_sim(data, base_dir=tmp_path)
    body = sim.boundary.body
    samples = sim.boundary.x.numpy()[body == 1]
    assert len(samples) == 26  # a 3 x 3 x 3 shell
    local = samples - np.array([0.45, 0.05, 0.2])
    # every sample lies on the cube's surface moved 1.2 r inwards (a closed mesh, see bodies.BODY_INSET)
    assert np.allclose(np.abs(local).max(axis=1), 0.05 - 1.2 * 0.02, atol=1e-5)
    # the spacing is the particle spacing: nearest neighbours ~ 2r apart
    d = np.linalg.norm(local[:, None] - local[None], axis=2)
    np.fill_diagonal(d, np.inf)
    assert np.median(d.min(axis=1)) <= 2 * sim.scene.particle_radius + 1e-6
    before = sim.boundary.x.numpy().copy()
    for _ in range(3):
        sim.step()
    assert np.array_equal(sim.boundary.x.numpy(), before)
    assert sim.launches["compute_boundary_volume"] == 1
    # sampled once and never moved: no velocities, and their cell grid is never rebuilt
    assert sim.boundary.v.shape[0] == 0
    assert sim.launches["scatter_points_to_cells"] == 1 + sim.step_count + 1  # boundary once; fluid at init and each step


def test_obsolete_solver_keys_load_with_a_warning_naming_them(tmp_path):
    """Scene files of earlier versions (the confined mode's keys) still load; each obsolete key is named in a
    warning and ignored, never silently."""
    import json
    import warnings

    from warpsph.scene import load_scene

    path = tmp_path / "old.json"
    path.write_text(json.dumps({"particle_radius": 0.05, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
                                "fluid_blocks": [{"start": [0, 0, 0], "end": [0.5, 0.5, 0.5]}],
                                "solver": {"clamp_pressure": False, "transport_velocity": 40}}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path)
    text = " ".join(str(w.message) for w in caught)
    assert "solver.clamp_pressure" in text and "solver.transport_velocity" in text
    assert not hasattr(scene.solver, "clamp_pressure") and scene.solver.shifting == 2.0
