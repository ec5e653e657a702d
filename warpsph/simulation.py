"""The stepper: DFSPH with non-pressure models, in the order of the VR paper's Algorithm 2."""

from __future__ import annotations

import contextlib
import time as _time
from collections import Counter, defaultdict
from dataclasses import dataclass

from pathlib import Path

import numpy as np
import warp as wp

from warpsph import sampling
from warpsph.bodies import BODY_INSET, MovingBodies, load_body
from warpsph.inflow import Inflow
from warpsph.kernels.bodies import mark_fluid_clear_of_mesh
from warpsph.kernels.boundary import compute_boundary_volume
from warpsph.kernels.density import compute_density_and_factor
from warpsph.kernels.integration import (
    advance_clock,
    advect_positions,
    compute_max_speed,
    compute_time_step,
    predict_velocity,
)
from warpsph.kernels.neighbours import gather
from warpsph.kernels.pressure import REDUCE_THREADS
from warpsph.kernels.particles import Boundary
from warpsph.kernels.stability import DENSITY_LIMIT, NOT_FINITE, OUTSIDE_DOMAIN, check_particles
from warpsph.models import REGISTRY, plugin_of
from warpsph.models.vorticity import VorticityField
from warpsph.neighbours import NeighbourSearch, sort_order
from warpsph.resources import check_fits
from warpsph.errors import SceneError
from warpsph.scene import Scene

from warpsph.solver import DFSPHSolver


@dataclass
class FluidParticles:
    """Per-particle state of the fluid (sorted by cell every ``solver.sort_interval`` steps)."""

    x: wp.array  # position [m]
    v: wp.array  # velocity [m/s]
    ids: wp.array  # stable id (int32; int64 in USD), follows the particle through re-sorting
    density: wp.array  # [kg/m^3]
    factor: wp.array  # DFSPH factor
    acceleration: wp.array  # non-pressure acceleration of this step [m/s^2]


@dataclass
class BoundaryParticles:
    """Akinci boundary samples of every body, sampled and weighed once: the static ones (domain
    box and fixed obstacles) first, then kinematic bodies, then dynamic ones (from ``first_dynamic``)."""

    x: wp.array
    v: wp.array  # the moving samples' only (from first_moving on): static ones stand still
    volume: wp.array
    body: np.ndarray  # host: which body each sample belongs to (0 = domain box, k = obstacles[k - 1])
    impulse: wp.array  # reaction impulses on dynamic samples (empty without dynamic bodies)
    first_moving: int
    first_dynamic: int

    @property
    def samples(self) -> Boundary:
        """The arrays as the struct the kernels take."""
        s = Boundary()
        s.x, s.v, s.volume = self.x, self.v, self.volume
        s.impulse, s.first_moving, s.first_dynamic = self.impulse, self.first_moving, self.first_dynamic
        return s


# The domain box's boundary layer lies this many particle radii outside its faces. A single
# Akinci layer sampled at spacing 2r has V_b ~ 1.43 (2r)^3, so a lattice fluid half a spacing
# from it would start at 1.5 rho0; 2.2 r from the layer it has rest density (within 0.2 %),
# so a fluid block that touches a face starts at rest.
WALL_OFFSET = 1.2


# Health limits checked after every step (see check_health)
# rho / rho0 above which the solver has lost control: a 2000-particle dam break peaks at 1.22 for one
# step as its front corner shoots out (then recovers); the 1M run that exploded reached 2.2
DENSITY_HARD_LIMIT = 1.5
ESCAPE_MARGIN = WALL_OFFSET + 1.0  # radii past the box: a radius beyond its wall layer = tunnelled through
MAX_ITERATION_STREAK = 50  # consecutive solves that stop at max_iterations
RETRIES = 4  # reduce-dt policy: halvings of dt tried for one frame
CHECK_NAMES = {int(NOT_FINITE): "NaN or inf in position, velocity or density",
               int(OUTSIDE_DOMAIN): "particle left the domain",
               int(DENSITY_LIMIT): f"density above {DENSITY_HARD_LIMIT:g} rho0"}


