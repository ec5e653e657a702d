"""Builds the obstacle meshes of the papers' scenes with trimesh primitives into scenes/meshes/.

    python tools/make_meshes.py

Meshes are in metres, centred as the scene files expect (their translations place them).
"""

from pathlib import Path

import numpy as np
import trimesh

OUT = Path(__file__).resolve().parent.parent / "scenes" / "meshes"


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    # a board across the tank, 0.1 m thick, with a 0.3 m vertical slot in its middle (VR paper Figs 1, 3)
    left = trimesh.creation.box(extents=[0.1, 2.0, 0.6])
    left.apply_translation([0, 1.0, -0.45])
    right = left.copy()
    right.apply_translation([0, 0, 0.9])
    trimesh.util.concatenate([left, right]).export(OUT / "board_with_gap.obj")
    # a pillar: cylinder of radius 0.1 m, 1.5 m tall, standing on y = 0 (VR paper Fig 11)
    pillar = trimesh.creation.cylinder(radius=0.1, height=1.5, sections=32)
    pillar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    pillar.apply_translation([0, 0.75, 0])
    pillar.export(OUT / "pillar.obj")
    # a hemisphere of radius 0.4 m resting on y = 0 (VR paper Fig 9)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    # the upper half (faces above the equator, flattened onto y = 0), open at the bottom: it sits on the floor
    keep = sphere.triangles_center[:, 1] > 0.0
    vertices = sphere.vertices.copy()
    vertices[:, 1] = np.maximum(vertices[:, 1], 0.0)
    hemisphere = trimesh.Trimesh(vertices, sphere.faces[keep], process=True)
    hemisphere.export(OUT / "hemisphere.obj")
    # a unit cube centred on the origin: falling blocks and floating boxes (scaled by the scene)
    trimesh.creation.box(extents=[1.0, 1.0, 1.0]).export(OUT / "unit_box.obj")
    # a stirring rod: cylinder of radius 0.05 m, 1.2 m long along y, centred (VR Fig 5, Rankine Fig 3)
    rod = trimesh.creation.cylinder(radius=0.05, height=1.2, sections=24)
    rod.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    rod.export(OUT / "rod.obj")
    # a propeller spinning about y: a hub (r 0.06 m) and three blades 0.35 m long, pitched 30 degrees
    parts = [trimesh.creation.cylinder(radius=0.06, height=0.12, sections=24,
                                       transform=trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))]
    for k in range(3):
        blade = trimesh.creation.box(extents=[0.35, 0.02, 0.12])
        blade.apply_translation([0.06 + 0.175, 0, 0])
        blade.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 6, [1, 0, 0]))
        blade.apply_transform(trimesh.transformations.rotation_matrix(2 * np.pi * k / 3, [0, 1, 0]))
        parts.append(blade)
    trimesh.util.concatenate(parts).export(OUT / "propeller.obj")
    # a boat: closed hull 0.8 x 0.25 x 0.3 m (x long), a pointed bow, flat deck; convex so mass comes from it
    deck = np.array([[-0.4, -0.15], [0.25, -0.15], [0.4, 0.0], [0.25, 0.15], [-0.4, 0.15]])
    keel = deck * [0.85, 0.65]
    top = np.stack([deck[:, 0], np.full(5, 0.25), deck[:, 1]], 1)
    bottom = np.stack([keel[:, 0], np.zeros(5), keel[:, 1]], 1)
    faces = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [5, 7, 6], [5, 8, 7], [5, 9, 8]]
    for k in range(5):
        a, b = k, (k + 1) % 5
        faces += [[a, 5 + a, b], [b, 5 + a, 5 + b]]
    boat = trimesh.Trimesh(np.concatenate([top, bottom]), np.array(faces), process=True)
    if boat.volume < 0:
        boat.invert()
    boat.apply_translation(-boat.center_mass)
    boat.export(OUT / "boat.obj")
    # a funnel: open cone from radius 0.4 m (top, y = 0.5) to 0.08 m (bottom, y = 0), walls only
    sections, rings = 32, 2
    angles = 2 * np.pi * np.arange(sections) / sections
    top = np.stack([0.4 * np.cos(angles), np.full(sections, 0.5), 0.4 * np.sin(angles)], 1)
    bottom = np.stack([0.08 * np.cos(angles), np.zeros(sections), 0.08 * np.sin(angles)], 1)
    faces = []
    for k in range(sections):
        a, b = k, (k + 1) % sections
        faces += [[a, b, sections + a], [b, sections + b, sections + a]]
    trimesh.Trimesh(np.concatenate([top, bottom]), np.array(faces), process=False).export(OUT / "funnel.obj")
    for path in sorted(OUT.glob("*.obj")):
        print(path.name, trimesh.load(path).bounds.tolist())


if __name__ == "__main__":
    main()
