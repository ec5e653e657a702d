"""Initial particle sampling: fluid blocks on a lattice, boundary surfaces from meshes.

Runs once per scene on the host (numpy + trimesh); nothing here runs per step. trimesh is imported by
the functions that read or transform meshes (it takes longer to import than the rest of warpsph),
so scenes without meshes never load it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .errors import SceneError

# The domain box's boundary layer lies this many particle radii outside its faces. A single
# Akinci layer sampled at spacing 2r has V_b ~ 1.43 (2r)^3, so a lattice fluid half a spacing
# from it would start at 1.5 rho0; 2.2 r from the layer it has rest density (within 0.2 %),
# so a fluid block that touches a face starts at rest.
WALL_OFFSET = 1.2


def fill_block(start, end, spacing):
    """Lattice points of spacing ``spacing`` inside the box [start, end], the first one
    half a spacing from ``start`` (warpsph's fill: floor(size / spacing) points an axis; not
    SPlisHSPlasH's rule, which :func:`splishsplash_block` reproduces: its blocks are converted
    into the warpsph block with the same lattice)."""
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    counts = np.floor((end - start) / spacing + 1e-6).astype(int)
    if np.any(counts < 1):
        return np.zeros((0, 3), dtype=np.float32)
    axes = [start[a] + spacing * (0.5 + np.arange(counts[a])) for a in range(3)]
    grid = np.empty((*counts, 3), dtype=np.float32)  # filled in place: no float64 meshgrid of 1M points
    grid[..., 0] = axes[0][:, None, None]
    grid[..., 1] = axes[1][None, :, None]
    grid[..., 2] = axes[2][None, None, :]
    return grid.reshape(-1, 3)


def _c_round(x):
    """C's round(): halves away from zero (Python's round() rounds them to even)."""
    return math.copysign(math.floor(abs(x) + 0.5), x)


def _splishsplash_shifts(radius, mode):
    diam = 2.0 * radius
    eps = 1.0e-9
    xshift = yshift = diam
    if mode == 1:
        yshift = math.sqrt(3.0) * radius + eps
    elif mode == 2:
        xshift = math.sqrt(6.0) * diam / 3.0 + eps
        yshift = math.sqrt(3.0) * radius + eps
    return xshift, yshift


def splishsplash_block_counts(lo, hi, radius, mode=0):
    """SPlisHSPlasH's lattice steps (x, y, z) of a fluid block [lo, hi] (after its scale and
    translation), as SimulatorBase::createFluidBlocks computes them (SPlisHSPlasH 2.x):
    steps = round(size / shift) - 1 an axis, the shifts 2r (denseMode 0) or the staggered ones
    (1: y by sqrt(3) r; 2: x by sqrt(6) 2r / 3 too), the sizes of denseMode 1 and 2 reduced by one
    shift across the staggering. A unit cube at r = 0.025 gives 19^3 = 6859 particles; the
    points start 2r inside ``lo``, so the block's fluid ends about r short of each face."""
    diam = 2.0 * radius
    xshift, yshift = _splishsplash_shifts(radius, mode)
    diff = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
    if mode == 1:
        diff[0] -= diam
        diff[2] -= diam
    elif mode == 2:
        diff[0] -= xshift
        diff[2] -= diam
    return (int(_c_round(diff[0] / xshift)) - 1, int(_c_round(diff[1] / yshift)) - 1,
            int(_c_round(diff[2] / diam)) - 1)


def splishsplash_block(lo, hi, radius, mode=0, sim2d=False):
    """The particles SPlisHSPlasH puts in a fluid block [lo, hi] (createFluidBlocks): none when a
    step count is 1 or less (it warns the block is empty), one z layer at z = 0 in 2D."""
    if mode not in (0, 1, 2):
        return np.zeros((0, 3), np.float64)
    lo = np.asarray(lo, np.float64)
    diam = 2.0 * radius
    xshift, yshift = _splishsplash_shifts(radius, mode)
    sx, sy, sz = splishsplash_block_counts(lo, hi, radius, mode)
    if sx <= 1 or sy <= 1 or sz <= 1:
        return np.zeros((0, 3), np.float64)
    start = lo + diam
    if sim2d:
        sz = 1
        start[2] = 0.0
    j, k, l = (a.ravel() for a in np.meshgrid(np.arange(sx), np.arange(sy), np.arange(sz), indexing="ij"))
    x = np.stack([j * xshift, k * yshift, l * diam], axis=1) + start
    if mode == 1:
        even = (k % 2) == 0
        x[even, 2] += radius
        x[~even, 0] += radius
    elif mode == 2:
        x[:, 2] += radius
        if not sim2d:
            x[:, 2] += np.where(j % 2 == 1, diam / 2.0 * np.where(k % 2 == 1, -1.0, 1.0), 0.0)
        x[:, 0] += np.where(k % 2 == 0, xshift / 2.0, 0.0)
    return x


