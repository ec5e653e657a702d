"""The fluid's surface mesh pushed out of the bodies (#42; :func:`warpsph.surface.clip_mesh`).

The colour field's iso surface reaches about a particle radius beyond the outermost particle
centres, so where the fluid touches a body the mesh pokes into it. Each vertex inside a closed
body's mesh (the generalised winding number, Warp's ``mesh_query_point_sign_winding_number``) is
moved to the nearest point of the body's surface.

An open mesh (a shell with boundary edges: the funnel, the hemisphere) has no inside; its boundary
samples lie on the mesh itself (``bodies.load_body``: inset 0), where a closed body's lie
``BODY_INSET`` r inside its surface and the walls' ``WALL_OFFSET`` r outside the faces. The fluid's
reachable space ends as far from the samples as at a closed body and a wall: :data:`SHELL` r (1.2 r)
on either side of the shell. A vertex closer than that to the shell is moved to :data:`SHELL` r from
its nearest point, on the side the fluid is on: its own side, unless its normal (which points out of
the fluid) points away from the shell while the vertex faces the shell's face, i.e. the fluid lies
between the vertex and the shell, on the other side (a surface that came through the shell); near a
rim the vertex is moved straight away from the rim.

A moving body is queried in body space: the vertices near it are taken there by the frame's pose and
back. Only vertices inside the body's bounding box (in body space; widened by the shell for an open
mesh) are queried; the bodies' meshes are small and built per frame on the CPU (also under a GPU
run: the preview's walls are clamped on the device, the bodies here on the host). Imported only
where a clip has bodies (it imports Warp).
"""

from __future__ import annotations

import numpy as np
import warp as wp
from .device import init_warp

wp.set_module_options({"enable_backward": False})

SHELL = 1.2  # r: the fluid's reachable space ends this far from an open body's mesh (= bodies.BODY_INSET, WALL_OFFSET)


@wp.kernel
def push_out(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), max_dist: float, moved: wp.array(dtype=wp.int32)):
    """points[i] inside the mesh -> the nearest point of its surface (moved[i] = 1)."""
    i = wp.tid()
    p = points[i]
    q = wp.mesh_query_point_sign_winding_number(mesh, p, max_dist)
    if q.result and q.sign < 0.0:
        points[i] = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        moved[i] = 1


@wp.kernel
def push_off_shell(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                   has_normals: int, thickness: float, moved: wp.array(dtype=wp.int32)):
    """points[i] closer than ``thickness`` to the open mesh -> ``thickness`` from its nearest point, on the fluid's
    side (moved[i] = 1); ``normals``: the fluid surface's vertex normals (out of the fluid), if ``has_normals``.
    Three passes: a vertex pushed off one face of a fold may come within ``thickness`` of the next."""
    i = wp.tid()
    p = points[i]
    for k in range(3):
        q = wp.mesh_query_point_no_sign(mesh, p, thickness)
        if q.result:
            s = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
            d = p - s
            dist = wp.length(d)
            if dist < thickness * 0.9999:
                n = wp.mesh_eval_face_normal(mesh, q.face)
                u = n
                if dist > 1.0e-4 * thickness:
                    u = d / dist
                elif has_normals != 0:
                    if wp.dot(normals[i], n) > 0.0:  # on the shell: the fluid is against its normal
                        u = -n
                if has_normals != 0 and k == 0:
                    # facing the face with its normal pointing away from it: the fluid lies between it and the shell
                    if wp.abs(wp.dot(u, n)) > 0.9 and wp.dot(normals[i], u) > 0.5:
                        u = -u
                p = s + u * thickness
                moved[i] = 1
    points[i] = p


@wp.kernel
def depth_in(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), closed: int, thickness: float, max_dist: float,
             depth: wp.array(dtype=float)):
    """depth[i]: how far points[i] lies inside a closed mesh (to its surface), or within ``thickness`` of an open
    one (thickness - distance); 0 elsewhere."""
    i = wp.tid()
    p = points[i]
    if closed != 0:
        q = wp.mesh_query_point_sign_winding_number(mesh, p, max_dist)
        if q.result and q.sign < 0.0:
            depth[i] = wp.length(p - wp.mesh_eval_position(mesh, q.face, q.u, q.v))
    else:
        q = wp.mesh_query_point_no_sign(mesh, p, thickness)
        if q.result:
            depth[i] = wp.max(thickness - wp.length(p - wp.mesh_eval_position(mesh, q.face, q.u, q.v)), 0.0)


_started = False


