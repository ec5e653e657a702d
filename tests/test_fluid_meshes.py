"""Fluid filled into closed meshes (scene key fluid_meshes): the lattice of spacing 2r inside the mesh."""

import json

import numpy as np
import pytest
import trimesh

from warpsph import SceneError, load_scene
from warpsph.simulation import Simulation, count_particles, sample_scene

R = 0.25  # sphere radius [m]
r = 0.02  # particle radius [m]


def sphere_scene(tmp_path, shape=None, **changes):
    (shape or trimesh.creation.icosphere(subdivisions=4, radius=1.0)).export(tmp_path / "sphere.obj")
    data = {"particle_radius": r, "domain": {"min": [-0.5, 0.0, -0.5], "max": [0.5, 1.0, 0.5]},
            "fluid_meshes": [{"mesh": "sphere.obj", "scale": [R, R, R], "translation": [0.0, 0.5, 0.0],
                              "rotation_axis": [1.0, 1.0, 0.0], "rotation_angle": 0.3, "velocity": [0.5, 0.0, 0.0]}],
            "output": {"frames": 1}}
    data["fluid_meshes"][0].update(changes)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(data))
    return path


def test_sphere_is_filled_at_the_particle_spacing(tmp_path):
    scene = load_scene(sphere_scene(tmp_path))
    x, v, *_ = sample_scene(scene)
    expected = 4.0 / 3.0 * np.pi * R**3 / (2 * r) ** 3
    assert len(x) == count_particles(scene)[0]
    assert len(x) == pytest.approx(expected, rel=0.03)
    assert np.linalg.norm(x - [0.0, 0.5, 0.0], axis=1).max() < R
    assert np.allclose(v, [0.5, 0.0, 0.0])
    # a lattice of spacing 2r: the nearest neighbour of every particle is 2r away
    d = np.linalg.norm(x[:, None] - x[None, :], axis=2) + np.eye(len(x))
    assert np.allclose(d.min(axis=1), 2 * r, rtol=1e-4)
    sim = Simulation(scene, device="cpu").run(frames=1)
    assert sim.num_fluid == len(x)


def test_open_mesh_is_refused_naming_the_key(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    sphere.update_faces(np.arange(len(sphere.faces)) != 0)
    scene = load_scene(sphere_scene(tmp_path, shape=sphere))
    with pytest.raises(SceneError, match=r"fluid_meshes\[0\].mesh.*not closed"):
        count_particles(scene)


def test_fluid_outside_the_domain_is_refused(tmp_path):
    scene = load_scene(sphere_scene(tmp_path, translation=[0.0, 0.1, 0.0]))
    with pytest.raises(SceneError, match=r"fluid_meshes\[0\].*outside the domain"):
        sample_scene(scene)


def test_missing_mesh_is_refused_on_load(tmp_path):
    path = sphere_scene(tmp_path, mesh="nothing.obj")
    with pytest.raises(SceneError, match=r"fluid_meshes\[0\].mesh.*not found"):
        load_scene(path)
