"""Kernels of the preview surface (``--surface-method preview``, :func:`warpsph.surface.reconstruct_preview`).

The colour field c(x) = sum_j V_j W(|x - x_j|, H) (cubic spline of support H) takes each particle's
volume from its own neighbourhood, V_j = 1 / sum_k W(|x_j - x_k|, H) (m_j / rho_j, as splashsurf's:
Loeschner et al. 2023), so a sparse sheet or a droplet keeps a field that reaches the iso value where
the rest volume (2 r)^3 would let it drop out. It is sampled at the nodes of a sparse grid: the grid is cut into blocks of
B^3 cells, a block is active when some particle's support box overlaps it, and only the nodes of
active blocks are evaluated (through a :class:`warp.HashGrid` of the particles). The cells whose
8 corners straddle the iso value go to Warp's ``sparse_marching_cubes_from_cells``. Vertex normals
are -grad c / |grad c| and vertex velocities the Shepard-normalised SPH interpolation.
"""

import warp as wp

from .sph_kernel import cubic_kernel, cubic_kernel_gradient

wp.set_module_options({"enable_backward": False})


@wp.kernel
def bounds(x: wp.array(dtype=wp.vec3), lo: wp.array(dtype=float), hi: wp.array(dtype=float)):
    i = wp.tid()
    p = x[i]
    for k in range(3):
        wp.atomic_min(lo, k, p[k])
        wp.atomic_max(hi, k, p[k])


@wp.kernel
def mark_blocks(x: wp.array(dtype=wp.vec3), lower: wp.vec3, block: float, support: float, dims: wp.vec3i,
                flags: wp.array(dtype=wp.int32)):
    """flags[block] = 1 for every block that the support box of particle i overlaps."""
    i = wp.tid()
    p = x[i] - lower
    a = wp.vec3i(0)
    b = wp.vec3i(0)
    for k in range(3):
        a[k] = wp.clamp(int(wp.floor((p[k] - support) / block)), 0, dims[k] - 1)
        b[k] = wp.clamp(int(wp.floor((p[k] + support) / block)), 0, dims[k] - 1)
    for bi in range(a[0], b[0] + 1):
        for bj in range(a[1], b[1] + 1):
            for bk in range(a[2], b[2] + 1):
                flags[(bi * dims[1] + bj) * dims[2] + bk] = 1