def sample_triangles(vertices, faces, spacing):
    """Samples a triangle mesh's surface with points about ``spacing`` apart.

    Each triangle gets a barycentric lattice of n = ceil(longest edge / spacing)
    divisions; points shared by neighbouring triangles are merged. Deterministic, so
    a scene samples the same boundary on every run and device.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    points = []
    tri = vertices[faces]  # (F, 3, 3)
    edges = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]], axis=1)
    divisions = np.maximum(np.ceil(np.linalg.norm(edges, axis=2).max(axis=1) / spacing), 1).astype(int)
    for n in np.unique(divisions):
        sel = tri[divisions == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        a = (i[keep] / n)[None, :, None]
        b = (j[keep] / n)[None, :, None]
        p = sel[:, None, 0] + a * (sel[:, None, 1] - sel[:, None, 0]) + b * (sel[:, None, 2] - sel[:, None, 0])
        points.append(p.reshape(-1, 3))
    points = np.concatenate(points) if points else np.zeros((0, 3))
    # merge duplicates on shared edges and vertices
    key = np.round(points / (1e-3 * spacing)).astype(np.int64)
    return points[_first_of_each_row(key)].astype(np.float32)


def _first_of_each_row(key):
    """Sorted indices of the first occurrence of each distinct row of an int64 (N, 3) array:
    ``np.sort(np.unique(key, axis=0, return_index=True)[1])``, with the rows packed into one int64
    where they fit (np.unique over rows sorts a structured view, several times slower)."""
    if not len(key):
        return np.zeros(0, dtype=np.int64)
    key = key - key.min(axis=0)  # the same rows are equal: a shift per column
    top = int(key.max()) + 1
    if top**3 >= 2**63:
        return np.sort(np.unique(key, axis=0, return_index=True)[1])
    packed = (key[:, 0] * top + key[:, 1]) * top + key[:, 2]
    return np.sort(np.unique(packed, return_index=True)[1])


def sample_box_walls(lo, hi, spacing, periodic=()):
    """Boundary particles on the faces of the domain box on a square lattice (spacing ``spacing``
    or just under, edges and corners shared), except the faces across periodic axes.

    A lattice per face, not the triangle sampler: a box face is two right triangles, whose
    barycentric lattice (divisions by the longest edge, the diagonal) sampled the walls twice as
    densely as needed, and a thin side wall up to 48x (1.19M wall samples where 0.31M do)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    counts = np.maximum(np.ceil((hi - lo) / spacing - 1e-6), 1).astype(int)
    axes = [np.linspace(lo[k], hi[k], counts[k] + 1) for k in range(3)]
    points = []
    for k in range(3):
        if "xyz"[k] in periodic:
            continue
        a, b = (k + 1) % 3, (k + 2) % 3
        ga, gb = np.meshgrid(axes[a], axes[b], indexing="ij")
        for plane in (lo[k], hi[k]):
            face = np.empty((ga.size, 3))
            face[:, k], face[:, a], face[:, b] = plane, ga.ravel(), gb.ravel()
            points.append(face)
    if not points:
        return np.zeros((0, 3), dtype=np.float32)
    points = np.concatenate(points)
    key = np.round((points - lo) / (1e-3 * spacing)).astype(np.int64)  # edges and corners once
    points = points[_first_of_each_row(key)]
    for axis in periodic:  # the samples on the far face are the images of those on the near one
        k = "xyz".index(axis)
        points = points[points[:, k] < hi[k] - 1e-6 * spacing]
    return points.astype(np.float32)


