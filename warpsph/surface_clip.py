"""The fluid's surface mesh pushed out of the closed bodies (#42; :func:`warpsph.surface.clip_mesh`).

The colour field's iso surface reaches about a particle radius beyond the outermost particle
centres, so where the fluid touches a body the mesh pokes into it. Each vertex inside a closed
body's mesh (the generalised winding number, Warp's ``mesh_query_point_sign_winding_number``) is
moved to the nearest point of the body's surface. A moving body is queried in body space: the
vertices near it are taken there by the frame's pose and back. Only vertices inside the body's
bounding box (in body space) are queried; the bodies' meshes are small and built per frame on the
CPU. Imported only where a clip has bodies (it imports Warp).
"""

from __future__ import annotations

import numpy as np
import warp as wp
from .device import init_warp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def push_out(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), max_dist: float, moved: wp.array(dtype=wp.int32)):
    """points[i] inside the mesh -> the nearest point of its surface (moved[i] = 1)."""
    i = wp.tid()
    p = points[i]
    q = wp.mesh_query_point_sign_winding_number(mesh, p, max_dist)
    if q.result and q.sign < 0.0:
        points[i] = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        moved[i] = 1


_started = False


def push_out_of_bodies(points, bodies, poses=None):
    """Moves the rows of ``points`` (V, 3) float32, in place, that lie inside one of ``bodies``
    (:class:`~warpsph.surface.ClipBody`; a moving one at its pose in ``poses``, {name: (position,
    rotation)} with world = rotation @ body + position, and left out without one) onto its surface;
    returns the boolean mask of the rows moved."""
    moved = np.zeros(len(points), bool)
    global _started
    if not _started:  # a splashsurf worker's Warp starts here: without the warning of a machine with no CUDA driver
        init_warp()
        _started = True
    device = wp.get_device("cpu")
    for body in bodies:
        if body.moving:
            if not poses or body.name not in poses:
                continue
            position, rotation = (np.asarray(a, np.float64) for a in poses[body.name])
        else:
            position, rotation = np.zeros(3), np.eye(3)
        local = (points.astype(np.float64) - position) @ rotation  # rotation^T (p - position), row by row
        lo, hi = body.vertices.min(axis=0), body.vertices.max(axis=0)
        near = np.flatnonzero(((local >= lo) & (local <= hi)).all(axis=1))
        if len(near) == 0:
            continue
        with wp.ScopedDevice(device):
            mesh = wp.Mesh(points=wp.array(body.vertices.astype(np.float32), dtype=wp.vec3, device=device),
                           indices=wp.array(body.faces.astype(np.int32).ravel(), dtype=wp.int32, device=device),
                           support_winding_number=True)
            query = wp.array(local[near].astype(np.float32), dtype=wp.vec3, device=device)
            flags = wp.zeros(len(near), dtype=wp.int32, device=device)
            wp.launch(push_out, len(near), inputs=[mesh.id, query, float(np.linalg.norm(hi - lo)) + 1e-6, flags],
                      device=device)
            inside = flags.numpy().astype(bool)
        if inside.any():
            rows = near[inside]
            points[rows] = (query.numpy()[inside].astype(np.float64) @ rotation.T + position).astype(np.float32)
            moved[rows] = True
    return moved