@wp.kernel
def compact(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    if flags[i] != 0:
        out[offsets[i]] = i


@wp.func
def block_origin(block: int, dims: wp.vec3i, B: int):
    """The node subscript of the block's minimum corner."""
    bk = block % dims[2]
    bj = (block // dims[2]) % dims[1]
    bi = block // (dims[2] * dims[1])
    return wp.vec3i(bi * B, bj * B, bk * B)


@wp.kernel
def particle_volumes(grid: wp.uint64, x: wp.array(dtype=wp.vec3), support: float, volumes: wp.array(dtype=float)):
    """V_i = 1 / sum_j W(|x_i - x_j|, H) over the particles (i included): the volume the colour field gives i."""
    i = wp.tid()
    p = x[i]
    total = float(0.0)
    query = wp.hash_grid_query(grid, p, support)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        total += cubic_kernel(wp.length(p - x[j]), support)
    volumes[i] = 1.0 / total


@wp.kernel
def block_field(blocks: wp.array(dtype=wp.int32), dims: wp.vec3i, B: int, lower: wp.vec3, cell: float,
                grid: wp.uint64, x: wp.array(dtype=wp.vec3), support: float, volumes: wp.array(dtype=float),
                values: wp.array(dtype=float)):
    """The colour field at the (B + 1)^3 nodes of each active block."""
    tid = wp.tid()
    n = B + 1
    node = tid % (n * n * n)
    o = block_origin(blocks[tid // (n * n * n)], dims, B)
    s = wp.vec3i(o[0] + node // (n * n), o[1] + (node // n) % n, o[2] + node % n)
    p = lower + cell * wp.vec3(float(s[0]), float(s[1]), float(s[2]))
    c = float(0.0)
    query = wp.hash_grid_query(grid, p, support)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        c += volumes[j] * cubic_kernel(wp.length(p - x[j]), support)
    values[tid] = c


@wp.func
def node_value(values: wp.array(dtype=float), base: int, n: int, i: int, j: int, k: int):
    return values[base + (i * n + j) * n + k]


@wp.kernel
def mark_cells(values: wp.array(dtype=float), B: int, iso: float, flags: wp.array(dtype=wp.int32)):
    """flags[cell] = 1 where the cell's corners straddle ``iso``."""
    tid = wp.tid()
    n = B + 1
    base = (tid // (B * B * B)) * n * n * n
    c = tid % (B * B * B)
    i = c // (B * B)
    j = (c // B) % B
    k = c % B
    below = int(0)
    for q in range(8):
        if node_value(values, base, n, i + q // 4, j + (q // 2) % 2, k + q % 2) < iso:
            below += 1
    flags[tid] = wp.where(below > 0 and below < 8, 1, 0)


@wp.kernel
def gather_cells(flags: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.int32), values: wp.array(dtype=float),
                 blocks: wp.array(dtype=wp.int32), dims: wp.vec3i, B: int, corner: wp.array(dtype=wp.vec3i),
                 cells: wp.array(dtype=wp.vec3i), corner_values: wp.array2d(dtype=float)):
    """The straddling cells' subscripts and their corner values in ``corner`` order."""
    tid = wp.tid()
    if flags[tid] == 0:
        return
    out = offsets[tid]
    n = B + 1
    block = tid // (B * B * B)
    base = block * n * n * n
    c = tid % (B * B * B)
    i = c // (B * B)
    j = (c // B) % B
    k = c % B
    o = block_origin(blocks[block], dims, B)
    cells[out] = wp.vec3i(o[0] + i, o[1] + j, o[2] + k)
    for q in range(8):
        d = corner[q]
        corner_values[out, q] = node_value(values, base, n, i + d[0], j + d[1], k + d[2])


@wp.kernel
def vertex_attributes(vertices: wp.array(dtype=wp.vec3), grid: wp.uint64, x: wp.array(dtype=wp.vec3),
                      v: wp.array(dtype=wp.vec3), scalar: wp.array(dtype=float), support: float,
                      volumes: wp.array(dtype=float),
                      normals: wp.array(dtype=wp.vec3), velocities: wp.array(dtype=wp.vec3),
                      scalars: wp.array(dtype=float)):
    """Outward normals (-grad c) and the Shepard-interpolated velocity and scalar at each vertex
    (``v``/``scalar`` of length 0: not interpolated)."""
    tid = wp.tid()
    p = vertices[tid]
    grad = wp.vec3(0.0)
    weight = float(0.0)
    vel = wp.vec3(0.0)
    s = float(0.0)
    query = wp.hash_grid_query(grid, p, support)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        d = p - x[j]
        w = volumes[j] * cubic_kernel(wp.length(d), support)
        grad += volumes[j] * cubic_kernel_gradient(d, support)
        weight += w
        if v.shape[0] > 0:
            vel += w * v[j]
        if scalar.shape[0] > 0:
            s += w * scalar[j]
    length = wp.length(grad)
    normals[tid] = wp.where(length > 0.0, -grad / wp.max(length, 1.0e-30), wp.vec3(0.0))
    if weight > 0.0:
        if v.shape[0] > 0:
            velocities[tid] = vel / weight
        if scalar.shape[0] > 0:
            scalars[tid] = s / weight


@wp.kernel
def magnitudes(values: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    """out[i] = |values[i]| (the vorticity magnitude the mesh carries)."""
    i = wp.tid()
    out[i] = wp.length(values[i])


@wp.kernel
def signed_volume(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), total: wp.array(dtype=float)):
    """total[0] += the signed volume of the tetrahedron of face f and the origin (positive: faces counter-clockwise
    seen from outside)."""
    f = wp.tid()
    a = points[indices[3 * f]]
    b = points[indices[3 * f + 1]]
    c = points[indices[3 * f + 2]]
    wp.atomic_add(total, 0, wp.dot(a, wp.cross(b, c)) / 6.0)


@wp.kernel
def count_neighbours(indices: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32)):
    """counts[i] += 2 for every face at vertex i (its two other corners: each edge is counted from its two faces,
    so every neighbour weighs the same)."""
    f = wp.tid()
    for k in range(3):
        wp.atomic_add(counts, indices[3 * f + k], 2)


@wp.kernel
def sum_neighbours(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), sums: wp.array(dtype=wp.vec3)):
    """sums[i] += the other two corners of every face at vertex i."""
    f = wp.tid()
    for k in range(3):
        i = indices[3 * f + k]
        wp.atomic_add(sums, i, points[indices[3 * f + (k + 1) % 3]] + points[indices[3 * f + (k + 2) % 3]])


@wp.kernel
def relax(points: wp.array(dtype=wp.vec3), sums: wp.array(dtype=wp.vec3), counts: wp.array(dtype=wp.int32),
          factor: float):
    """One Laplacian step of Taubin's smoothing: x_i += factor (mean of the neighbours - x_i) (factor lambda > 0
    smooths, mu < -lambda undoes the shrinking)."""
    i = wp.tid()
    n = counts[i]
    if n > 0:
        points[i] = points[i] + factor * (sums[i] / float(n) - points[i])


@wp.kernel
def clamp_points(points: wp.array(dtype=wp.vec3), lo: wp.vec3, hi: wp.vec3):
    """points[i] clamped into the box [lo, hi] (the domain's walled faces: the mesh stops at the walls)."""
    i = wp.tid()
    points[i] = wp.min(wp.max(points[i], lo), hi)


@wp.kernel
def reverse_faces(indices: wp.array(dtype=wp.int32)):
    """Face f's winding reversed (its first and last corners swapped)."""
    f = wp.tid()
    a = indices[3 * f]
    indices[3 * f] = indices[3 * f + 2]
    indices[3 * f + 2] = a
