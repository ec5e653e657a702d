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
    for path in sorted(OUT.glob("*.obj")):
        print(path.name, trimesh.load(path).bounds.tolist())


if __name__ == "__main__":
    main()