class InstabilityError(RuntimeError):
    """The simulation became unstable; the message names the step, time, check and particle."""

    def __init__(self, step, time, check, particle_id=None, position=None):
        self.step, self.time, self.check, self.particle_id, self.position = step, time, check, particle_id, position
        where = "" if particle_id is None else f", particle id {particle_id} at {np.round(position, 4).tolist()}"
        super().__init__(f"unstable at step {step} (t = {time:.4f} s): {check}{where}")


class StageTimer:
    """Wall time per stage, synchronising the device around each; free when disabled."""

    def __init__(self, enabled=False):
        self.enabled = enabled
        self.seconds = defaultdict(float)
        self._null = contextlib.nullcontext()

    def __call__(self, name):
        return self._stage(name) if self.enabled else self._null

    @contextlib.contextmanager
    def _stage(self, name):
        wp.synchronize()
        start = _time.perf_counter()
        yield
        wp.synchronize()
        self.seconds[name] += _time.perf_counter() - start


# Neighbour lists index with int32: about 40 neighbours a particle keeps 50M particles below 2^31.
MAX_PARTICLES = 50_000_000


def count_particles(scene: Scene):
    """Fluid and domain-wall particle counts, computed before anything is sampled."""
    d = scene.particle_diameter
    fluid = sum(int(np.prod(np.floor((np.subtract(b.end, b.start)) / d + 1e-6))) for b in scene.fluid_blocks)
    ext = np.subtract(scene.domain.max, scene.domain.min) + 2 * WALL_OFFSET * scene.particle_radius
    walls = int(2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2]) / d**2) if scene.domain.walls else 0
    return fluid, walls


def sample_scene(scene: Scene):
    """Host-side initial particles: fluid (x, v), the static boundary (x, body index, Z-ordered)
    and every obstacle as a :class:`RigidBody` (static ones included, for the USD meshes)."""
    fluid, walls = count_particles(scene)
    if fluid > MAX_PARTICLES or walls > MAX_PARTICLES:
        raise SceneError(scene.source, "particle_radius",
                         f"r = {scene.particle_radius:.3g} m needs about {max(fluid, walls):.3g} particles, over the "
                         f"{MAX_PARTICLES:,} limit: use a larger radius or a smaller --scale")
    if fluid == 0 and not any(e.start == 0.0 for e in scene.emitters):
        raise SceneError(scene.source, "fluid_blocks", "no fluid at t = 0: every block is thinner than one particle "
                                                       "spacing (or missing) and no emitter starts at 0")
    d = scene.particle_diameter
    blocks = [sampling.fill_block(b.start, b.end, d) for b in scene.fluid_blocks]
    fluid_x = np.concatenate(blocks) if blocks else np.zeros((0, 3), np.float32)
    fluid_v = np.concatenate([np.tile(np.asarray(b.velocity, np.float32), (len(p), 1))
                              for b, p in zip(scene.fluid_blocks, blocks)]) if blocks else np.zeros((0, 3), np.float32)
    # walls stand off 1.2 r from the faces; along periodic axes they span the domain exactly
    offset = np.where(np.asarray(scene.domain.period) > 0, 0.0, WALL_OFFSET * scene.particle_radius)
    bodies = [sampling.sample_box_walls(np.asarray(scene.domain.min) - offset, np.asarray(scene.domain.max) + offset, d,
                                        scene.domain.periodic) if scene.domain.walls else np.zeros((0, 3), np.float32)]
    size = float(np.linalg.norm(np.subtract(scene.domain.max, scene.domain.min)))
    rigid = [load_body(o, scene.mesh_path(o), d, size, f"{Path(o.mesh).stem}_{n}", scene.fluid.density)
             for n, o in enumerate(scene.obstacles)]
    names = [b.name for b in rigid]
    for n, name in enumerate(names):
        if names.index(name) != n:
            raise SceneError(scene.source, f"obstacles[{n}].name", f"another body is named {name!r}")
    bodies += [b.world_samples() if b.kind == "static" else np.zeros((0, 3), np.float32) for b in rigid]
    boundary_x = np.concatenate(bodies).reshape(-1, 3)
    body = np.concatenate([np.full(len(p), n, dtype=np.int32) for n, p in enumerate(bodies)])
    order = sampling.morton_order(boundary_x, np.asarray(scene.domain.min), scene.support_radius)
    return fluid_x, fluid_v, boundary_x[order], body[order], rigid


