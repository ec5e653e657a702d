"""Volume maps for dynamic bodies (Bender et al. 2019), as SPlisHSPlasH's boundaryHandlingMethod 2 holds the fluid.

Set up once per mapped body (:func:`tabulate_volume`): the map's volume Psi on a grid in the body's frame. Each step
(:meth:`VolumeMaps.place`) every fluid particle gets its boundary point of each mapped body (kernels/volume_map.py),
which the density, pressure, viscosity and coupling kernels read as one more boundary sample. Scenes without a mapped
body create none of this."""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from warpsph.kernels import volume_map as vk

MAX_NODES_PER_AXIS = 160  # the grid's spacing is r/2, coarser only where a body is longer than this many spacings
SUPERSAMPLE = 4  # sub-points per axis of a grid cell when the ball |y| < H is rasterised


def _normalised_cubic(q):
    """W(q H) / W(0) of the cubic spline (q = s / H)."""
    q = np.asarray(q, np.float64)
    return np.where(q <= 0.5, 6.0 * q**3 - 6.0 * q**2 + 1.0, np.where(q <= 1.0, 2.0 * (1.0 - q) ** 3, 0.0))


def ball_weights(support_radius, spacing):
    """The ball |y| < H on the grid: each node's share of its cell inside the ball times the cell's volume
    (SUPERSAMPLE^3 sub-points a cell), a cube of 2R + 1 nodes a side."""
    reach = int(math.ceil(support_radius / spacing))
    offsets = np.arange(-reach, reach + 1) * spacing
    sub = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    sub = sub * spacing
    # per axis: node offsets + sub-point offsets
    a = (offsets[:, None] + sub[None, :]).ravel()
    r2 = a[:, None, None] ** 2 + a[None, :, None] ** 2 + a[None, None, :] ** 2
    inside = (r2 < support_radius * support_radius).astype(np.float64)
    n = 2 * reach + 1
    inside = inside.reshape(n, SUPERSAMPLE, n, SUPERSAMPLE, n, SUPERSAMPLE).mean(axis=(1, 3, 5))
    return inside * spacing**3


def _convolved(d, support_radius, spacing):
    """Psi on a grid from the signed distances ``d`` (less the thickness) at its nodes ((z, y, x) order): the
    integral over |y| < H of chi(d), chi = 1 where d <= 0, W(d)/W(0) for 0 < d < H (FFT convolution)."""
    chi = np.where(d <= 0.0, 1.0, _normalised_cubic(d / support_radius))
    ball = ball_weights(support_radius, spacing)
    shape = [chi.shape[k] + ball.shape[k] - 1 for k in range(3)]
    axes = (0, 1, 2)
    full = np.fft.irfftn(np.fft.rfftn(chi, shape, axes) * np.fft.rfftn(ball, shape, axes), shape, axes)
    reach = (ball.shape[0] - 1) // 2
    psi = full[reach:reach + chi.shape[0], reach:reach + chi.shape[1], reach:reach + chi.shape[2]]
    return np.where(psi > 1e-9 * spacing**3, psi, 0.0).ravel().astype(np.float32)


