"""From a scene to its initial particles, on the host before anything is allocated: particle counts, the
fluid blocks and meshes and boundary samples, and the fluid that they put inside bodies removed."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import warp as wp

from warpsph import sampling
from warpsph.bodies import BODY_INSET, load_body
from warpsph.errors import SceneError
from warpsph.kernels.bodies import mark_fluid_clear_of_mesh
from warpsph.sampling import WALL_OFFSET
from warpsph.scene import Scene, walled_faces
from warpsph.io.splishsplash import conversion_of

# Neighbour lists index with int32: about 40 neighbours a particle keeps 50M particles below 2^31.
MAX_PARTICLES = 50_000_000


@functools.lru_cache(maxsize=16)
def _filled_mesh(path, stamp, scale, axis, angle, translation, spacing):
    mesh = sampling.load_mesh(path)
    if not mesh.is_watertight:
        return None
    local = sampling.fill_mesh(np.asarray(mesh.vertices) * np.asarray(scale), mesh.faces, spacing)
    points = (local @ sampling.rotation_matrix(axis, angle).T + np.asarray(translation)).astype(np.float32)
    points.flags.writeable = False
    return points


def fluid_mesh_points(scene: Scene, n: int):
    """The fluid particles of ``scene.fluid_meshes[n]`` (world space, float32): the closed mesh filled
    on the lattice of spacing 2r (``sampling.fill_mesh``), then rotated and translated. An open mesh, or
    fluid outside the domain, is a :class:`SceneError` naming the key."""
    m = scene.fluid_meshes[n]
    path = scene.mesh_path(m)
    stamp = path.stat().st_mtime_ns if path.is_file() else None
    points = _filled_mesh(str(path), stamp, tuple(m.scale), tuple(m.rotation_axis), m.rotation_angle,
                          tuple(m.translation), scene.particle_diameter)
    if points is None:
        raise SceneError(path, f"fluid_meshes[{n}].mesh", "the mesh is not closed (watertight): it has no inside to fill")
    lo, hi = np.asarray(scene.domain.min), np.asarray(scene.domain.max)
    if len(points) and (np.any(points.min(axis=0) < lo - 1e-9) or np.any(points.max(axis=0) > hi + 1e-9)):
        raise SceneError(scene.source, f"fluid_meshes[{n}]", f"the filled mesh reaches {points.min(axis=0).tolist()}.."
                                                              f"{points.max(axis=0).tolist()}, outside the domain "
                                                              f"{list(lo)}..{list(hi)}")
    return points


def count_particles(scene: Scene):
    """Fluid and domain-wall particle counts, computed before anything is sampled (fluid meshes are filled)."""
    d = scene.particle_diameter
    fluid = sum(int(np.prod(np.floor((np.subtract(b.end, b.start)) / d + 1e-6))) for b in scene.fluid_blocks)
    fluid += sum(len(fluid_mesh_points(scene, n)) for n in range(len(scene.fluid_meshes)))
    ext = np.subtract(scene.domain.max, scene.domain.min) + 2 * WALL_OFFSET * scene.particle_radius
    walls = int(2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2]) / d**2) if scene.domain.walls else 0
    return fluid, walls


def sample_scene(scene: Scene, limit_fluid=True, with_fluid=True):
    """Host-side initial particles: fluid (x, v), the static boundary (x, body index, Z-ordered)
    and every obstacle as a :class:`RigidBody` (static ones included, for the USD meshes). ``limit_fluid``
    False: the fluid may exceed MAX_PARTICLES (a decomposed simulation limits each subdomain's rows);
    ``with_fluid`` False: no fluid particles (the subdomains get theirs)."""
    fluid, walls = count_particles(scene)
    if (limit_fluid and fluid > MAX_PARTICLES) or walls > MAX_PARTICLES:
        raise SceneError(scene.source, "particle_radius",
                         f"r = {scene.particle_radius:.3g} m needs about {max(fluid, walls):.3g} particles, over the "
                         f"{MAX_PARTICLES:,} limit: use a larger radius or a smaller --scale")
    if fluid == 0 and not any(e.start == 0.0 for e in scene.emitters):
        raise SceneError(scene.source, "fluid_blocks", "no fluid at t = 0: every block is thinner than one particle "
                                                       "spacing, every fluid mesh holds no lattice point (or they are "
                                                       "missing) and no emitter starts at 0")
    d = scene.particle_diameter
    sources = list(scene.fluid_blocks) + list(scene.fluid_meshes)
    blocks = [sampling.fill_block(b.start, b.end, d) for b in scene.fluid_blocks] if with_fluid else []
    blocks += [fluid_mesh_points(scene, n) for n in range(len(scene.fluid_meshes))] if with_fluid else []
    fluid_x = np.concatenate(blocks) if blocks else np.zeros((0, 3), np.float32)
    fluid_v = np.concatenate([np.tile(np.asarray(b.velocity, np.float32), (len(p), 1))
                              for b, p in zip(sources, blocks)]) if blocks else np.zeros((0, 3), np.float32)
    # walls stand off 1.2 r from the faces; along periodic axes they span the domain exactly
    offset = np.where(np.asarray(scene.domain.period) > 0, 0.0, WALL_OFFSET * scene.particle_radius)
    bodies = [sampling.sample_box_walls(np.asarray(scene.domain.min) - offset, np.asarray(scene.domain.max) + offset, d,
                                        scene.domain.periodic) if scene.domain.walls else np.zeros((0, 3), np.float32)]
    size = float(np.linalg.norm(np.subtract(scene.domain.max, scene.domain.min)))
    insets = _imported_body_insets(scene)
    rigid = [load_body(o, scene.mesh_path(o), d, size, f"{Path(o.mesh).stem}_{n}", scene.fluid.density, insets[n])
             for n, o in enumerate(scene.obstacles)]
    for b, thickness in zip(rigid, imported_volume_maps(scene)):
        if b.kind == "dynamic" and b.closed:
            b.volume_map = thickness
    names = [b.name for b in rigid]
    for n, name in enumerate(names):
        if names.index(name) != n:
            raise SceneError(scene.source, f"obstacles[{n}].name", f"another body is named {name!r}")
    bodies += [inside_wall_layer(scene, b.world_samples()) if b.kind == "static" else np.zeros((0, 3), np.float32)
               for b in rigid]
    boundary_x = np.concatenate(bodies).reshape(-1, 3)
    body = np.concatenate([np.full(len(p), n, dtype=np.int32) for n, p in enumerate(bodies)])
    order = sampling.morton_order(boundary_x, np.asarray(scene.domain.min), scene.support_radius)
    return fluid_x, fluid_v, boundary_x[order], body[order], rigid


def inside_wall_layer(scene: Scene, points):
    """A static body's samples less those behind the domain's wall layer (WALL_OFFSET r outside each walled face;
    periodic axes and open domains keep all). The fluid never gets there, and such samples would only crowd the
    layer's own samples, whose Akinci volumes (1 / sum_k W_bk over all static samples) then shrink: where a body
    runs into a wall the wall held the fluid beside it with 0.73 of its density sum and 0.44 of its push, and the
    fluid pressed into that corner went through (an imported SPlisHSPlasH obstacle that touches its container, its
    samples 0.2 r outside its surface and the faces 1.4 r in: Obstacle.json, #39)."""
    if not len(points) or not scene.domain.walls:
        return points
    lo, hi = walled_faces(scene.domain)
    layer = (WALL_OFFSET + 1e-3) * scene.particle_radius
    keep = np.all((points >= np.subtract(lo, layer)) & (points <= np.add(hi, layer)), axis=1)
    return points if keep.all() else points[keep]


def _imported_body_insets(scene: Scene):
    """Each obstacle's sample inset [r]: BODY_INSET, or where an imported SPlisHSPlasH scene's boundary holds the
    fluid (``Conversion.body_insets``, one per obstacle of the conversion)."""
    conversion = conversion_of(scene)
    insets = list(conversion.body_insets) if conversion is not None else []
    if len(insets) != len(scene.obstacles):
        insets = [BODY_INSET] * len(scene.obstacles)
    return insets


def imported_volume_maps(scene: Scene):
    """Each obstacle's volume-map thickness [m], or None: an imported SPlisHSPlasH scene's dynamic bodies with
    boundaryHandlingMethod 2 hold the fluid by a volume map (``Conversion.volume_maps``, warpsph.volume_maps)."""
    conversion = conversion_of(scene)
    maps = list(conversion.volume_maps) if conversion is not None else []
    return maps if len(maps) == len(scene.obstacles) else [None] * len(scene.obstacles)


def remove_fluid_inside_bodies(scene, bodies, fluid_x, fluid_v, device, launch):
    """Drops the fluid particles that the blocks put inside a closed body or within one
    particle radius of its surface (at the body's initial pose); open meshes keep them."""
    closed = [b for b in bodies if b.closed]
    if not closed or not len(fluid_x):
        return fluid_x, fluid_v
    x = wp.array(fluid_x, dtype=wp.vec3, device=device)
    keep = wp.ones(len(fluid_x), dtype=wp.int32, device=device)
    for b in closed:
        mesh = wp.Mesh(points=wp.array(b.to_world(b.vertices), dtype=wp.vec3, device=device),
                       indices=wp.array(b.faces.ravel(), dtype=wp.int32, device=device))
        launch(mark_fluid_clear_of_mesh, len(fluid_x), [mesh.id, x, scene.particle_radius, keep])
    kept = keep.numpy().astype(bool)
    if not kept.any():
        raise SceneError(scene.source, "obstacles", "the bodies cover every fluid particle: no fluid left")
    return fluid_x[kept], fluid_v[kept]