def _near_bodies(points, bodies, poses, radius):
    """(body, position, rotation, rows near it, their points in body space, the shell's half thickness or 0) for
    each body of ``bodies`` that has vertices near it: moving ones at their pose in ``poses`` (left out without
    one), open ones only with a ``radius``."""
    global _started
    if not _started:  # a splashsurf worker's Warp starts here: without the warning of a machine with no CUDA driver
        init_warp()
        _started = True
    for body in bodies:
        closed = getattr(body, "closed", True)
        if not closed and not radius:
            continue
        if body.moving:
            if not poses or body.name not in poses:
                continue
            position, rotation = (np.asarray(a, np.float64) for a in poses[body.name])
        else:
            position, rotation = np.zeros(3), np.eye(3)
        thickness = 0.0 if closed else SHELL * float(radius)
        local = (np.asarray(points, np.float64) - position) @ rotation  # rotation^T (p - position), row by row
        lo, hi = body.vertices.min(axis=0) - thickness, body.vertices.max(axis=0) + thickness
        near = np.flatnonzero(((local >= lo) & (local <= hi)).all(axis=1))
        if len(near):
            yield body, position, rotation, near, local[near], thickness


def _warp_mesh(body, device):
    return wp.Mesh(points=wp.array(body.vertices.astype(np.float32), dtype=wp.vec3, device=device),
                   indices=wp.array(body.faces.astype(np.int32).ravel(), dtype=wp.int32, device=device),
                   support_winding_number=bool(getattr(body, "closed", True)))


def push_out_of_bodies(points, bodies, poses=None, radius=None, normals=None):
    """Moves the rows of ``points`` (V, 3) float32, in place, that lie inside one of ``bodies``
    (:class:`~warpsph.surface.ClipBody`; a moving one at its pose in ``poses``, {name: (position,
    rotation)} with world = rotation @ body + position, and left out without one) onto its surface,
    and those within :data:`SHELL` ``radius`` of an open one to that distance on the fluid's side
    (``normals``: the mesh's vertex normals, which tell the side; open bodies are left out without a
    ``radius``); returns the boolean mask of the rows moved."""
    moved = np.zeros(len(points), bool)
    for body, position, rotation, near, local, thickness in _near_bodies(points, bodies, poses, radius):
        device = wp.get_device("cpu")
        with wp.ScopedDevice(device):
            mesh = _warp_mesh(body, device)
            query = wp.array(local.astype(np.float32), dtype=wp.vec3, device=device)
            flags = wp.zeros(len(near), dtype=wp.int32, device=device)
            if thickness > 0.0:
                has = normals is not None and len(normals) == len(points)
                local_normals = (np.asarray(normals, np.float64)[near] @ rotation if has else np.zeros((len(near), 3)))
                wp.launch(push_off_shell, len(near), device=device,
                          inputs=[mesh.id, query, wp.array(local_normals.astype(np.float32), dtype=wp.vec3, device=device),
                                  int(has), float(thickness), flags])
            else:
                span = float(np.linalg.norm(body.vertices.max(axis=0) - body.vertices.min(axis=0)))
                wp.launch(push_out, len(near), inputs=[mesh.id, query, span + 1e-6, flags], device=device)
            inside = flags.numpy().astype(bool)
        if inside.any():
            rows = near[inside]
            points[rows] = (query.numpy()[inside].astype(np.float64) @ rotation.T + position).astype(np.float32)
            moved[rows] = True
    return moved


def depths_in_bodies(points, bodies, poses=None, radius=None):
    """Per row of ``points`` (V, 3): the largest depth [m] inside one of ``bodies`` (a closed one: to its surface;
    an open one: into its shell, :data:`SHELL` ``radius`` minus the distance to its mesh; open ones need ``radius``),
    the moving ones at ``poses`` as :func:`push_out_of_bodies`; 0 outside them all."""
    depth = np.zeros(len(points))
    for body, _, _, near, local, thickness in _near_bodies(points, bodies, poses, radius):
        device = wp.get_device("cpu")
        with wp.ScopedDevice(device):
            mesh = _warp_mesh(body, device)
            query = wp.array(local.astype(np.float32), dtype=wp.vec3, device=device)
            out = wp.zeros(len(near), dtype=float, device=device)
            span = float(np.linalg.norm(body.vertices.max(axis=0) - body.vertices.min(axis=0)))
            wp.launch(depth_in, len(near), device=device,
                      inputs=[mesh.id, query, int(thickness == 0.0), float(thickness), span + 1e-6, out])
            depth[near] = np.maximum(depth[near], out.numpy())
    return depth