class Simulation:
    """A scene on a device. ``step()`` advances one adaptive time step; ``run()`` frames.

    >>> sim = Simulation(load_scene("scenes/dam_break.json", scale=0.05), device="cpu")
    >>> sim.run(frames=10)
    """

    def __init__(self, scene: Scene, device=None, profile=False, use_graph=None):
        self.scene = scene
        self.device = wp.get_device(device)
        self.timer = StageTimer(profile)
        self.launches = Counter()  # kernel name -> launches (capture counts once)
        self.allocations = defaultdict(int)  # owner -> bytes
        r = scene.particle_radius
        self.support_radius = 4.0 * r
        self.fluid_volume = (2.0 * r) ** 3  # a lattice of spacing 2r sums to rho0 (see docs)
        self.rest_density = scene.fluid.density
        self.particle_mass = self.rest_density * self.fluid_volume
        self.gravity = scene.gravity  # (the setter also starts without a captured graph)
        # explicit viscosity is stable for dt <= 0.125 h^2 / nu with h = H / 2 (Morris et al. 1997): at
        # r = 2.9 mm and nu = 0.05 a 0.57 ms step flung dam-break particles out at 38 m/s
        nu = max(scene.fluid.viscosity, scene.fluid.boundary_viscosity)
        self.viscous_dt = 0.125 * (0.5 * self.support_radius) ** 2 / nu if nu > 0 else 1.0e30

        fluid_x, fluid_v, boundary_x, body, self.bodies = sample_scene(scene)
        fluid_x, fluid_v = self._remove_fluid_inside_bodies(fluid_x, fluid_v)
        # moving bodies' samples follow the static ones: kinematic, then dynamic
        moving = sorted((b for b in self.bodies if b.kind != "static"), key=lambda b: b.kind == "dynamic")
        first_moving = len(boundary_x)
        if moving:
            boundary_x = np.concatenate([boundary_x] + [b.world_samples() for b in moving])
            index = {id(b): n + 1 for n, b in enumerate(self.bodies)}
            body = np.concatenate([body] + [np.full(len(b.samples), index[id(b)], np.int32) for b in moving])
        self.num_fluid = len(fluid_x)
        self.num_boundary = len(boundary_x)
        # emitters, sinks, and the removal of what leaves an open domain
        self.inflow = Inflow(scene, self.num_fluid) if scene.emitters or scene.sinks or scene.domain.is_open else None
        # per-particle arrays hold the fluid at its largest: the initial particles and what emitters add
        self.capacity = self.num_fluid + (self.inflow.room if self.inflow is not None else 0)
        self._per_particle = []
        self._scratch = None
        model_classes = [plugin_of(p) for p in scene.models]
        self._scratch_columns = max([DFSPHSolver.columns(scene)] + [m.scratch_columns for m in model_classes])
        check_fits(scene, self.capacity, self.num_boundary, self.device)  # refuse before allocating
        with wp.ScopedDevice(self.device):
            z, p = self.zeros, self.per_particle
            self.fluid = FluidParticles(
                x=p("fluid", wp.vec3, fluid_x), v=p("fluid", wp.vec3, fluid_v),
                ids=p("fluid", wp.int32, np.arange(self.num_fluid, dtype=np.int32)),
                density=p("fluid"), factor=p("fluid"), acceleration=p("fluid", wp.vec3))
            has_dynamic = any(b.kind == "dynamic" for b in moving)
            first_dynamic = first_moving + sum(len(b.samples) for b in moving if b.kind == "kinematic")
            self.boundary = BoundaryParticles(
                x=self.array("boundary", boundary_x, wp.vec3), v=z("boundary", self.num_boundary - first_moving, dtype=wp.vec3),
                volume=z("boundary", self.num_boundary), body=body,
                impulse=z("bodies", self.num_boundary if has_dynamic else 0, dtype=wp.vec3), first_moving=first_moving,
                first_dynamic=first_dynamic if has_dynamic else self.num_boundary)
            self.moving_bodies = MovingBodies(self, moving, first_moving) if moving else None
            self.neighbours = NeighbourSearch(self, self.boundary.x)
            if self.num_boundary:  # V_b once: static samples together, each moving body on its own
                sample_body = wp.array(body, dtype=wp.int32, device=self.device)
                first_moving_body = int(body[first_moving]) if moving else len(self.bodies) + 1
                self.launch(compute_boundary_volume, self.num_boundary,
                            [self.neighbours.boundary_grid.grid, self.boundary.x, sample_body, first_moving_body,
                             self.support_radius, self.neighbours.lower, self.neighbours.period, self.boundary.volume])
            self.pressure_solver = DFSPHSolver(self)
            viscous = scene.fluid.viscosity > 0.0 or scene.fluid.boundary_viscosity > 0.0
            self.viscosity_model = REGISTRY["viscosity"](self) if viscous else None
            self.turbulence_models = [cls(self, p) for cls, p in zip(model_classes, scene.models)]
            self.models = ([self.viscosity_model] if viscous else []) + self.turbulence_models
            # the vorticity of v~, shared by the models, exists only when one reads it
            self.vorticity_field = None
            if any(m.needs_vorticity for m in self.models):
                self.vorticity_field = VorticityField(self)
            # clock on the device: dt, previous dt, time, steps, max speed^2
            self.dt = z("clock", 1)
            self.dt_previous = self.array("clock", np.array([scene.time_step_bounds[1]], np.float32), float)
            self.time_device = z("clock", 1, dtype=wp.float64)
            self.steps_device = z("clock", 1, dtype=wp.int64)
            self.max_speed_sq = z("clock", 1)
            self.health_counts = z("health", 4, dtype=wp.int32)
            self.health_first = z("health", 4, dtype=wp.int32)
            if scene.initial_packing is not None:  # the blocks' particles relaxed before t = 0
                from warpsph.packing import packed_positions

                packed = packed_positions(scene, self.device)
                wp.copy(self.fluid.x, wp.array(packed, dtype=wp.vec3, device=self.device), count=len(packed))
            if self.inflow is not None:  # the layers due at t = 0
                self.inflow.emit(self, 0.0)
            # densities of the initial state, so that frame 0 has them
            self.neighbours.update(self.fluid.x)
            self._compute_density()
        self.step_count = 0
        self.frame = 0  # last output frame reached by run()
        self.on_instability = "stop"  # or "reduce-dt": retry the step with a smaller dt
        self._dt_scale = 1.0
        self.use_graph = self.device.is_cuda and wp.is_conditional_graph_supported() if use_graph is None else use_graph
        self._graph = None
        self._graph_generation = None

    def _remove_fluid_inside_bodies(self, fluid_x, fluid_v):
        """Drops the fluid particles that the blocks put inside a closed body or within one
        particle radius of its surface (at the body's initial pose); open meshes keep them."""
        closed = [b for b in self.bodies if b.closed]
        if not closed or not len(fluid_x):
            return fluid_x, fluid_v
        x = wp.array(fluid_x, dtype=wp.vec3, device=self.device)
        keep = wp.ones(len(fluid_x), dtype=wp.int32, device=self.device)
        for b in closed:
            mesh = wp.Mesh(points=wp.array(b.to_world(b.vertices), dtype=wp.vec3, device=self.device),
                           indices=wp.array(b.faces.ravel(), dtype=wp.int32, device=self.device))
            self.launch(mark_fluid_clear_of_mesh, len(fluid_x), [mesh.id, x, self.scene.particle_radius, keep])
        kept = keep.numpy().astype(bool)
        if not kept.any():
            raise SceneError(self.scene.source, "obstacles", "the bodies cover every fluid particle: no fluid left")
        return fluid_x[kept], fluid_v[kept]

    @property
    def gravity(self) -> wp.vec3:
        """Gravity [m/s^2]; may be changed between steps (a ramp, a tilting tank): setting it drops
        the captured CUDA graph, whose launches hold the value they were captured with."""
        return self._gravity

    @gravity.setter
    def gravity(self, value):
        self._gravity = wp.vec3(*[float(c) for c in value])
        self._graph = None

    # -- allocation and launch bookkeeping ---------------------------------------------------
    def zeros(self, owner, shape, dtype=float):
        a = wp.zeros(shape, dtype=dtype, device=self.device)
        self.allocations[owner] += a.capacity
        return a

    def per_particle(self, owner, dtype=float, data=None):
        """A per-fluid-particle array of ``capacity`` entries (room for emitted particles), with
        ``data`` in its first rows; registered, so that emitted particles start at zero in it."""
        a = self.zeros(owner, self.capacity, dtype=dtype)
        if data is not None and len(data):
            a[: len(data)].assign(np.ascontiguousarray(data))
        self._per_particle.append(a)
        return a

    def scratch(self, dtype, column=0):
        """A per-particle scratch array of ``dtype`` over float columns ``column ..`` of the scratch
        pool, for values that live within one stage (stream function, next angular velocity,
        solver stiffness and error). The models run one after the other and the pressure solver
        apart from them, so they all share one pool: ``capacity`` x the widest ``scratch_columns``
        that the solver or an enabled model declares."""
        width = wp.types.type_size_in_bytes(dtype) // 4
        if column + width > self._scratch_columns:
            raise ValueError(f"scratch columns {column}..{column + width - 1} of {dtype} exceed the "
                             f"{self._scratch_columns} declared (raise the owner's scratch_columns)")
        if self._scratch is None:
            self._scratch = self.zeros("scratch", self.capacity * self._scratch_columns)
        return wp.array(ptr=self._scratch.ptr + 4 * column * self.capacity, dtype=dtype, shape=(self.capacity,),
                        device=self.device)

    def active(self, array):
        """The rows of a per-particle array that hold particles (a view; the array itself when full)."""
        return array if array.shape[0] == self.num_fluid else array[: self.num_fluid]

    def host(self, array):
        """The particles' rows of a per-particle array, copied to the host."""
        return self.active(array).numpy()

    # public numpy accessors: copies of the active fluid particles (rows 0..num_fluid-1, in the
    # current sort order; ``ids()`` gives each row's stable id)
    def _copy(self, array):
        out = self.host(array)  # on the CPU, Warp's numpy() is a view of the particles' memory
        return out.copy() if self.device.is_cpu else out

    def positions(self):
        """Fluid particle positions [m] as a new (num_fluid, 3) float32 numpy array."""
        return self._copy(self.fluid.x)

    def velocities(self):
        """Fluid particle velocities [m/s] as a new (num_fluid, 3) float32 numpy array."""
        return self._copy(self.fluid.v)

    def densities(self):
        """Fluid particle densities [kg/m^3] as a new (num_fluid,) float32 numpy array."""
        return self._copy(self.fluid.density)

    def ids(self):
        """Stable particle ids (int32, unchanged by re-sorting) of the rows of :meth:`positions`."""
        return self._copy(self.fluid.ids)

    def kinetic_energy(self):
        """Kinetic energy of the fluid [J], summed on the host in float64."""
        v = self.velocities().astype(np.float64)
        return 0.5 * self.particle_mass * float(np.sum(v * v))

    def array(self, owner, data, dtype):
        a = wp.array(data, dtype=dtype, device=self.device)
        self.allocations[owner] += a.capacity
        return a

    def launch(self, kernel, dim, inputs):
        self.launches[kernel.key] += 1
        wp.launch(kernel, dim=dim, inputs=inputs, device=self.device)

    # -- re-sorting by cell ------------------------------------------------------------------------
    def permute(self, array, order):
        """array[:] = array[order] for one per-particle array (through a temporary copy)."""
        scratch = wp.empty_like(array)
        self.launch(gather, self.num_fluid, [array, order, scratch])
        wp.copy(array, scratch, count=self.num_fluid)

    def sort_particles(self):
        """Re-sorts every fluid particle array (and each model's state) into Z-order of cells. The
        keys, the permutation and the gather copies live only while sorting (every sort_interval
        steps, outside the captured graph): 40 B a particle that the step itself never holds."""
        keys = wp.empty(2 * self.num_fluid, dtype=wp.int32, device=self.device)  # radix sort needs 2n
        order = wp.empty(2 * self.num_fluid, dtype=wp.int32, device=self.device)
        sort_order(self, self.fluid.x, keys, order)
        self.reorder_particles(order)

    def reorder_particles(self, order):
        """Permutes every array that carries a particle's state from step to step (the others are
        recomputed each step) by ``order``: re-sorting and sink compaction."""
        for a in (self.fluid.x, self.fluid.v, self.fluid.ids):
            self.permute(a, order)
        self.pressure_solver.reorder(self, order)
        for m in self.models:
            m.reorder(self, order)

    # -- the step --------------------------------------------------------------------------------------
    def step(self):
        """One DFSPH step with its models (VR paper Algorithm 2; SPlisHSPlasH's step order).

        The divergence correction of Algorithm 1 runs at the start of the step, on the
        densities of the new positions: it turns v^n (advected at the end of the last
        step) into the divergence-free v~ that the models refine."""
        with wp.ScopedDevice(self.device):
            # t^n, read from the device once for the emitters and the bodies' poses
            now = self.time if self.inflow is not None or self.moving_bodies is not None else None
            if self.inflow is not None:
                with self.timer("inflow"):  # sinks remove, emitters add: the count changes here only
                    self.inflow.update(self, now)
            interval = self.scene.solver.sort_interval
            if interval and self.step_count % interval == 0:
                with self.timer("sort"):
                    self.sort_particles()
            if self.moving_bodies is not None:
                with self.timer("bodies"):  # boundary samples at the bodies' poses at t^n
                    self.moving_bodies.place(now)
                    self.neighbours.rebuild_boundary_grid()
            with self.timer("neighbours"):
                self.neighbours.update(self.fluid.x)
            if self.use_graph and not self.timer.enabled and self._dt_scale == 1.0:
                self._step_with_graph()
            else:
                self._solve_step()
            if self.moving_bodies is not None and self.moving_bodies.dynamic:
                with self.timer("bodies"):  # two-way coupling: the fluid's impulses of this step move them
                    d = self.scene.domain
                    self.moving_bodies.integrate(float(self.dt.numpy()[0]), self.scene.gravity, d.min, d.max, d.periodic,
                                                 margin=BODY_INSET * self.scene.particle_radius)
        self.step_count += 1

    def _step_with_graph(self):
        key = (self.neighbours.generation, self.num_fluid)  # the graph holds array pointers and launch sizes
        if self._graph is None or self._graph_generation != key:
            if self.step_count == 0:  # load the modules outside the capture
                self._solve_step()
                return
            with wp.ScopedCapture(device=self.device) as capture:
                self._solve_step()
            self._graph = capture.graph
            self._graph_generation = key
        wp.capture_launch(self._graph)

    def _solve_step(self):
        f, n, t = self.fluid, self.num_fluid, self.timer
        with t("density"):  # rho^n, the DFSPH factor and the free surface at x^n
            self._compute_density()
            self.pressure_solver.detect_free_surface()
        with t("time_step"):  # CFL condition on |v^n|
            self.max_speed_sq.zero_()
            self.launch(compute_max_speed, min(n, REDUCE_THREADS), [f.v, n, self.max_speed_sq])
            tm = self.scene.time
            self.launch(compute_time_step, 1,
                        [self.max_speed_sq, self.scene.particle_diameter, tm.cfl, *self.scene.time_step_bounds,
                         tm.fixed_dt or 0.0, self.viscous_dt, self._dt_scale, self.dt_previous, self.dt])
        with t("divergence_solve"):  # v~ = correctDivergence(v)
            self.pressure_solver.correct_divergence()
        with t("non_pressure"):  # a_adv = a_vis; turbulence models refine v~ (Algorithm 2)
            f.acceleration.zero_()
            # zeta~ = curl v~, once for all models: in the viscosity pass when there is one
            if self.vorticity_field is not None and not any(m.computes_vorticity for m in self.models):
                self.vorticity_field.update(self)
            for model in self.models:
                model.step(self)
        with t("advection"):  # v_adv = v~ + dt (a_adv + g)
            self.launch(predict_velocity, n, [f.acceleration, self.gravity, self.dt, f.v])
        with t("density_solve"):  # projection: rho*(x + dt v_adv) -> rho0
            self.pressure_solver.correct_density()
        with t("integration"):  # x^{n+1} = x^n + dt v
            self.launch(advect_positions, n, [f.v, self.dt, self.neighbours.lower, self.neighbours.period, f.x])
            self.pressure_solver.shift_particles()  # particle shifting (no-op when off)
            self.launch(advance_clock, 1, [self.dt, self.time_device, self.steps_device])
        with t("health"):  # NaN/inf, escaped particles, runaway density: counted on the device
            self.health_counts.zero_()
            self.health_first.fill_(2**31 - 1)
            lo = np.asarray(self.scene.domain.min) - ESCAPE_MARGIN * self.scene.particle_radius
            hi = np.asarray(self.scene.domain.max) + ESCAPE_MARGIN * self.scene.particle_radius
            if not self.scene.domain.walls:  # an open domain: particles may leave (the next step removes them)
                lo, hi = np.full(3, -1e30), np.full(3, 1e30)
            self.launch(check_particles, n, [f.x, f.v, f.density, wp.vec3(*lo), wp.vec3(*hi),
                                             DENSITY_HARD_LIMIT * self.rest_density, self.health_counts,
                                             self.health_first])

    def _compute_density(self):
        f = self.fluid
        self.launch(compute_density_and_factor, self.num_fluid,
                    [f.x, self.neighbours.lists, self.boundary.samples, self.fluid_volume, self.rest_density,
                     self.support_radius, f.density, f.factor, *self.pressure_solver.density_pass_outputs()])

    # -- host views -------------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time [s] (reads the device clock)."""
        return float(self.time_device.numpy()[0])

    def check_health(self):
        """The first failed health check of the last step as an :class:`InstabilityError`, or None."""
        counts, first = self.health_counts.numpy(), self.health_first.numpy()
        for check in (int(NOT_FINITE), int(OUTSIDE_DOMAIN), int(DENSITY_LIMIT)):
            if counts[check]:
                i = int(first[check])
                return InstabilityError(self.step_count, self.time, f"{CHECK_NAMES[check]} ({counts[check]} particles)",
                                        int(self.fluid.ids.numpy()[i]), self.fluid.x.numpy()[i])
        streak = self.pressure_solver.max_iteration_streak.numpy()
        if streak.max() >= MAX_ITERATION_STREAK:
            which = "divergence" if streak[0] >= MAX_ITERATION_STREAK else "density"
            return InstabilityError(self.step_count, self.time,
                                    f"{which} solver hit max_iterations {int(streak.max())} steps in a row")
        return None

    # -- state: what a checkpoint keeps and a retried step restores -----------------------------------------
    def state_arrays(self):
        """Every device array that carries state from one step to the next, by name."""
        out = {"fluid/x": self.fluid.x, "fluid/v": self.fluid.v, "fluid/ids": self.fluid.ids,
               "solver/totals": self.pressure_solver.totals,
               "solver/max_iteration_streak": self.pressure_solver.max_iteration_streak,
               "clock/time": self.time_device, "clock/steps": self.steps_device, "clock/dt": self.dt,
               "clock/dt_previous": self.dt_previous}
        for n, a in enumerate(self.pressure_solver.pressure_sum):
            out[f"solver/pressure_sum_{n}"] = a
        for m in self.turbulence_models:
            for name, a in m.state().items():
                out[f"models/{m.name}/{name}"] = a
        if self.moving_bodies is not None and self.moving_bodies.dynamic:
            out["bodies/state"] = self.moving_bodies.state
        return out

    def state_flags(self):
        """Host-side state: step and frame counters and the models' flags."""
        out = {"step": self.step_count, "frame": self.frame, "num_fluid": self.num_fluid}
        if self.inflow is not None:
            out.update(self.inflow.state())
        for m in self.turbulence_models:
            out.update({f"{m.name}.{k}": v for k, v in m.flags().items()})
        return out

    def restore_flags(self, flags):
        self.step_count, self.frame = int(flags["step"]), int(flags["frame"])
        self.num_fluid = int(flags.get("num_fluid", self.num_fluid))
        if self.inflow is not None:
            self.inflow.restore(flags)
        if self.moving_bodies is not None:
            self.moving_bodies.load_state()
        for m in self.turbulence_models:
            m.restore_flags({k: flags[f"{m.name}.{k}"] for k in m.flag_names})

    def _snapshot(self):
        return {k: wp.clone(a) for k, a in self.state_arrays().items()}, self.state_flags()

    def _restore(self, snapshot):
        arrays, flags = snapshot
        for k, a in self.state_arrays().items():
            wp.copy(a, arrays[k])
        self.restore_flags(flags)

    def _advance_to(self, target):
        """Steps until ``time >= target``, checking health after every step. With
        ``on_instability == "reduce-dt"`` a frame that fails is undone (to the state at its start,
        where the damage had not begun) and redone with dt halved, up to RETRIES times."""
        snapshot = self._snapshot() if self.on_instability == "reduce-dt" else None
        try:
            for attempt in range(RETRIES + 1):
                try:
                    while self.time < target - 1e-9:
                        self.step()
                        problem = self.check_health()
                        if problem is not None:
                            raise problem
                    return
                except InstabilityError:
                    if snapshot is None or attempt == RETRIES:
                        raise
                    self._restore(snapshot)
                    self._dt_scale *= 0.5
        finally:
            self._dt_scale = 1.0

    def run(self, frames=None, on_frame=None, until_time=None):
        """Advances to output frame ``frames`` at the scene's fps (or to ``until_time``), calling
        ``on_frame(sim, frame)`` after the initial state and each frame. A simulation restored
        from a checkpoint continues after its last frame (``self.frame``)."""
        fps = self.scene.output.fps
        frames = self.scene.output.frames if frames is None and until_time is None else frames
        if until_time is not None:
            frames = int(np.ceil(until_time * fps - 1e-9))
        if on_frame is not None and self.frame == 0 and self.step_count == 0:
            on_frame(self, 0)
        for frame in range(self.frame + 1, frames + 1):
            target = frame / fps
            self._advance_to(target)
            self.frame = frame
            if on_frame is not None:
                on_frame(self, frame)
        return self

    def statistics(self):
        """Solver iterations per solve, the last average errors and the particles removed so far
        (inside sinks; outside an open domain)."""
        div_it, div_n, dens_it, dens_n = self.pressure_solver.iteration_totals()
        div_err, dens_err = self.pressure_solver.last_errors()
        return {
            "steps": self.step_count,
            "divergence_iterations": div_it / max(div_n, 1),
            "density_iterations": dens_it / max(dens_n, 1),
            "divergence_error": div_err,
            "density_error": dens_err,
            "removed_in_sinks": self.inflow.removed_in_sinks if self.inflow is not None else 0,
            "removed_outside": self.inflow.removed_outside if self.inflow is not None else 0,
        }

    def fields(self):
        """Per-particle fields by name, for every writer (USD, checkpoints, plots)."""
        out = {"density": self.fluid.density}
        if self.vorticity_field is not None:
            out["vorticity"] = self.vorticity_field.vorticity
        for m in self.models:
            out.update(m.fields())
        return out
