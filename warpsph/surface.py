"""Surface meshes of the fluid (``warpsph run --surface``, ``warpsph surface``), with splashsurf.

Reconstruction runs `pysplashsurf <https://github.com/InteractiveComputerGraphics/splashsurf>`_
(pinned 0.14.1.0, the optional extra ``warpsph[surface]``) on one frame's particles on the host:
an SPH "colour field" (cubic spline kernel) sampled on a marching-cubes grid, the iso surface at
``iso``, then splashsurf's post-processing. The defaults are splashsurf's recommendations for
particles of radius r sampled 2 r apart with a cubic kernel of support 4 r:

- ``smoothing`` 2.0: smoothing length 2 r (kernel support 4 r), in multiples of the radius;
- ``cube`` 0.75: marching-cubes cell of 0.75 r (0.5 r is finer and about 2x slower, 3x the triangles);
- ``iso`` 0.6: the colour-field threshold;
- mesh cleanup (Moore & Warren), 25 iterations of weighted Laplacian smoothing (Löschner et al.
  2023) and vertex normals smoothed 10 times.

pysplashsurf 0.14.1.0 reads ``smoothing_length`` and ``cube_size`` as *multiples of the particle
radius* (its ``reconstruct_surface`` docstring says absolute units); warpsph passes multiples and
tests it (a sphere's mesh keeps the sphere's radius, its edges are about ``cube`` r long).

Every mesh is clipped to the tank (#42, :func:`clip_mesh`): vertices outside the domain's walled faces
are moved onto them, vertices inside a closed body onto its surface and vertices within 1.2 r of an
open body's mesh (a shell: the funnel) 1.2 r off it on the fluid's side (:func:`surface_clip` of the
scene's domain and bodies; ``warpsph surface`` reads the domain from the cache's ``warpsph:domain``).

Per vertex the mesh carries the particles' velocity interpolated with the SPH kernel (for motion
blur: USD ``velocities``) and, when the frame has a vorticity field (a turbulence model runs),
the vorticity magnitude (a primvar for shading foam and detail).

Example:

```python
import warpsph
from warpsph.surface import SurfaceOptions, mesh_frame, surface_clip

sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
sim.run(frames=2)
mesh = mesh_frame(sim.positions(), sim.scene.particle_radius, sim.velocities(),
                  options=SurfaceOptions(method="preview"),  # the default "splashsurf" needs pysplashsurf
                  clip=surface_clip(sim.scene.domain))  # no vertex through the tank's walls
print(len(mesh.points), len(mesh.faces))
```
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .errors import SceneError
from .io.processes import load, load_tree, start_workers, stop_workers, store, store_tree
from .io.files import fsync
from .scene import walled_faces

__all__ = ["SurfaceOptions", "SurfaceMesh", "reconstruct", "reconstruct_preview", "mesh_frame", "mesh_volume",
           "SurfaceClip", "ClipBody", "surface_clip", "clip_mesh", "open_frames", "UsdFrames", "H5Frames", "plan_remesh",
           "remesh", "mesh_quality"]

PYSPLASHSURF = "0.14.1.0"
INSTALL_HINT = f"pip install 'warpsph[surface]' (pysplashsurf=={PYSPLASHSURF})"
METHODS = ("splashsurf", "preview")
ISO_DEFAULTS = {"splashsurf": 0.6, "preview": 0.6}


@dataclass(frozen=True)
class SurfaceOptions:
    """Reconstruction parameters; ``smoothing`` and ``cube`` in multiples of the particle radius.

    Example:

    ```python
    from warpsph.surface import SurfaceOptions

    fine = SurfaceOptions(cube=0.5, smoothing=2.0).check()  # SceneError naming an out-of-range option
    print(fine.threshold, SurfaceOptions(method="preview").threshold)  # the iso values: 0.6, 0.6
    ```
    """

    cube: float = 0.75
    smoothing: float = 2.0
    iso: float | None = None  # None: the method's default (0.6, splashsurf's, for both)
    smoothing_iters: int = 25
    normals_iters: int = 10
    cleanup: bool = True
    method: str = "splashsurf"  # or "preview": Warp's sparse marching cubes (reconstruct_preview)

    @property
    def threshold(self):
        """The iso value of the colour field."""
        return self.iso if self.iso is not None else ISO_DEFAULTS[self.method]

    def check(self, prefix="--"):
        """Raises :class:`SceneError` naming the option when a value is out of range."""
        if self.method not in METHODS:
            raise SceneError("", f"{prefix}method" if prefix == "--surface-" else "--method",
                             f"expected one of {', '.join(METHODS)}, got {self.method!r}")
        if not (np.isfinite(self.cube) and self.cube > 0):
            raise SceneError("", f"{prefix}cube", f"expected a marching-cubes cell size > 0 (in particle radii, "
                                                  f"e.g. 0.5 to 0.75), got {self.cube}")
        if not (np.isfinite(self.smoothing) and self.smoothing > 0):
            raise SceneError("", f"{prefix}smoothing", f"expected a smoothing length > 0 (in particle radii, "
                                                       f"e.g. 2.0), got {self.smoothing}")
        if not (np.isfinite(self.threshold) and self.threshold > 0):
            raise SceneError("", f"{prefix}iso", f"expected an iso threshold > 0 (e.g. 0.6), got {self.iso}")
        return self


@dataclass
class SurfaceMesh:
    """A triangle mesh: ``points`` (V, 3) float32, ``faces`` (F, 3) int32, ``normals`` and
    ``velocities`` (V, 3) float32 (velocities None when not asked), ``primvars`` {name: (V,) or
    (V, 3) float32}; ``seconds`` the reconstruction's wall time. ``layer``: the USD layer the mesh was
    written into where it was made (a --clips frame layer, by the mesher's worker), its arrays then empty.

    Example:

    ```python
    import numpy as np
    from warpsph.surface import reconstruct_preview

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    mesh = reconstruct_preview(points, r)  # a SurfaceMesh
    print(mesh.points.shape, mesh.faces.shape, mesh.normals.shape, mesh.seconds)
    ```
    """

    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    velocities: np.ndarray | None = None
    primvars: dict = field(default_factory=dict)
    seconds: float = 0.0
    layer: str | None = None
    pending: object = None  # a Warp event: the arrays (pinned host memory) are being copied until it completes

    def wait(self):
        """Waits for the copies of :func:`preview_on_device` (``pending``); the arrays are readable after it."""
        if self.pending is not None:
            import warp as wp

            wp.synchronize_event(self.pending)
            self.pending = None
        return self

    @staticmethod
    def empty(velocities=True):
        """A mesh with no vertices and no faces (a frame without fluid)."""
        z = np.zeros((0, 3), np.float32)
        return SurfaceMesh(z, np.zeros((0, 3), np.int32), z.copy(), z.copy() if velocities else None)


@dataclass(frozen=True, eq=False)
class ClipBody:
    """A body the fluid's surface is pushed out of: ``vertices`` (V, 3) in world space (a static
    body) or in body space (a moving one, placed by each frame's pose), ``faces`` (F, 3), outward;
    ``closed`` false: an open mesh (boundary edges, no inside), a shell of ``surface_clip.SHELL`` r
    (1.2 r) either side of the mesh.

    Example:

    ```python
    import numpy as np
    import trimesh
    from warpsph.surface import ClipBody, SurfaceClip, clip_mesh, reconstruct_preview

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    box = trimesh.creation.box(bounds=((0.05, -0.05, -0.05), (0.15, 0.05, 0.05)))  # closed, outward
    clip = SurfaceClip(bodies=(ClipBody("box", box.vertices, box.faces),))
    mesh = reconstruct_preview(points, r)
    assert clip_mesh(mesh, clip) > 0  # the vertices inside the box moved onto its faces
    ```
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    moving: bool = False
    closed: bool = True


@dataclass(frozen=True, eq=False)
class SurfaceClip:
    """What a mesh is clipped to (#42): the walled faces of the domain, ``lo`` and ``hi`` per axis (-inf and
    +inf along an axis without walls: periodic, or an open domain), and the ``bodies``
    (:class:`ClipBody`: closed meshes and open shells). The colour field's iso surface reaches about a particle radius beyond the
    outermost particle centres, and the particles sit up to the wall (``inside_lo``/``inside_hi`` of the
    simulation): unclipped, splashsurf's meshes reached 1.3 r through the walls and the floor.

    Example:

    ```python
    import numpy as np
    from warpsph.surface import SurfaceClip, clip_mesh, reconstruct_preview

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    clip = SurfaceClip(lo=(-np.inf, 0.0, -np.inf), hi=(np.inf, np.inf, np.inf))  # a floor at y = 0
    print(clip.walled, "|", clip.describe())  # "y" | the walls across y
    mesh = reconstruct_preview(points, r)
    print(clip_mesh(mesh, clip), "vertices moved onto the floor")
    ```
    """

    lo: tuple = (-np.inf, -np.inf, -np.inf)
    hi: tuple = (np.inf, np.inf, np.inf)
    bodies: tuple = ()

    @property
    def walled(self):
        """The axes with walls, e.g. "xyz", "y" (x and z periodic) or "" (an open domain)."""
        return "".join("xyz"[k] for k in range(3) if np.isfinite(self.lo[k]) or np.isfinite(self.hi[k]))

    def describe(self):
        """E.g. "the walls across x, y, z and 2 bodies"."""
        parts = [f"the walls across {', '.join(self.walled)}"] if self.walled else []
        if self.bodies:
            parts.append(f"{len(self.bodies)} bod{'y' if len(self.bodies) == 1 else 'ies'}")
        return " and ".join(parts) or "nothing"


def surface_clip(domain=None, bodies=()):
    """The :class:`SurfaceClip` of a scene: the walled faces of ``domain`` (a scene's ``Box``, or anything
    with ``min``, ``max``, ``periodic`` and ``walls``: the faces the simulation keeps the particles inside)
    and the meshes of ``bodies`` ((name, vertices, faces, moving) as :func:`warpsph.io.usd.body_meshes`
    gives them; a mesh with boundary edges has no inside and is an open shell, ``ClipBody.closed``
    false: its boundary samples lie on the mesh, and the fluid keeps 1.2 r off it on either side). None
    when there is nothing to clip to.

    Example:

    ```python
    import warpsph
    from warpsph.surface import surface_clip

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    clip = surface_clip(scene.domain)  # the tank's walls; bodies: (name, vertices, faces, moving) tuples
    print(clip.describe())
    ```
    """
    lo, hi = walled_faces(domain) if domain is not None else ((-np.inf,) * 3, (np.inf,) * 3)
    clipped = []
    for name, vertices, faces, moving in bodies or ():
        vertices, faces = np.asarray(vertices, np.float64).reshape(-1, 3), np.asarray(faces, np.int32).reshape(-1, 3)
        if len(faces) == 0:
            continue
        closed = boundary_edges(faces) == 0
        if closed and mesh_volume(vertices, faces) < 0:  # inward triangles: the winding number would call the inside outside
            faces = np.ascontiguousarray(faces[:, ::-1])
        clipped.append(ClipBody(str(name), vertices, faces, bool(moving), closed))
    clip = SurfaceClip(lo, hi, tuple(clipped))
    return clip if clip.walled or clip.bodies else None


def clip_mesh(mesh, clip, poses=None, radius=None):
    """Moves the vertices of ``mesh`` that lie outside a walled face of ``clip`` onto the face (along walled
    axes only), then those inside a closed body of ``clip`` onto the body's surface (the nearest point)
    and those within ``surface_clip.SHELL`` ``radius`` (the particle radius; open bodies are left out
    without it) of an open body's mesh to that distance on the fluid's side (the side the vertex's normal
    points away from; a moving body at its pose in ``poses``, {name: (position, rotation)}, left out
    without one), then onto the walls again (a body reaching through a wall). Returns the number of
    vertices moved. The faces stay (a closed mesh stays closed), and so do the velocities and the
    normals (the colour field's at the vertex meshed: at a vertex flattened onto a wall they point out of
    the fluid, into the wall, as the flattened surface's own normal does). A GPU run's preview has its
    walls clamped on the device (:func:`preview_on_device`) and the rest done here on the host.

    Example:

    ```python
    import numpy as np
    from warpsph.surface import SurfaceClip, clip_mesh, reconstruct_preview

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    mesh = reconstruct_preview(points, r)
    moved = clip_mesh(mesh, SurfaceClip(hi=(0.05, np.inf, np.inf)))  # a wall at x = 0.05
    assert moved > 0 and mesh.points[:, 0].max() <= 0.05 + 1e-6
    ```
    """
    if clip is None or len(mesh.points) == 0:
        return 0
    points = np.array(mesh.points, np.float32)
    moved = np.zeros(len(points), bool)
    lo, hi = wall_bounds(clip) if clip.walled else (None, None)
    if clip.walled:
        moved |= ((points < lo) | (points > hi)).any(axis=1)
        np.clip(points, lo, hi, out=points)
    if clip.bodies:
        from .surface_clip import push_out_of_bodies

        pushed = push_out_of_bodies(points, clip.bodies, poses, radius, mesh.normals)
        moved |= pushed
        if clip.walled and pushed.any():
            np.clip(points, lo, hi, out=points)
    mesh.points = points
    return int(moved.sum())


def wall_bounds(clip):
    """The walled faces of ``clip`` as float32 (lo, hi), rounded inwards (on or inside the faces); +-inf (float32
    max) along an axis without walls."""
    lo, hi = np.asarray(clip.lo, np.float32), np.asarray(clip.hi, np.float32)
    lo = np.where(lo < np.asarray(clip.lo), np.nextafter(lo, np.float32(np.inf)), lo)
    hi = np.where(hi > np.asarray(clip.hi), np.nextafter(hi, np.float32(-np.inf)), hi)
    return lo, hi


def require_pysplashsurf(option="--surface"):
    """The pysplashsurf module, or a :class:`SceneError` naming ``option`` that says how to install it."""
    try:
        import pysplashsurf
    except ImportError:
        raise SceneError("", option, f"surface meshes need pysplashsurf, which is not installed: {INSTALL_HINT}") from None
    return pysplashsurf


def reconstruct(points, radius, velocities=None, vorticity=None, options=SurfaceOptions(), threads=True):
    """The surface mesh of particles at ``points`` (N, 3) of radius ``radius`` [m].

    ``velocities`` (N, 3): interpolated to the vertices; ``vorticity`` (N, 3) or its magnitude (N,):
    its magnitude interpolated as the primvar ``vorticity_magnitude``. ``threads``: splashsurf's
    own multi-threading (rayon; it releases the GIL).

    Example:

    ```python
    import numpy as np
    from warpsph.surface import reconstruct  # needs: pysplashsurf

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    mesh = reconstruct(points, r, velocities=np.zeros_like(points))
    print(len(mesh.faces), mesh.velocities.shape)
    ```
    """
    ps = require_pysplashsurf()
    start = time.perf_counter()
    points = np.ascontiguousarray(points, np.float32)
    if len(points) == 0:
        mesh = SurfaceMesh.empty(velocities is not None)
        if vorticity is not None:
            mesh.primvars["vorticity_magnitude"] = np.zeros(0, np.float32)
        return mesh
    attributes = {}
    if velocities is not None:
        attributes["velocity"] = np.ascontiguousarray(velocities, np.float32)
    if vorticity is not None:
        vorticity = np.asarray(vorticity, np.float32)
        magnitude = np.linalg.norm(vorticity, axis=1) if vorticity.ndim == 2 else vorticity
        attributes["vorticity_magnitude"] = np.ascontiguousarray(magnitude, np.float32)
    result, _ = ps.reconstruction_pipeline(
        points, attributes_to_interpolate=attributes or None, particle_radius=float(radius),
        smoothing_length=float(options.smoothing), cube_size=float(options.cube),  # multiples of the radius in 0.14.1
        iso_surface_threshold=float(options.threshold), multi_threading=threads, subdomain_grid=True,
        mesh_cleanup=options.cleanup, mesh_smoothing_weights=True, mesh_smoothing_iters=options.smoothing_iters or None,
        compute_normals=True, normals_smoothing_iters=options.normals_iters or None)
    tri = result.mesh
    data = result.point_attributes
    vertices = np.ascontiguousarray(tri.vertices, np.float32)
    normals = data.get("normals")
    normals = (np.ascontiguousarray(normals, np.float32) if normals is not None
               else np.zeros_like(vertices))
    mesh = SurfaceMesh(vertices, np.ascontiguousarray(tri.triangles, np.int32), normals)
    if velocities is not None:
        mesh.velocities = np.ascontiguousarray(data["velocity"], np.float32)
    if vorticity is not None:
        mesh.primvars["vorticity_magnitude"] = np.ascontiguousarray(data["vorticity_magnitude"], np.float32).ravel()
    mesh.seconds = time.perf_counter() - start
    return mesh


PREVIEW_BLOCK = 8  # cells per block edge of the preview's sparse grid
PREVIEW_MAX_BLOCKS = 1 << 24  # the dense block-flag grid; coarser blocks beyond it (a particle flung far away)


def reconstruct_preview(points, radius, velocities=None, vorticity=None, options=None, device="cpu"):
    """A surface with Warp's sparse marching cubes (``--surface-method preview``), on ``device``, from host
    arrays: ``points`` (N, 3), ``velocities`` (N, 3) interpolated to the vertices, ``vorticity`` (N, 3) or its
    magnitude (N,) carried as the primvar ``vorticity_magnitude``. See :func:`preview_on_device`.

    Example:

    ```python
    import numpy as np
    from warpsph.surface import reconstruct_preview

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    mesh = reconstruct_preview(points, r, device="cpu")  # "cuda": on the GPU
    print(len(mesh.faces))
    ```
    """
    import warp as wp

    options = options if options is not None else SurfaceOptions(method="preview")
    start = time.perf_counter()
    points = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    magnitude = None
    if vorticity is not None:
        vorticity = np.asarray(vorticity, np.float32)
        magnitude = np.linalg.norm(vorticity, axis=1) if vorticity.ndim == 2 else vorticity.ravel()
    if len(points) == 0:
        return _empty_preview(velocities is not None, magnitude is not None)
    device = wp.get_device(device)
    with wp.ScopedDevice(device):
        x = wp.array(points, dtype=wp.vec3, device=device)
        v = wp.array(np.ascontiguousarray(velocities, np.float32), dtype=wp.vec3, device=device) \
            if velocities is not None else None
        scalar = wp.array(np.ascontiguousarray(magnitude, np.float32), dtype=float, device=device) \
            if magnitude is not None else None
        mesh = preview_on_device(x, radius, v, scalar, options).wait()
    mesh.seconds = time.perf_counter() - start
    return mesh


def _empty_preview(velocities, vorticity):
    mesh = SurfaceMesh.empty(velocities)
    if vorticity:
        mesh.primvars["vorticity_magnitude"] = np.zeros(0, np.float32)
    return mesh


def preview_on_device(x, radius, velocities=None, scalar=None, options=None, walls=None):
    """The preview surface of the particles ``x`` (a Warp array of vec3 on its device: the simulation's own, no
    copy to the host), the host arrays of a :class:`SurfaceMesh` back. ``velocities`` (vec3) and ``scalar``
    (float, the vorticity magnitude) are Warp arrays of the same rows, or None. Every launch goes to the device's
    current stream: on a simulation's device, called between its steps (:class:`DeviceMesher` runs the same
    stages, :func:`preview_stages`, on a stream of its own without waiting). On a GPU the mesh's arrays are copied
    into pinned host memory without waiting: call :meth:`SurfaceMesh.wait` before reading them. ``walls``:
    (lo, hi) of :func:`wall_bounds`, the box the vertices are clamped into (the domain's walled faces), or None.

    The colour field c(x) = sum_j V_j W(|x - x_j|) (cubic spline, support ``2 * smoothing`` r; V_j = 1 / sum_k
    W(|x_j - x_k|), each particle's volume from its neighbours, as splashsurf's) is sampled at the nodes of the
    blocks of 8^3 cells of ``cube`` r that some particle's support overlaps, and the cells that straddle ``iso``
    (default 0.6, splashsurf's) are meshed by ``warp.geometry.sparse_marching_cubes_from_cells`` (shared
    vertices: watertight). ``options.smoothing_iters`` steps of Taubin's smoothing (lambda 0.5, mu -0.53,
    alternating; Taubin 1995) take off the marching cubes' staircase without shrinking the mesh. Normals are
    -grad c at the smoothed vertices; velocities and the scalar are interpolated with the kernel (Shepard)."""
    import warp as wp

    stages = preview_stages(x, radius, velocities, scalar, options, walls)
    try:
        event = next(stages)
        while True:  # each stage waits for the small values it reads from the device
            if event is not None:
                wp.synchronize_event(event)
            event = stages.send(None)
    except StopIteration as done:
        return done.value


def preview_stages(x, radius, velocities=None, scalar=None, options=None, walls=None):
    """:func:`preview_on_device` as a generator: it launches a stage's work and yields a ``wp.Event`` (None on the
    CPU) where it must read a few numbers back from the device (the particles' bounds, the count of active blocks,
    of straddling cells, the mesh's orientation) through pinned memory; resumed once the event is complete, it
    reads them without waiting and goes on; it returns the :class:`SurfaceMesh`. Each resumption launches on the
    device's current stream. Every device array lives in the generator until it returns."""
    import warp as wp
    from warp.geometry import IsoSurfaceMarchingCubes, sparse_marching_cubes_from_cells

    from .kernels import surface_preview as K

    options = options if options is not None else SurfaceOptions(method="preview")
    n = len(x)
    if n == 0:
        return _empty_preview(velocities is not None, scalar is not None)
    device = x.device
    pinned = device.is_cuda
    support = 2.0 * float(options.smoothing) * float(radius)
    cell = float(options.cube) * float(radius)
    iso = float(options.threshold)

    def read_back(*arrays):  # the arrays copied into pinned host memory, and the event that says they are there
        copies = []
        for a in arrays:
            out = wp.empty(a.shape, dtype=a.dtype, device="cpu", pinned=pinned)
            wp.copy(out, a)
            copies.append(out)
        return copies, (wp.record_event() if pinned else None)

    with wp.ScopedDevice(device):  # every allocation names the device too: the current device is process-wide
        bounds = wp.array([np.inf] * 3 + [-np.inf] * 3, dtype=float, device=device)
        wp.launch(K.bounds, n, inputs=[x, bounds[:3], bounds[3:]], device=device)
        (host_bounds,), event = read_back(bounds)
    yield event
    with wp.ScopedDevice(device):
        b = host_bounds.numpy().astype(np.float64)
        lo, hi = b[:3], b[3:]
        lower = lo - support - cell
        B = PREVIEW_BLOCK
        while True:
            block = B * cell
            dims = np.maximum(np.ceil((hi + support + cell - lower) / block).astype(np.int64), 1)
            if int(np.prod(dims)) <= PREVIEW_MAX_BLOCKS:
                break
            B *= 2
        dims_v = wp.vec3i(*map(int, dims))
        lower_v = wp.vec3(*map(float, lower))
        grid = wp.HashGrid(*[int(max(1, min(128, d))) for d in np.ceil((hi - lo) / support + 1)], device=device)
        grid.build(x, support)
        volumes = wp.empty(n, dtype=float, device=device)
        wp.launch(K.particle_volumes, n, inputs=[grid.id, x, support, volumes], device=device)
        flags = wp.zeros(int(np.prod(dims)), dtype=wp.int32, device=device)
        wp.launch(K.mark_blocks, n, device=device, inputs=[x, lower_v, float(block), support, dims_v, flags])
        offsets = wp.empty_like(flags)
        wp.utils.array_scan(flags, offsets, inclusive=False)
        (last_offset, last_flag), event = read_back(offsets[-1:], flags[-1:])
    yield event
    with wp.ScopedDevice(device):
        count = int(last_offset.numpy()[0] + last_flag.numpy()[0])
        blocks = wp.empty(max(count, 1), dtype=wp.int32, device=device)
        wp.launch(K.compact, len(flags), device=device, inputs=[flags, offsets, blocks])
        nodes = (B + 1) ** 3
        values = wp.empty(count * nodes, dtype=float, device=device)
        wp.launch(K.block_field, count * nodes, device=device,
                  inputs=[blocks, dims_v, B, lower_v, cell, grid.id, x, support, volumes, values])
        cell_flags = wp.empty(count * B ** 3, dtype=wp.int32, device=device)
        wp.launch(K.mark_cells, len(cell_flags), device=device, inputs=[values, B, iso, cell_flags])
        cell_offsets = wp.empty_like(cell_flags)
        wp.utils.array_scan(cell_flags, cell_offsets, inclusive=False)
        (last_offset, last_flag), event = read_back(cell_offsets[-1:], cell_flags[-1:]) if len(cell_flags) else \
            ((None, None), None)
    yield event
    with wp.ScopedDevice(device):
        ncells = int(last_offset.numpy()[0] + last_flag.numpy()[0]) if len(cell_flags) else 0
        if ncells == 0:
            return _empty_preview(velocities is not None, scalar is not None)
        corner = wp.array(np.asarray(IsoSurfaceMarchingCubes.CUBE_CORNER_OFFSETS, np.int32).reshape(8, 3),
                          dtype=wp.vec3i, device=device)
        cells = wp.empty(ncells, dtype=wp.vec3i, device=device)
        corner_values = wp.empty((ncells, 8), dtype=float, device=device)
        wp.launch(K.gather_cells, len(cell_flags), device=device,
                  inputs=[cell_flags, cell_offsets, values, blocks, dims_v, B, corner, cells, corner_values])
        vertices, indices = sparse_marching_cubes_from_cells(cells, corner_values, origin=lower_v, cell_width=cell,
                                                             threshold=iso, device=device)
        nv, nf = len(vertices), len(indices) // 3
        if options.smoothing_iters and nf:
            counts = wp.zeros(nv, dtype=wp.int32, device=device)
            wp.launch(K.count_neighbours, nf, inputs=[indices, counts], device=device)
            sums = wp.empty(nv, dtype=wp.vec3, device=device)
            for step in range(int(options.smoothing_iters)):
                sums.zero_()
                wp.launch(K.sum_neighbours, nf, inputs=[vertices, indices, sums], device=device)
                wp.launch(K.relax, nv, inputs=[vertices, sums, counts, TAUBIN[step % 2]], device=device)
        v = velocities if velocities is not None else wp.empty(0, dtype=wp.vec3, device=device)
        s = scalar if scalar is not None else wp.empty(0, dtype=float, device=device)
        normals = wp.zeros(nv, dtype=wp.vec3, device=device)
        vertex_v = wp.zeros(nv if velocities is not None else 0, dtype=wp.vec3, device=device)
        vertex_s = wp.zeros(nv if scalar is not None else 0, dtype=float, device=device)
        wp.launch(K.vertex_attributes, nv, device=device,
                  inputs=[vertices, grid.id, x, v, s, support, volumes, normals, vertex_v, vertex_s])
        signed = wp.zeros(1, dtype=float, device=device)
        wp.launch(K.signed_volume, nf, inputs=[vertices, indices, signed], device=device)
        (host_signed,), event = read_back(signed)
    yield event
    with wp.ScopedDevice(device):
        if host_signed.numpy()[0] < 0:  # outward: counter-clockwise seen from outside
            wp.launch(K.reverse_faces, nf, inputs=[indices], device=device)
        if walls is not None:
            wp.launch(K.clamp_points, nv, inputs=[vertices, wp.vec3(*walls[0]), wp.vec3(*walls[1])], device=device)
        (points, faces, vertex_normals, *attributes), pending = read_back(
            vertices, indices, normals, *([vertex_v] if velocities is not None else []),
            *([vertex_s] if scalar is not None else []))
        mesh = SurfaceMesh(points.numpy(), faces.numpy().reshape(-1, 3), vertex_normals.numpy())
        if velocities is not None:
            mesh.velocities = attributes.pop(0).numpy()
        if scalar is not None:
            mesh.primvars["vorticity_magnitude"] = attributes.pop(0).numpy()
        mesh.pending = pending
    return mesh


TAUBIN = (0.5, -0.53)  # lambda and mu of Taubin's smoothing (mu < -lambda: no shrinking)


BEHIND = ("wait", "skip")


class BackgroundMesher:
    """Meshes every ``every``-th frame in the background (``warpsph run --surface``): a thread per worker of
    the mesh function (``mesh.workers``, default 1), each waiting on its frame's mesh.

    The writer hands it a frame's host arrays after writing the particles (:meth:`submit`) and
    writes the meshes that are done (:meth:`ready`) into the frames they belong to. One frame waits
    while one is meshed (``depth``): when the mesher is behind, ``behind="wait"`` blocks the writer
    (and so, after the writer's few buffer sets, the simulation) and every asked frame gets its
    mesh; ``behind="skip"`` drops the frame (listed in ``skipped``) and the simulation never waits
    for meshing. ``mesh(arrays)`` returns a :class:`SurfaceMesh`."""

    def __init__(self, mesh, every=1, behind="wait", depth=1):
        import queue
        import threading

        self.mesh, self.every, self.behind = mesh, max(1, int(every)), behind
        self.workers = max(1, int(getattr(mesh, "workers", 1)))  # frames meshed at once
        self._lock = threading.Lock()
        self.jobs = queue.Queue(maxsize=max(1, depth))
        self.results = queue.Queue()
        self.skipped = []
        self.meshed = 0
        self.seconds = 0.0  # meshing time (on the mesher's thread)
        self.waited = 0.0  # time the writer waited for a free place in the queue
        self.error = None  # (frame, exception)
        self._threads = [threading.Thread(target=self._loop, name=f"warpsph-mesher-{n}", daemon=True)
                         for n in range(self.workers)]
        for thread in self._threads:
            thread.start()

    def wants(self, frame):
        return frame % self.every == 0

    @property
    def clip(self):
        """The :class:`SurfaceClip` the meshes are clipped to (the mesh function's), or None."""
        return getattr(self.mesh, "clip", None)

    def _loop(self):
        while True:
            job = self.jobs.get()
            if job is None:
                return
            frame, arrays = job
            if self.error is not None:
                continue
            try:
                mesh = self.mesh(arrays)
                with self._lock:
                    self.seconds += mesh.seconds
                self.results.put((frame, mesh))
            except BaseException as exc:  # raised on the writer's thread by the next submit or ready
                self.error = (frame, exc)

    def check(self):
        if self.error is not None:
            frame, exc = self.error
            raise RuntimeError(f"surface mesh of frame {frame}: {exc}") from exc

    def submit(self, frame, arrays):
        """Queues frame ``frame`` (``arrays``: x, v, vorticity, not reused by the caller, and where the
        cache has one the frame's own layer, ``layer`` (path, frame), which a mesh function may write the
        mesh into itself, as :class:`ProcessMesher` does); False when it is skipped (``behind="skip"``
        and the mesher busy)."""
        import queue

        self.check()
        if self.behind == "skip":
            try:
                self.jobs.put_nowait((frame, arrays))
            except queue.Full:
                self.skipped.append(frame)
                return False
            return True
        start = time.perf_counter()
        self.jobs.put((frame, arrays))
        self.waited += time.perf_counter() - start
        return True

    def ready(self):
        """The (frame, mesh) pairs done since the last call."""
        import queue

        done = []
        while True:
            try:
                done.append(self.results.get_nowait())
            except queue.Empty:
                break
        self.meshed += len(done)
        self.check()
        return done

    def close(self):
        """Meshes what is queued, stops the thread (and the mesh function's worker) and returns the last
        (frame, mesh) pairs."""
        if self._threads:
            for _ in self._threads:
                self.jobs.put(None)
            for thread in self._threads:
                thread.join()
            self._threads = []
            close = getattr(self.mesh, "close", None)
            if close is not None:
                close()
        return self.ready()

    def note(self, options):
        """The ``warpsph:surface`` metadata of the cache."""
        text = (f"/World/FluidSurface: {options.method} mesh of every {self.every}-th frame" if self.every > 1
                else f"/World/FluidSurface: {options.method} mesh of every frame")
        if self.every > 1 or self.skipped:
            text += "; a frame without its own mesh holds the mesh of the last meshed frame before it"
        if self.skipped:
            text += (f"; {len(self.skipped)} frames were skipped because the mesher was behind the simulation "
                     f"(--surface-behind skip): re-mesh them with warpsph surface")
        clip = self.clip
        return {"method": options.method, "every": self.every, "behind": self.behind, "workers": self.workers,
                "meshed": self.meshed,
                "skipped": len(self.skipped), "skipped_frames": list(self.skipped), "cube": float(options.cube),
                "smoothing": float(options.smoothing), "iso": float(options.threshold),
                "clipped": clip.describe() if clip is not None else "nothing", "note": text}


@dataclass
class _MeshJob:
    """The device mesher's mesh in flight: its frame, its stages (:func:`preview_stages`), the event its next stage
    waits for (None: none) and the seconds its stages took on the simulation's thread so far."""

    frame: int
    stages: object
    event: object = None
    seconds: float = 0.0


class DeviceMesher:
    """The preview meshes of a run on a GPU (``warpsph run --surface`` on cuda), made on the simulation's own
    device from a copy of the frame's device arrays (nothing goes through the host but the mesh), on a stream of
    its own, its stages launched by the simulation's thread between the following steps as their numbers come back
    (:meth:`mesh_now`, :meth:`advance`; it never waits but for the last frame's mesh at the next frame), clipped
    and written by the writer's thread. The interface of
    :class:`BackgroundMesher`: the writer hands it each frame (:meth:`submit`) and writes the meshes that are
    done (:meth:`ready`). It is never behind: no frame waits or is skipped.

    A mesher process of its own (:class:`ProcessMesher`) had a CUDA context of its own, which the GPU time-slices
    with the simulation's: on the 1M dam break (H100, 25 frames) the run's wall grew by 25-31 %.

    In a --clips cache (a frame with its ``layer``), a process of its own writes the mesh into the frame's layer
    (:func:`_write_layer_in_worker`, the arrays through files as :class:`ProcessMesher`'s): pxr's layer save holds
    the GIL for its whole length, which the simulation's host thread needs every step."""

    def __init__(self, options, radius, clip=None, every=1):
        import threading

        self.pool = self.folder = None  # the layer writer's process, started by the first frame with a layer
        self._writing = []  # (frame, future, its folder) of the meshes being written into their layers
        self._jobs = 0
        self.options, self.radius, self.clip, self.every = options, float(radius), clip, max(1, int(every))
        # what each frame is clipped to: the walls on the device (mesh_now), the bodies on the writer's (submit), by
        # clip_mesh as on the CPU (its walls again: a no-op but where a body pushed a vertex through them)
        self._walls = wall_bounds(clip) if clip is not None and clip.walled else None
        self._bodies = SurfaceClip(clip.lo, clip.hi, clip.bodies) if clip is not None and clip.bodies else None
        self.behind, self.workers = "wait", 1
        self.skipped, self.meshed, self.seconds, self.waited = [], 0, 0.0, 0.0
        self.error = None  # (frame, exception)
        self._lock = threading.Lock()
        self._made_changed = threading.Condition(self._lock)
        self._made = {}  # frame -> its mesh, made and not yet handed over by the writer
        self._done = []
        self._stream = None  # the meshes' own stream (on a GPU)
        self._job = None  # the mesh in flight (:class:`_MeshJob`)
        self._owner = None  # the simulation's thread, which alone launches

    wants = BackgroundMesher.wants
    check = BackgroundMesher.check
    note = BackgroundMesher.note

    def mesh_now(self, sim, frame):
        """Starts meshing frame ``frame`` of ``sim`` (one device) if it is one to mesh, after finishing the last
        frame's mesh: a copy of the particles on the simulation's stream, then the stages of
        :func:`preview_stages` on a stream of their own, each launched as soon as the numbers it reads back are
        there (:meth:`advance`, after each step: the simulation never waits for them). A failure is raised on the
        writer's thread (:meth:`submit`), as a mesher thread's is."""
        self.finish()
        if not self.wants(frame) or self.error is not None:
            return
        import threading

        import warp as wp

        from .kernels import surface_preview as K

        start = time.perf_counter()
        try:
            n = sim.num_fluid
            fluid, fields = sim.fluid, sim.fields()
            x, v = wp.clone(fluid.x[:n]), wp.clone(fluid.v[:n])  # the frame's particles, on the simulation's stream
            scalar = None
            if "vorticity" in fields:
                scalar = wp.empty(n, dtype=float, device=sim.device)
                wp.launch(K.magnitudes, n, inputs=[fields["vorticity"][:n], scalar], device=sim.device)
            if self._stream is None:
                self._stream = wp.Stream(sim.device) if sim.device.is_cuda else None
            self._owner = threading.get_ident()
            self._job = _MeshJob(frame, preview_stages(x, self.radius, v, scalar, self.options, self._walls),
                                 seconds=time.perf_counter() - start)
            self._resume(first=True)
        except Exception as exc:
            self._fail(frame, exc)
            return
        self.advance()

    def advance(self, sim=None):
        """Launches the current mesh's next stages whose numbers are back (``on_step`` of a run; no waiting)."""
        while self._job is not None and (self._job.event is None or self._job.event.is_complete):
            self._resume()

    def finish(self):
        """Runs the current mesh's stages to the end, waiting for each (the next frame's mesh, the run's end)."""
        import warp as wp

        while self._job is not None:
            if self._job.event is not None:
                wp.synchronize_event(self._job.event)
            self._resume()

    def _resume(self, first=False):
        """The current mesh's next stage, on the mesher's stream (the first waits for the simulation's stream: the
        copy of the particles)."""
        import warp as wp

        job = self._job
        start = time.perf_counter()
        try:
            if self._stream is None:
                job.event = next(job.stages)
            else:
                with wp.ScopedStream(self._stream, sync_enter=first):
                    job.event = next(job.stages)
            job.seconds += time.perf_counter() - start
        except StopIteration as done:
            mesh = done.value
            mesh.seconds = job.seconds + time.perf_counter() - start
            self._job = None
            with self._made_changed:
                self._made[job.frame] = mesh
                self._made_changed.notify_all()
        except Exception as exc:
            self._job = None
            self._fail(job.frame, exc)

    def _fail(self, frame, exc):
        with self._made_changed:
            self.error = (frame, exc)
            self._made_changed.notify_all()

    def submit(self, frame, arrays):
        """The mesh of frame ``frame`` (started by :meth:`mesh_now`), clipped to the moving bodies at the frame's
        ``arrays["poses"]``, is done, once the simulation's thread has made it; False when it was not made."""
        import threading

        if self._owner == threading.get_ident():
            self.finish()  # called on the simulation's thread (the API's writer on the calling thread)
        with self._made_changed:
            while frame not in self._made and self.error is None and self._job is not None and self._job.frame == frame:
                self._made_changed.wait(0.05)
        self.check()
        with self._lock:
            mesh = self._made.pop(frame, None)
        if mesh is None:
            return False
        start = time.perf_counter()
        mesh.wait()
        if self._bodies is not None:  # the walls were clamped on the device
            clip_mesh(mesh, self._bodies, arrays.get("poses"), self.radius)
        mesh.seconds += time.perf_counter() - start
        if arrays.get("layer") is not None:
            self._write_in_layer(frame, mesh, arrays["layer"])
            return True
        with self._lock:
            self.seconds += mesh.seconds
            self._done.append((frame, mesh))
        return True

    def _write_in_layer(self, frame, mesh, layer):
        import os

        if self.pool is None:
            self.folder, self._remove_folder, self.pool = start_workers(self, 1, prefix="warpsph-mesh")
        job = os.path.join(self.folder, str(self._jobs))
        self._jobs += 1
        os.mkdir(job)
        future = self.pool.submit(_write_layer_in_worker, _store_mesh(mesh, job), layer)
        with self._lock:
            self._writing.append((frame, future, job))

    def ready(self, wait=False):
        """The (frame, mesh) pairs done since the last call (``wait``: with every mesh still being written)."""
        import shutil

        with self._lock:
            done, self._done = self._done, []
            writing, self._writing = self._writing, []
        for frame, future, job in writing:
            if not (wait or future.done()):
                with self._lock:
                    self._writing.append((frame, future, job))
                continue
            try:
                mesh = future.result()
                with self._lock:
                    self.seconds += mesh.seconds
                done.append((frame, mesh))
            except BaseException as exc:
                if self.error is None:
                    self.error = (frame, exc)
            finally:
                shutil.rmtree(job, ignore_errors=True)
        self.meshed += len(done)
        self.check()
        return done

    def close(self):
        """Waits for the meshes still being written into their layers; stops the layer writer's process."""
        try:
            return self.ready(wait=True)
        finally:
            if self.pool is not None:
                stop_workers(self.pool, self._remove_folder)
                self.pool = None


class ProcessMesher:
    """``mesh(arrays)`` of a run (``warpsph run --surface``), computed in a child process of its own.

    pysplashsurf holds the GIL through most of its pipeline (a Python thread beside a 512K-particle
    reconstruction ran at 1 % of its speed), so a mesher thread stopped the simulation's host thread
    while it meshed: the 1M dam break ran 2.8x slower with --surface although it never waited for the
    writer. A spawned process has its own GIL and, for the preview, its own Warp device state (Warp's
    current device and stream are process-wide, not per thread). ``workers`` processes mesh frames at
    once (default: one per 4 cores beyond two, at most 4), each on its share of the cores.

    The arrays go through files in a folder of its own (``folder``, in /dev/shm where there is one;
    :mod:`warpsph.io.processes`). Each frame's files are removed when its mesh is back or its worker failed; :meth:`close` (or the
    end of the process) removes the folder. An array whose file cannot be written (a full /dev/shm)
    goes by pickle. With ``arrays["layer"]`` (a --clips frame layer and its frame) the worker writes the
    mesh into that layer itself and returns it without its arrays (``layer`` set): the main process then
    neither reads the mesh nor writes it into USD."""

    def __init__(self, options, radius, device="cpu", workers=None, clip=None):
        import os
        from itertools import count

        self.options, self.radius, self.device = options, radius, str(device)
        self.clip = clip  # goes to each worker once (its initializer), a moving body's pose with each frame
        cores = os.cpu_count() or 1
        # splashsurf scales poorly past a few threads (1M particles on 16 cores: 1.78 s a mesh, 2.17 s on 6): several
        # frames at once on 4 threads each mesh more per second than one on all; the preview runs on the device
        spare = 2 if cores > 4 else 0  # the simulation's host thread and the writer keep a core each
        if workers is None:
            workers = 1 if options.method == "preview" else max(1, min(4, (cores - spare) // 4))
        self.workers = max(1, int(workers))
        self._jobs = count()
        self.folder, self._remove_folder, self.pool = start_workers(
            self, self.workers, max(1, (cores - spare) // self.workers), _set_worker_clip, (clip,), "warpsph-mesh")
        self.worker_pid = None

    def __call__(self, arrays):
        import os
        import shutil

        job = os.path.join(self.folder, str(next(self._jobs)))  # a frame's files: its arrays, then its mesh
        os.mkdir(job)
        try:
            points, velocities, vorticity = (store(os.path.join(job, name), arrays.get(name))
                                             for name in ("x", "v", "vorticity"))
            future = self.pool.submit(_mesh_in_worker, points, self.radius, velocities, vorticity, self.options,
                                      self.device, job, arrays.get("layer"), arrays.get("poses"))
            mesh, self.worker_pid = future.result()
            return _load_mesh(mesh)
        finally:  # done, failed in the worker, or the worker died: nothing of the frame stays
            shutil.rmtree(job, ignore_errors=True)

    def close(self):
        stop_workers(self.pool, self._remove_folder)


_worker_clip = None  # a mesher worker's SurfaceClip (:func:`_set_worker_clip`)


def _set_worker_clip(clip):
    """A mesher worker's :class:`SurfaceClip`, once (not with every frame)."""
    global _worker_clip
    _worker_clip = clip


def _mesh_in_worker(points, radius, velocities, vorticity, options, device, folder=None, layer=None, poses=None):
    """A frame's mesh in a worker, clipped to the worker's clip (the moving bodies at ``poses``): arrays as
    :func:`~warpsph.io.processes.store` left them; the mesh stored in ``folder`` (None: by pickle), or, with ``layer`` (path,
    frame), written into that USD layer and returned without its arrays."""
    import os

    mesh = mesh_frame(load(points), radius, load(velocities), load(vorticity), options, device, _worker_clip, poses)
    if layer is not None:
        return _write_layer(mesh, layer), os.getpid()
    return (mesh if folder is None else _store_mesh(mesh, folder)), os.getpid()


def _write_layer(mesh, layer):
    """``mesh`` written into the --clips frame layer ``layer`` (path, frame); the mesh without its arrays back."""
    from .io.usd import write_surface_layer

    path, frame = layer
    start = time.perf_counter()
    write_surface_layer(path, frame, mesh)
    written = SurfaceMesh.empty(mesh.velocities is not None)
    written.seconds, written.layer = mesh.seconds + time.perf_counter() - start, str(path)
    return written


def _write_layer_in_worker(mesh, layer):
    """A device mesher's frame (arrays as :func:`_store_mesh` left them) written into its frame layer."""
    return _write_layer(_load_mesh(mesh), layer)


def _store_mesh(mesh, folder):
    """``mesh`` with its arrays stored in ``folder`` (:func:`warpsph.io.processes.store_tree`)."""
    return store_tree(mesh, folder)


def _load_mesh(mesh):
    """A mesh from :func:`_store_mesh` with its arrays read back (the files stay: the caller removes them)."""
    return load_tree(mesh)


def mesher_for(options, radius, device="cpu", workers=None, clip=None):
    """The ``mesh(arrays)`` of a run: a :class:`ProcessMesher`, splashsurf on the host's cores or the preview
    on ``device`` (the run's: the worker process has its own CUDA context and streams), its meshes clipped
    to ``clip`` (:func:`surface_clip` of the scene's domain and bodies; None: not clipped)."""
    return ProcessMesher(options, radius, device, workers, clip=clip)


def mesh_frame(points, radius, velocities=None, vorticity=None, options=SurfaceOptions(), device="cpu", clip=None,
               poses=None):
    """One frame's mesh with ``options.method``, clipped to ``clip`` (a :class:`SurfaceClip`: the domain's
    walls and the bodies, the moving ones at ``poses``; None: not clipped) by :func:`clip_mesh`.

    Example:

    ```python
    import numpy as np
    from warpsph.surface import SurfaceClip, SurfaceOptions, mesh_frame

    r = 0.01  # particles 2r apart in a ball of radius 0.1 m
    g = np.mgrid[-0.1:0.1:2 * r, -0.1:0.1:2 * r, -0.1:0.1:2 * r].reshape(3, -1).T
    points = g[(g ** 2).sum(axis=1) < 0.1 ** 2].astype(np.float32)
    floor = SurfaceClip(lo=(-np.inf, -0.05, -np.inf))  # a wall at y = -0.05
    mesh = mesh_frame(points, r, options=SurfaceOptions(method="preview"), clip=floor)
    assert mesh.points[:, 1].min() >= -0.05
    ```
    """
    if options.method == "preview":
        mesh = reconstruct_preview(points, radius, velocities, vorticity, options, device)
    else:
        mesh = reconstruct(points, radius, velocities, vorticity, options)
    if clip is not None:
        start = time.perf_counter()
        clip_mesh(mesh, clip, poses, radius)
        mesh.seconds += time.perf_counter() - start
    return mesh


def mesh_volume(points, faces):
    """The signed volume a closed, outward-oriented triangle mesh encloses (divergence theorem).

    Example:

    ```python
    import numpy as np
    from warpsph.surface import mesh_volume

    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward
    assert abs(mesh_volume(corners, faces) - 1 / 6) < 1e-6
    ```
    """
    p = np.asarray(points, np.float64)
    a, b, c = (p[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def boundary_edges(faces):
    """The number of edges used by one face only (0 for a closed mesh)."""
    f = np.asarray(faces, np.int64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


# ---------------------------------------------------------------------------------------------
# warpsph surface CACHE: re-mesh a finished run without simulating it again


def _sibling_usd(h5_path):
    """The USD cache beside OUT.particles.h5 (OUT.usdc, .usda or .usd), or None."""
    from pathlib import Path

    h5_path = Path(h5_path)
    stem = h5_path.name[: -len(".particles.h5")] if h5_path.name.endswith(".particles.h5") else h5_path.stem
    for suffix in (".usdc", ".usda", ".usd"):
        candidate = h5_path.with_name(stem + suffix)
        if candidate.is_file():
            return candidate
    return None


class UsdFrames:
    """The particle frames of a USD point cache (single file or the top-level file of --clips).

    Example:

    ```python
    import warpsph
    from warpsph.surface import UsdFrames

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    with warpsph.io.UsdWriter("out/dam_break.usdc", sim) as usd:
        sim.run(frames=2, on_frame=usd)
    frames = UsdFrames("out/dam_break.usdc")
    print(frames.frames, frames.fps, frames.radius)
    points, velocities, vorticity = frames.read(1)
    ```
    """

    def __init__(self, path):
        from pxr import Usd

        self.path = path
        try:
            self.stage = Usd.Stage.Open(str(path))
        except Exception:
            self.stage = None
        prim = self.stage.GetPrimAtPath("/World/Fluid") if self.stage is not None else None
        if prim is None or not prim.IsValid() or not prim.GetAttribute("points").GetTimeSamples():
            raise SceneError(path, "", "not a warpsph point cache (no time-sampled /World/Fluid points) "
                                       "nor a --particles-h5 file")
        self.prim = prim
        self.frames = [int(round(t)) for t in prim.GetAttribute("points").GetTimeSamples()]
        self.fps = self.stage.GetTimeCodesPerSecond()
        widths = prim.GetAttribute("widths")
        value = widths.Get(self.frames[0]) if widths else None
        self.radius = float(value[0]) / 2.0 if value is not None and len(value) else None
        self.usd = path
        self.clip, self.has_domain = stage_clip(self.stage)

    def poses(self, frame):
        """{name: (position, rotation)} of the moving bodies at ``frame`` (None without any)."""
        return stage_poses(self.stage, self.clip, frame)

    def read(self, frame):
        """(points, velocities or None, vorticity magnitude or None) of ``frame``."""
        get = lambda name: self.prim.GetAttribute(name).Get(frame) if self.prim.GetAttribute(name) else None  # noqa: E731
        points = np.asarray(get("points"), np.float32)
        velocities, vorticity = get("velocities"), get("primvars:vorticity_magnitude")
        if vorticity is None:
            vorticity = get("primvars:vorticity")
        return (points, None if velocities is None else np.asarray(velocities, np.float32),
                None if vorticity is None else np.asarray(vorticity, np.float32))


class H5Frames:
    """The particle frames of a ``--particles-h5`` file (x, v and vorticity per frame).

    Example:

    ```python
    import warpsph
    from warpsph.io.particles_h5 import ParticleFrames
    from warpsph.surface import H5Frames

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    h5 = ParticleFrames("dam_break.particles.h5")
    sim.run(frames=2, on_frame=h5)
    h5.close()
    x, v, vorticity = H5Frames("dam_break.particles.h5").read(2)
    ```
    """

    def __init__(self, path):
        import h5py

        self.path = path
        self.file = h5py.File(path, "r")
        self.group = self.file["frames"]
        self.frames = sorted(int(name) for name in self.group)
        if not self.frames:
            raise SceneError(path, "", "holds no frames")
        self.usd = _sibling_usd(path)
        self.radius, self.fps = None, None
        self.clip, self.has_domain, self._cache = None, False, None  # the walls and bodies: in the USD cache
        if self.usd is not None:
            try:
                cache = UsdFrames(self.usd)
                self.radius, self.fps = cache.radius, cache.fps
                self.clip, self.has_domain, self._cache = cache.clip, cache.has_domain, cache
            except SceneError:
                self.usd = None
        if self.fps is None:
            last = self.group[f"{self.frames[-1]:06d}"]
            t = float(last.attrs.get("time", 0.0))
            self.fps = self.frames[-1] / t if t > 0 else 25.0

    def poses(self, frame):
        """{name: (position, rotation)} of the moving bodies at ``frame``, from the USD cache beside (None)."""
        return self._cache.poses(frame) if self._cache is not None else None

    def read(self, frame):
        """(points, velocities or None, vorticity or None) of ``frame``."""
        g = self.group[f"{frame:06d}"]
        return (g["x"][...], g["v"][...] if "v" in g else None, g["vorticity"][...] if "vorticity" in g else None)


DOMAIN = "warpsph:domain"  # customLayerData of a cache: the scene's domain (min, max, periodic, walls)


def stage_clip(stage):
    """(:class:`SurfaceClip` or None, whether the cache recorded its domain) of a cache's stage: the
    domain's walled faces from the root layer's ``warpsph:domain`` (written by warpsph since #42; an
    older cache has none, and its meshes are clipped to its bodies only) and the closed meshes under
    /World/Bodies (a moving one in body space, with time-sampled ``xformOp``s)."""
    from pxr import UsdGeom

    data = stage.GetRootLayer().customLayerData.get(DOMAIN) if stage is not None else None
    domain = None
    if data:
        from types import SimpleNamespace

        domain = SimpleNamespace(min=list(data["min"]), max=list(data["max"]), periodic=tuple(str(data["periodic"])),
                                 walls=bool(data["walls"]))
    bodies = []
    root = stage.GetPrimAtPath("/World/Bodies") if stage is not None else None
    for prim in root.GetChildren() if root is not None and root.IsValid() else ():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        points, indices = mesh.GetPointsAttr().Get(), mesh.GetFaceVertexIndicesAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        if points is None or indices is None or counts is None or not np.all(np.asarray(counts) == 3):
            continue
        moving = bool(UsdGeom.Xformable(prim).GetOrderedXformOps())
        bodies.append((prim.GetName(), np.asarray(points, np.float64), np.asarray(indices, np.int32).reshape(-1, 3),
                       moving))
    return surface_clip(domain, bodies), domain is not None


def stage_poses(stage, clip, frame):
    """{name: (position, rotation)} of the moving bodies of ``clip`` at ``frame`` in ``stage`` (their
    transforms; world = rotation @ body + position), None without moving bodies."""
    from pxr import Usd, UsdGeom

    moving = [b.name for b in clip.bodies if b.moving] if clip is not None else []
    if not moving:
        return None
    poses = {}
    for name in moving:
        matrix = UsdGeom.Xformable(stage.GetPrimAtPath(f"/World/Bodies/{name}")).ComputeLocalToWorldTransform(
            Usd.TimeCode(frame))
        m = np.array(matrix, np.float64).reshape(4, 4)  # row vectors: world = body @ m[:3, :3] + m[3, :3]
        poses[name] = (m[3, :3].copy(), m[:3, :3].T.copy())
    return poses


def open_frames(path):
    """The frames of a USD cache or of a ``--particles-h5`` file; :class:`SceneError` otherwise.

    Example:

    ```python
    import warpsph
    from warpsph.surface import open_frames

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    with warpsph.io.UsdWriter("out/dam_break.usdc", sim) as usd:
        sim.run(frames=2, on_frame=usd)
    frames = open_frames("out/dam_break.usdc")  # or OUT.particles.h5
    points, velocities, vorticity = frames.read(2)
    ```
    """
    from pathlib import Path

    from .io.particles_h5 import is_particles_h5

    path = Path(path)
    if not path.is_file():
        raise SceneError(path, "", "no such file (expected a warpsph USD cache or OUT.particles.h5)")
    if is_particles_h5(path):
        return H5Frames(path)
    return UsdFrames(path)


def default_output(path):
    """CACHE.surface.usdc beside the cache (OUT.particles.h5 -> OUT.surface.usdc)."""
    from pathlib import Path

    path = Path(path)
    stem = path.name[: -len(".particles.h5")] if path.name.endswith(".particles.h5") else path.stem
    return path.with_name(stem + ".surface.usdc")


def plan_remesh(cache, frames=None, out=None, radius=None, overwrite=False, options=SurfaceOptions()):
    """Checks everything before anything is written: returns (source, frame list, output path,
    radius). Raises :class:`SceneError` naming the option at fault.

    Example:

    ```python
    import warpsph
    from warpsph.surface import plan_remesh

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    with warpsph.io.UsdWriter("out/dam_break.usdc", sim) as usd:
        sim.run(frames=2, on_frame=usd)
    source, frames, out, radius = plan_remesh("out/dam_break.usdc")  # all frames, beside the cache
    print(frames, out, radius)  # [0, 1, 2] out/dam_break.surface.usdc ...
    ```
    """
    import os
    from pathlib import Path

    from .io.usd import written_by_warpsph

    options.check("--")
    if options.method == "splashsurf":
        require_pysplashsurf("surface")
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise SceneError("", "--radius", f"expected a particle radius > 0 in metres, got {radius}")
    source = open_frames(cache)
    if frames is not None:
        first, last = frames
        known = set(source.frames)
        if first > last or first not in known or last not in known:
            raise SceneError(cache, "--frames", f"unknown frame range {first}..{last}; the cache holds frames "
                                                f"{source.frames[0]}..{source.frames[-1]}")
        chosen = [f for f in source.frames if first <= f <= last]
    else:
        chosen = list(source.frames)
    radius = radius if radius is not None else source.radius
    if radius is None:
        raise SceneError(cache, "--radius", "the particle radius is not in this file (no widths, no OUT.usdc "
                                            "beside it): pass --radius R in metres")
    out = Path(out) if out is not None else default_output(cache)
    if out.suffix.lower() not in (".usdc", ".usda", ".usd"):
        raise SceneError(out, "--out", "expected a file name ending in .usdc, .usda or .usd")
    if out.resolve() == Path(cache).resolve() or (source.usd is not None and out.resolve() == Path(source.usd).resolve()):
        raise SceneError(out, "--out", "is the input cache; the mesh goes into a new file (it sublayers the input)")
    if out.is_dir():
        raise SceneError(out, "--out", "is a directory")
    if out.exists():
        if not written_by_warpsph(out):
            raise SceneError(out, "--out", "exists and was not written by warpsph: refusing to replace it")
        if not overwrite:
            raise SceneError(out, "--out", "exists; pass --overwrite to replace it, or choose another --out")
    parent = out.absolute().parent
    if parent.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise SceneError(out, "--out", f"cannot write in {parent}")
    return source, chosen, out, radius


def remesh(source, frames, out, radius, options=SurfaceOptions(), log=None, device="cpu", clip="cache"):
    """Meshes ``frames`` of ``source`` (:func:`open_frames`) into the new layer ``out``: stage
    metadata of the cache, the cache itself as a sublayer (so ``out`` shows the particles and the
    surface), and ``/World/FluidSurface``, clipped to ``clip`` ("cache": the walls and bodies the cache
    records, ``source.clip``; a :class:`SurfaceClip`; None: not clipped). Written as OUT.partial, which
    grows by crash-consistent saves (:class:`warpsph.io.usd.GrowingLayer`; a kill or a full disk leaves OUT.partial
    with the frames of the last save, and ``out`` as it was) after a frame while a save
    costs at most ``FLUSH_SHARE`` of the time since the last, and renamed to ``out`` at the end or when stopped.
    Returns {"frames", "seconds" (meshing), "vertices", "triangles", "clipped" (what the meshes were clipped to)}.

    Example:

    ```python
    import warpsph
    from warpsph.surface import SurfaceOptions, plan_remesh, remesh

    sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
    with warpsph.io.UsdWriter("out/dam_break.usdc", sim) as usd:
        sim.run(frames=2, on_frame=usd)
    source, frames, out, radius = plan_remesh("out/dam_break.usdc", frames=[1, 2])
    print(remesh(source, frames, out, radius, options=SurfaceOptions(method="preview")))  # what `warpsph surface` runs
    ```
    """
    import os
    import time

    from pxr import Usd, UsdGeom

    from .io.usd import (FLUSH_SHARE, GrowingLayer, _mark, _set_stage_metadata, remove_leftovers, save_layer,
                         write_surface)

    partial = out.with_name(out.stem + ".partial" + out.suffix)
    remove_leftovers(partial)
    if partial.exists():
        partial.unlink()
    up = "Y"
    if source.usd is not None:
        base = Usd.Stage.Open(str(source.usd))
        up = "Z" if UsdGeom.GetStageUpAxis(base) == UsdGeom.Tokens.z else "Y"
    stage = Usd.Stage.CreateInMemory()  # the file appears at the first save, whole and marked
    _mark(stage.GetRootLayer())
    _set_stage_metadata(stage, source.fps, up)
    stage.SetStartTimeCode(frames[0])
    stage.SetEndTimeCode(frames[-1])
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    save_layer(stage.GetRootLayer(), partial)
    grown = GrowingLayer(partial)  # each save appends the frames since the last; memory stays at one frame
    layer = grown.layer
    stage = Usd.Stage.Open(layer)
    if source.usd is not None:  # a path relative to the file (an in-memory layer would resolve it elsewhere)
        layer.subLayerPaths.append(os.path.relpath(os.path.abspath(source.usd), os.path.abspath(out.parent)))
    saved = [0.0, 0.0]  # (start, seconds) of the last save

    def save(again=True):
        start = time.perf_counter()
        if grown.save(again):
            saved[:] = [start, time.perf_counter() - start]
    if isinstance(clip, str):
        clip = getattr(source, "clip", None)
        if log is not None and source.usd is not None and not getattr(source, "has_domain", False):
            log(f"{source.usd} does not record its domain (written before warpsph:domain): the meshes are not "
                f"clipped to its walls" + (f", only to its {len(clip.bodies)} bodies" if clip is not None else ""))
    if log is not None and clip is not None:
        log(f"the meshes are clipped to {clip.describe()}")
    done = {"frames": 0, "seconds": 0.0, "vertices": 0, "triangles": 0,
            "clipped": clip.describe() if clip is not None else "nothing"}
    try:
        for frame in frames:
            points, velocities, vorticity = source.read(frame)
            bad = int((~np.isfinite(np.asarray(points)).all(axis=1)).sum())
            if bad:
                raise SceneError(getattr(source, "path", source.usd), "--frames", f"{bad} of the {len(points)} particle positions of "
                                 f"frame {frame} are NaN or infinite (an unstable run's frame): mesh the frames before it"
                                 + (f" (--frames {frames[0]} {frame - 1}; those done are kept)" if frame > frames[0] else ""))
            poses = source.poses(frame) if clip is not None and hasattr(source, "poses") else None
            mesh = mesh_frame(points, radius, velocities, vorticity, options, device, clip, poses)
            write_surface(stage, frame, mesh)
            if time.perf_counter() - saved[0] >= saved[1] / FLUSH_SHARE:
                save()
            done["frames"] += 1
            done["seconds"] += mesh.seconds
            done["vertices"] += len(mesh.points)
            done["triangles"] += len(mesh.faces)
            if log is not None:
                log(f"frame {frame}: {len(points)} particles -> {len(mesh.points)} vertices, {len(mesh.faces)} triangles "
                    f"in {mesh.seconds:.2f} s")
    finally:
        try:
            save(again=False)  # a failed save raises here: OUT.partial keeps the frames of the save before
        finally:
            grown.close()
        del stage
        if done["frames"]:
            os.replace(partial, out)
            fsync(out.parent)
        elif partial.exists():
            partial.unlink()
    return done


# ---------------------------------------------------------------------------------------------
# mesh quality (#42): the numbers that compare the surface methods side by side


SLIVER_DEGREES = 10.0  # a face whose smallest angle is below this is a sliver


def _mesh_arrays(mesh):
    """(vertices (V, 3) float64, faces (F, 3) int64) of a :class:`SurfaceMesh`, a trimesh or a (points, faces) pair."""
    if isinstance(mesh, tuple):
        points, faces = mesh
    else:
        points, faces = (mesh.points if hasattr(mesh, "points") else mesh.vertices), mesh.faces
    return np.asarray(points, np.float64).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3)


def face_min_angles(points, faces):
    """The smallest interior angle of each triangle [degrees]; 0 for a degenerate one (a repeated corner)."""
    p = np.asarray(points, np.float64)
    corners = [p[faces[:, k]] for k in range(3)]
    angles = []
    for k in range(3):
        u, v = corners[(k + 1) % 3] - corners[k], corners[(k + 2) % 3] - corners[k]
        norms = np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1)
        cos = np.divide(np.einsum("ij,ij->i", u, v), norms, out=np.ones(len(u)), where=norms > 0)
        angles.append(np.where(norms > 0, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), 0.0))
    return np.min(angles, axis=0) if len(faces) else np.zeros(0)


_distance_kernel = None


def distances_to_mesh(query, points, faces):
    """Each row of ``query`` (Q, 3): its distance [m] to the nearest point of the triangle mesh (``points``,
    ``faces``) (Warp's BVH query on the CPU; float32, so about 1e-7 of the mesh's size)."""
    global _distance_kernel
    import warp as wp

    query = np.ascontiguousarray(query, np.float32).reshape(-1, 3)
    if len(query) == 0 or len(faces) == 0:
        return np.full(len(query), np.inf if len(faces) == 0 else 0.0)
    if _distance_kernel is None:
        @wp.kernel(enable_backward=False)
        def nearest_distance(mesh: wp.uint64, query: wp.array(dtype=wp.vec3), max_dist: float,
                             distance: wp.array(dtype=float)):
            """distance[i] = |query[i] - the nearest point of the mesh|."""
            i = wp.tid()
            q = wp.mesh_query_point_no_sign(mesh, query[i], max_dist)
            if q.result:
                distance[i] = wp.length(query[i] - wp.mesh_eval_position(mesh, q.face, q.u, q.v))

        _distance_kernel = nearest_distance
    device = wp.get_device("cpu")
    span = np.concatenate([np.asarray(points, np.float64), np.asarray(query, np.float64)])
    max_dist = float(np.linalg.norm(span.max(axis=0) - span.min(axis=0))) * 2.0 + 1.0
    with wp.ScopedDevice(device):
        mesh = wp.Mesh(points=wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=device),
                       indices=wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32, device=device))
        q = wp.array(query, dtype=wp.vec3, device=device)
        distance = wp.full(len(query), np.inf, dtype=float, device=device)
        wp.launch(_distance_kernel, len(query), inputs=[mesh.id, q, max_dist, distance], device=device)
        return distance.numpy().astype(np.float64)


def mesh_quality(mesh, reference=None, radius=1.0, clip=None, sliver_degrees=SLIVER_DEGREES, poses=None):
    """The quality of a surface mesh, as a dict of plain numbers (the side-by-side comparison of the surface
    methods, #42).

    ``mesh`` and ``reference``: a :class:`SurfaceMesh`, a trimesh or a (points, faces) pair; distances are in
    multiples of ``radius`` (the particle radius; the default 1 gives metres); ``clip``: a
    :class:`SurfaceClip` (the domain's walls).

    Keys: ``vertices``, ``faces``; ``watertight`` (trimesh's: every edge shared by exactly two faces, the mesh
    as written, vertices not merged), ``winding_consistent``, ``boundary_edges``; ``area`` [m^2] and
    ``volume`` [m^3] (signed, :func:`mesh_volume`; meaningful when watertight); ``sliver_fraction``: the
    fraction of faces whose smallest angle is below ``sliver_degrees`` (10), and ``min_angle_median``
    [degrees]; with ``reference``: ``distance_mean`` and ``distance_max`` from each vertex to the reference's
    surface and ``reverse_mean``, ``reverse_max`` from the reference's vertices to this mesh (what the mesh
    misses), in radii, and ``distance_over_1r``, ``reverse_over_1r``: the fractions of those vertices more than
    one radius away (droplets one mesh has and the other lacks); with ``clip``: ``outside_walls_max``, the largest distance of a vertex outside a
    walled face of the domain, in radii (0 when none is outside), and with bodies in it ``in_bodies_max``, the
    largest depth of a vertex inside a closed body or into an open one's shell (``surface_clip.SHELL``
    ``radius`` either side of its mesh: give the particle radius), the moving ones at ``poses``.

    Example:

    ```python
    import trimesh
    from warpsph.surface import mesh_quality

    q = mesh_quality(trimesh.creation.icosphere(subdivisions=3, radius=1.0))
    assert q["watertight"] and q["sliver_fraction"] == 0.0 and round(q["area"], 2) == 12.51
    ```
    """
    import trimesh

    points, faces = _mesh_arrays(mesh)
    tri = trimesh.Trimesh(vertices=points, faces=faces, process=False, validate=False)
    angles = face_min_angles(points, faces)
    quality = {
        "vertices": int(len(points)), "faces": int(len(faces)),
        "watertight": bool(tri.is_watertight) if len(faces) else False,
        "winding_consistent": bool(tri.is_winding_consistent) if len(faces) else False,
        "boundary_edges": boundary_edges(faces) if len(faces) else 0,
        "area": float(tri.area), "volume": mesh_volume(points, faces) if len(faces) else 0.0,
        "sliver_fraction": float((angles < sliver_degrees).mean()) if len(faces) else 0.0,
        "min_angle_median": float(np.median(angles)) if len(faces) else 0.0,
    }
    if reference is not None:
        ref_points, ref_faces = _mesh_arrays(reference)
        forward = distances_to_mesh(points, ref_points, ref_faces) / radius
        reverse = distances_to_mesh(ref_points, points, faces) / radius
        quality.update(distance_mean=float(forward.mean()) if len(forward) else 0.0,
                       distance_max=float(forward.max()) if len(forward) else 0.0,
                       distance_over_1r=float((forward > 1.0).mean()) if len(forward) else 0.0,
                       reverse_mean=float(reverse.mean()) if len(reverse) else 0.0,
                       reverse_max=float(reverse.max()) if len(reverse) else 0.0,
                       reverse_over_1r=float((reverse > 1.0).mean()) if len(reverse) else 0.0)
    if clip is not None:
        lo, hi = np.asarray(clip.lo, np.float64), np.asarray(clip.hi, np.float64)
        outside = np.maximum(np.maximum(lo - points, points - hi), 0.0) if len(points) else np.zeros((0, 3))
        quality["outside_walls_max"] = float(outside.max()) / radius if len(points) else 0.0
        if clip.bodies:
            from .surface_clip import depths_in_bodies

            depth = depths_in_bodies(points, clip.bodies, poses, radius) if len(points) else np.zeros(0)
            quality["in_bodies_max"] = float(depth.max()) / radius if len(depth) else 0.0
    return quality