def fill_mesh(vertices, faces, spacing):
    """Lattice points of spacing ``spacing`` inside a closed triangle mesh, in the mesh's frame: the
    lattice of the mesh's bounding box, its first point half a spacing inside the lower corner (as
    :func:`fill_block`, and as SPlisHSPlasH's VolumeSampling), kept where a ray along +x from the
    point crosses the surface an odd number of times."""
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces, np.int64)]
    lo = v.min(axis=0)
    counts = np.floor((v.max(axis=0) - lo) / spacing + 1e-9).astype(int) + 1
    origin = lo + 0.5 * spacing
    # rows (y, z) of the lattice, nudged off edges and vertices that lie exactly on one
    nudge = spacing * 1e-7 * np.array([0.0, 0.7548776662, 0.5698402910])
    y0, z0 = tri[:, :, 1] - origin[1] - nudge[1], tri[:, :, 2] - origin[2] - nudge[2]
    j0 = np.maximum(np.ceil(y0.min(axis=1) / spacing), 0).astype(np.int64)
    j1 = np.minimum(np.floor(y0.max(axis=1) / spacing), counts[1] - 1).astype(np.int64)
    k0 = np.maximum(np.ceil(z0.min(axis=1) / spacing), 0).astype(np.int64)
    k1 = np.minimum(np.floor(z0.max(axis=1) / spacing), counts[2] - 1).astype(np.int64)
    nj, nk = np.maximum(j1 - j0 + 1, 0), np.maximum(k1 - k0 + 1, 0)
    per = nj * nk
    t = np.repeat(np.arange(len(tri)), per)  # one entry per (triangle, row under its shadow)
    local = np.arange(len(t)) - np.repeat(np.cumsum(per) - per, per)
    j, k = j0[t] + local // nk[t], k0[t] + local % nk[t]
    py, pz = j * spacing, k * spacing
    ay, az, by, bz, cy, cz = y0[t, 0], z0[t, 0], y0[t, 1], z0[t, 1], y0[t, 2], z0[t, 2]
    area = (by - ay) * (cz - az) - (cy - ay) * (bz - az)
    with np.errstate(divide="ignore", invalid="ignore"):
        wa = ((by - py) * (cz - pz) - (cy - py) * (bz - pz)) / area
        wb = ((cy - py) * (az - pz) - (ay - py) * (cz - pz)) / area
        wc = 1.0 - wa - wb
    hit = (area != 0.0) & (wa > 0) & (wb > 0) & (wc > 0)
    x = wa[hit] * tri[t[hit], 0, 0] + wb[hit] * tri[t[hit], 1, 0] + wc[hit] * tri[t[hit], 2, 0]
    first = np.ceil((x - origin[0]) / spacing).astype(np.int64)  # the first lattice point past the crossing
    ok = first < counts[0]
    flips = np.zeros((counts[1], counts[2], counts[0] + 1), np.uint8)
    np.add.at(flips, (j[hit][ok], k[hit][ok], np.maximum(first[ok], 0)), 1)
    inside = (np.cumsum(flips[:, :, :-1], axis=2, dtype=np.uint8) & 1).astype(bool)  # parity (wraps mod 256)
    jj, kk, ii = np.nonzero(inside)
    return (origin + spacing * np.stack([ii, jj, kk], axis=1)).astype(np.float64)


def load_mesh(path):
    """Reads a mesh with trimesh; any failure is a :class:`SceneError` naming the file."""
    import trimesh

    path = Path(path)
    try:
        mesh = trimesh.load(str(path), force="mesh", process=True)
    except OSError as exc:
        raise SceneError(path, "", f"cannot read mesh: {exc.strerror or exc}") from None
    except Exception as exc:  # trimesh raises many types (even ImportError) for damaged files
        raise SceneError(path, "", f"cannot read mesh: not a valid {path.suffix.lstrip('.').upper() or 'mesh'} file "
                                   f"(damaged, or another format; {type(exc).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SceneError(path, "", "the mesh has no triangles")
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise SceneError(path, "", "not a 3D triangle mesh (damaged file?)")
    if not np.isfinite(vertices).all() or faces.min() < 0 or faces.max() >= len(vertices):
        raise SceneError(path, "", "the mesh has vertices that are not finite numbers or faces that name missing vertices")
    # geometry only: an OBJ with texture coordinates or normals has its vertices split along the
    # seams, which left closed meshes (SPlisHSPlasH's UnitBox, sphere, torus) open to trimesh
    mesh = trimesh.Trimesh(vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces), process=True)
    return mesh