def _grid(lo, hi, particle_radius, support_radius, thickness):
    """Nodes about the box [lo, hi] reaching H + thickness + 2 spacings beyond it: (points (x fastest), dims (x, y, z),
    lower, spacing); spacing r/2, coarser where more than MAX_NODES_PER_AXIS would be needed."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    spacing = max(0.5 * particle_radius, float((hi - lo).max() + 2.0 * (support_radius + thickness)) / (MAX_NODES_PER_AXIS - 5))
    margin = support_radius + thickness + 2.0 * spacing
    lower = lo - margin
    dims = np.ceil((hi + margin - lower) / spacing).astype(int) + 1
    axes = [lower[k] + spacing * np.arange(dims[k]) for k in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")  # (z, y, x): x fastest when flattened
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1), [int(c) for c in dims], lower, spacing


def tabulate_volume(vertices, faces, particle_radius, support_radius, thickness, device):
    """Psi(x) = integral over |y| < H of chi(d(x + y)) on a grid about a closed mesh (body space): chi = 1 where
    d = (signed distance - ``thickness``) <= 0, W(d)/W(0) for 0 < d < H, 0 beyond (SimulatorBase::initVolumeMap;
    warpsph.io.splishsplash.volume_map_standoff for the plane). Signed distances from the mesh (Warp's winding number),
    the integral a discrete convolution with :func:`ball_weights` (FFT). Returns (values, dims (x, y, z), lower,
    spacing), values flat with x fastest [m^3]."""
    vertices = np.asarray(vertices, np.float64)
    points, dims, lower, spacing = _grid(vertices.min(axis=0), vertices.max(axis=0), particle_radius, support_radius,
                                         thickness)
    mesh = wp.Mesh(points=wp.array(vertices.astype(np.float32), dtype=wp.vec3, device=device),
                   indices=wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32, device=device))
    distance = wp.zeros(len(points), dtype=float, device=device)
    far = float(2.0 * (support_radius + thickness) + spacing)
    wp.launch(vk.signed_distance_at_points, len(points),
              [mesh.id, wp.array(points.astype(np.float32), dtype=wp.vec3, device=device), far, distance], device=device)
    d = distance.numpy().astype(np.float64).reshape(dims[2], dims[1], dims[0]) - thickness
    return _convolved(d, support_radius, spacing), dims, lower, spacing


class VolumeMaps:
    """The mapped dynamic bodies' maps and meshes on the device. Their points take the boundary slots from ``first``:
    fluid particle i's point of map m in slot ``first + i * count + m`` (``count`` maps)."""

    def __init__(self, state, constants, bodies, mapped, first, first_moving):
        """``mapped``: [(index of the body in ``bodies``, thickness [m])]."""
        self.count = len(mapped)
        self.first = first
        self.first_moving = first_moving
        r, h = constants.particle_radius, constants.support_radius
        tables, firsts, dims, lowers, inverse = [], [0], [], [], []
        self.meshes = []
        for index, thickness in mapped:
            b = bodies[index]
            values, n, lower, spacing = tabulate_volume(b.vertices, b.faces, r, h, thickness, state.device)
            tables.append(values)
            firsts.append(firsts[-1] + len(values))
            dims.append(n)
            lowers.append(lower)
            inverse.append(1.0 / spacing)
            self.meshes.append(wp.Mesh(points=state.array("bodies", b.vertices.astype(np.float32), wp.vec3),
                                       indices=state.array("bodies", b.faces.ravel().astype(np.int32), wp.int32)))
        self.spacings = [1.0 / s for s in inverse]
        self.body_indices = [i for i, _ in mapped]
        self.values = state.array("bodies", np.concatenate(tables), float)
        self.value_first = state.array("bodies", np.asarray(firsts[:-1], np.int32), wp.int32)
        self.dims = state.array("bodies", np.asarray(dims, np.int32), wp.vec3i)
        self.lower = state.array("bodies", np.asarray(lowers, np.float32), wp.vec3)
        self.inverse_spacing = state.array("bodies", np.asarray(inverse, np.float32), float)
        self.mesh_ids = state.array("bodies", np.array([m.id for m in self.meshes], np.uint64), wp.uint64)
        self.body = state.array("bodies", np.asarray(self.body_indices, np.int32), wp.int32)
        self.thickness = state.array("bodies", np.asarray([t for _, t in mapped], np.float32), float)

    def place(self, launch, x, num_fluid, moving, boundary, constants):
        """Each fluid particle's boundary point of each map at the bodies' current poses (before the lists)."""
        launch(vk.place_map_samples, num_fluid * self.count,
               [x, self.mesh_ids, self.body, self.thickness, self.values, self.value_first, self.dims, self.lower,
                self.inverse_spacing, moving.rotation, moving.position, moving.velocity, moving.angular_velocity,
                self.count, self.first, self.first_moving, constants.particle_radius, constants.support_radius,
                boundary.x, boundary.v, boundary.volume])

    def place_velocities(self, launch, num_fluid, moving, boundary):
        """The points' velocities after the bodies' velocities changed (strong coupling)."""
        launch(vk.place_map_velocities, num_fluid * self.count,
               [self.body, moving.position, moving.velocity, moving.angular_velocity, self.count, self.first,
                self.first_moving, boundary.x, boundary.volume, boundary.v])

    def add_neighbours(self, launch, num_fluid, boundary_volume, fill, rows, neighbours):
        """Each particle's own points in its boundary list (``fill`` 0: the counts, before the scan; 1: the entries)."""
        launch(vk.add_map_neighbours, num_fluid, [boundary_volume, self.count, self.first, fill, rows, neighbours])