def rotation_matrix(axis, angle):
    axis = np.asarray(axis, dtype=np.float64)
    norm = np.linalg.norm(axis)
    if norm == 0.0 or angle == 0.0:
        return np.eye(3)
    import trimesh

    return trimesh.transformations.rotation_matrix(angle, axis / norm)[:3, :3]


def place_mesh(obstacle, path, spacing, domain_size):
    """An obstacle's mesh in world space at its placement (scale, then rotate, then translate).

    A mesh far larger than the domain (say, authored in millimetres) or smaller than one
    particle spacing is refused with a :class:`SceneError` naming the file."""
    mesh = load_mesh(path)
    v = np.asarray(mesh.vertices) * np.asarray(obstacle.scale)
    size = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    if size > 100.0 * domain_size:
        raise SceneError(path, "scale", f"the scaled mesh is {size:.3g} m across, over 100x the domain "
                                        f"({domain_size:.3g} m): wrong units or scale?")
    if size < spacing:
        raise SceneError(path, "scale", f"the scaled mesh is {size:.3g} m across, smaller than one particle "
                                        f"spacing ({spacing:.3g} m)")
    v = v @ rotation_matrix(obstacle.rotation_axis, obstacle.rotation_angle).T + np.asarray(obstacle.translation)
    import trimesh

    return trimesh.Trimesh(vertices=v, faces=np.asarray(mesh.faces), process=False)


def inset_vertices(mesh, distance):
    """Vertices of a closed mesh moved inwards so that every face plane moves ``distance`` along
    its inward normal: per vertex, the least-squares solution of n_f . d = -distance over the
    distinct normals of its faces (exact at a box corner, along the mean normal on smooth parts).

    Fluid particles rest about 2.2 r from a single Akinci layer (see WALL_OFFSET), so sampling a
    body's surface 1.2 r inside the mesh puts the fluid's edge (its centres minus r) on the mesh
    surface: a body displaces its own volume (a box of half the water's density floats half
    submerged); unset, it would displace a body 2.4 r thicker. Open meshes are left as they are."""
    vertices = np.asarray(mesh.vertices, np.float64)
    if not mesh.is_watertight or distance <= 0.0:
        return vertices
    out = vertices.copy()
    normals = np.asarray(mesh.face_normals)
    corner_vertex = np.asarray(mesh.faces).ravel()
    corner_face = np.repeat(np.arange(len(mesh.faces)), 3)
    order = np.argsort(corner_vertex, kind="stable")
    starts = np.searchsorted(corner_vertex[order], np.arange(len(vertices) + 1))
    for v in range(len(vertices)):
        n = normals[corner_face[order[starts[v]:starts[v + 1]]]]
        if not len(n):
            continue
        n = np.unique(np.round(n, 6), axis=0)
        delta, *_ = np.linalg.lstsq(n, np.full(len(n), -distance), rcond=1e-2)
        out[v] += delta
    return out


def morton_order(points, origin, cell_size):
    """Permutation that sorts points by the Z-order of their grid cell (memory coherence)."""
    cells = np.clip(np.floor((points - origin) / cell_size).astype(np.int64), 0, 1023)
    key = _SPREAD_BITS[cells[:, 0]] | (_SPREAD_BITS[cells[:, 1]] << 1) | (_SPREAD_BITS[cells[:, 2]] << 2)
    return np.argsort(key, kind="stable")


def _spread_bits(n_bits=10):
    """Table of the 2^n_bits cell coordinates with bit b moved to bit 3b (one axis of a Morton key)."""
    c = np.arange(1 << n_bits, dtype=np.int64)
    out = np.zeros_like(c)
    for bit in range(n_bits):
        out |= ((c >> bit) & 1) << (3 * bit)
    return out


_SPREAD_BITS = _spread_bits()
