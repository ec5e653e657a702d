"""The stepper: a pressure solver (DFSPH or IISPH) with non-pressure models, in the order of the VR paper's
Algorithm 2."""

from __future__ import annotations

import contextlib
import time as _time
from collections import Counter, defaultdict
from dataclasses import dataclass


import numpy as np
import warp as wp

from warpsph import health, precompiled, warmup
from warpsph.diagnostics import DiagnosticsContext
from warpsph.bodies import BODY_INSET, BodiesContext, MovingBodies
from warpsph.health import InstabilityError  # noqa: F401 (public here too)
from warpsph.inflow import Inflow, InflowContext
from warpsph.kernels.boundary import compute_boundary_volume
from warpsph.kernels.density import compute_density_and_factor
from warpsph.kernels.integration import (
    advance_clock,
    advect_positions,
    compute_max_body_speed,
    compute_max_speed,
    compute_time_step,
    predict_velocity,
)
from warpsph.kernels.neighbours import gather
from warpsph.kernels.pressure import REDUCE_THREADS
from warpsph.kernels.particles import Boundary
from warpsph.models import REGISTRY, ModelContext, plugin_of
from warpsph.models.vorticity import VorticityField, curl_of
from warpsph.neighbours import NeighbourSearch, sort_order
from warpsph.resources import check_fits
from warpsph.scene import Scene
from warpsph.state import Constants, FluidParticles, State, viscous_substeps  # noqa: F401 (public here too)
from warpsph.scene_setup import count_particles, remove_fluid_inside_bodies, sample_scene  # noqa: F401 (public here too)
from warpsph.volume_maps import VolumeMaps

from warpsph.solvers import SolverContext, solver_class as registered_solver
from warpsph.packing import packed_positions


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


class Simulation:
    """A scene on a device. ``step()`` advances one adaptive time step; ``run()`` frames.

    Example:

    ```python
    import warpsph

    scene = warpsph.load_scene("scenes/dam_break.json", scale=0.05)
    sim = warpsph.Simulation(scene, device="cpu")  # "cuda", "cuda:0"; None: Warp's default device
    sim.run(frames=10)
    print(sim.time, sim.num_fluid, sim.kinetic_energy())
    ```
    """

    def __init__(self, scene: Scene, device=None, profile=False, use_graph=None, particles=None, halo=None,
                 preload=None, bodies_move=True, on_instability="stop", setup_timer=None):
        """``bodies_move`` False: the moving bodies stay at their initial pose (sampled there, never placed,
        integrated or coupled: :func:`~warpsph.packing.packed_positions` relaxes the fluid around them).
        ``on_instability``: as the attribute. ``setup_timer``: a callable ``name -> context manager`` wrapped around
        each stage of the set-up (``warpsph bench job`` times the time to the first step by it); None: untimed.
        ``particles`` (x, v, ids) and ``halo`` are for one subdomain of a
        :class:`~warpsph.decomposition.DecomposedSimulation`: its fluid particles instead of the scene's
        sampled (and packed) ones, and the link to the other subdomains (ghost rows, exchanges, reductions).
        ``preload``: True compiles (or loads from Warp's kernel cache) the Warp modules the scene launches
        (:func:`~warpsph.warmup.scene_modules`) together, a thread per idle core, before the set-up launches
        anything; False: each module compiles at its first launch, one after another; None (default): True unless
        the environment variable ``WARPSPH_PRELOAD`` is 0 (:mod:`warpsph.warmup`); a list of module names: as
        None, with those too (``warpsph run``'s frame diagnostics)."""
        self.scene = scene
        self.halo = halo
        self.device = wp.get_device(device)
        self.timer = StageTimer(profile)
        self.launches = Counter()  # kernel name -> launches (a graph's replay counts its captured launches)
        self.constants = Constants.from_scene(scene)  # radius, support, mass, rest density, domain: fixed
        self.gravity = scene.gravity  # (the setter also starts without a captured graph)

        stage = setup_timer or (lambda name: contextlib.nullcontext())
        ids = None
        if particles is None:
            with stage("sample_scene (all host sampling)"):
                fluid_x, fluid_v, boundary_x, body, self.bodies = sample_scene(scene)
            self._preload(preload, len(fluid_x))
            fluid_x, fluid_v = remove_fluid_inside_bodies(scene, self.bodies, fluid_x, fluid_v, self.device, self.launch)
        else:  # a subdomain: its own fluid, the scene's boundary
            with stage("sample_scene (all host sampling)"):
                _, _, boundary_x, body, self.bodies = sample_scene(scene, limit_fluid=False, with_fluid=False)
            self._preload(preload, 0)  # (the decomposed simulation cleared the bodies' insides)
            fluid_x, fluid_v, ids = particles
        # moving bodies' samples follow the static ones: kinematic, then dynamic
        moving = sorted((b for b in self.bodies if b.kind != "static"), key=lambda b: b.kind == "dynamic")
        first_moving = len(boundary_x)
        if moving:
            boundary_x = np.concatenate([boundary_x] + [b.world_samples() for b in moving])
            index = {id(b): n + 1 for n, b in enumerate(self.bodies)}
            body = np.concatenate([body] + [np.full(len(b.samples), index[id(b)], np.int32) for b in moving])
        self.num_boundary = len(boundary_x)
        # emitters, sinks, and the removal of what leaves an open domain
        self.inflow = Inflow(scene, len(fluid_x)) if scene.emitters or scene.sinks or scene.domain.is_open else None
        # per-particle arrays hold the fluid at its largest: the initial particles and what emitters add
        capacity = len(fluid_x) + (self.inflow.room if self.inflow is not None else 0)
        if halo is not None:  # owned particles, those that arrive, and ghost rows
            capacity = halo.capacity
        self.state = State(self.device, capacity, len(fluid_x))
        self._scratch = None
        model_classes = [plugin_of(p) for p in scene.models]
        solver_class = registered_solver(scene.solver.method)
        self._scratch_columns = max([solver_class.columns(scene)] + [m.scratch_columns for m in model_classes])
        check_fits(scene, self.capacity, self.num_boundary, self.device)  # refuse before allocating
        with wp.ScopedDevice(self.device):
            z = self.zeros
            self.state.allocate_fluid(fluid_x, fluid_v, factor=solver_class.needs_factor, ids=ids)
            self.state.allocate_clock(scene.time_step_bounds[1])
            # the viscosity's sub-steps this step and their dt, and the loop's count (none without sub-steps)
            sub = self.max_viscous_substeps > 1
            self.viscous_substeps = (z("clock", int(sub), dtype=wp.int32), z("clock", int(sub)))
            self.substeps_left = z("clock", int(sub), dtype=wp.int32)
            # [max |v|^2 of the fluid, the CFL speed^2, with viscosity its largest rate (compute_max_speed)]
            self.max_speed_sq = z("clock", 3 if scene.fluid.viscous else 2)
            # each particle's bound on the explicit viscosity's rate, from the density pass (compute_density_and_factor)
            self.viscous_rate = z("viscosity", self.capacity if scene.fluid.viscous else 0)
            has_dynamic = any(b.kind == "dynamic" for b in moving)
            first_dynamic = first_moving + sum(len(b.samples) for b in moving if b.kind == "kinematic")
            # volume maps (warpsph.volume_maps): each fluid particle's point of each mapped body after the samples
            # (the dynamic bodies of an imported scene with boundaryHandlingMethod 2; one domain)
            mapped = [(k, float(b.volume_map)) for k, b in enumerate(moving)
                      if b.kind == "dynamic" and b.volume_map is not None] if halo is None else []
            maps = len(mapped)
            slots = self.num_boundary + capacity * maps
            if maps:
                boundary_x = np.concatenate([boundary_x, np.zeros((capacity * maps, 3), np.float32)])
            self.boundary = BoundaryParticles(
                x=self.array("boundary", boundary_x, wp.vec3), v=z("boundary", slots - first_moving, dtype=wp.vec3),
                volume=z("boundary", slots), body=body,
                impulse=z("bodies", slots if has_dynamic else 0, dtype=wp.vec3), first_moving=first_moving,
                first_dynamic=first_dynamic if has_dynamic else self.num_boundary)
            bodies = BodiesContext(self.state, self.constants, self.boundary, self.launch, lambda: self.gravity,
                                   lambda: self.neighbours.lists)  # what the bodies see
            self.moving_bodies = MovingBodies(bodies, moving, first_moving,
                                              [b for b in self.bodies if b.kind == "static"]) if moving else None
            with stage("neighbour grids (boundary grid)"):
                self.neighbours = NeighbourSearch(self, self.boundary.x, self.num_boundary)
            if self.num_boundary:  # V_b once: static samples together, each moving body on its own
                sample_body = wp.array(body, dtype=wp.int32, device=self.device)
                first_moving_body = int(body[first_moving]) if moving else len(self.bodies) + 1
                with stage("boundary volumes (incl. kernel load)"):
                    self.launch(compute_boundary_volume, self.num_boundary,
                                [self.neighbours.boundary_grid.grid, self.boundary.x, sample_body, first_moving_body,
                                 self.support_radius, self.neighbours.lower, self.neighbours.period,
                                 self.boundary.volume])
            self.volume_maps = None
            if maps:  # the mapped bodies' samples stay for their contacts (volume 0); their maps hold the fluid
                with stage("volume maps"):
                    self.volume_maps = VolumeMaps(self.state, self.constants, moving, mapped, self.num_boundary,
                                                  first_moving)
                    held = [index[id(moving[k])] for k, _ in mapped]
                    volume = self.boundary.volume.numpy()
                    volume[: self.num_boundary][np.isin(body, held)] = 0.0
                    self.boundary.volume.assign(volume)
                    self.moving_bodies.attach_volume_maps(self.volume_maps, capacity)
                    self.neighbours.volume_maps = (self.volume_maps, self._place_volume_maps)
            self._solver_context = SolverContext(  # what the pressure solver sees
                state=self.state, constants=self.constants, parameters=scene.solver, boundary=self.boundary,
                neighbour_lists=lambda: self.neighbours.lists, lower=self.neighbours.lower,
                period=self.neighbours.period, launch=self.launch, scratch=self.scratch, permute=self.permute,
                exchange=self.exchange, allreduce=self.allreduce, global_count=lambda: self.global_count,
                gravity=lambda: self.gravity, max_speed_sq=self.max_speed_sq,
                # the dynamic bodies it moves inside its iterations (start_coupling below); not those that stay put
                bodies=self.moving_bodies if bodies_move else None)
            with stage("pressure solver set-up"):
                self.pressure_solver = solver_class(self._solver_context)
            if self.moving_bodies is not None and solver_class.couples_bodies:
                self.moving_bodies.start_coupling()  # dynamic bodies move inside the pressure iterations
            viscous = scene.fluid.viscous
            self.model_context = ModelContext(self)  # what the plug-ins see
            self.viscosity_model = REGISTRY["viscosity"](self.model_context) if viscous else None
            self.turbulence_models = [cls(self.model_context, p) for cls, p in zip(model_classes, scene.models)]
            self.models = ([self.viscosity_model] if viscous else []) + self.turbulence_models
            for m in self.turbulence_models:
                for name, a in m.state().items():
                    self.state.carry(f"models/{m.name}/{name}", a)
            # the vorticity of v~, shared by the models, exists only when one reads it
            self.vorticity_field = None
            if any(m.needs_vorticity for m in self.models):
                self.vorticity_field = VorticityField(self)
            self.diagnostics_context = DiagnosticsContext(  # what the frame diagnostics see
                self.state, self.constants, self.device, self.launch, scene.gravity,
                None if self.vorticity_field is None else self.vorticity_field.vorticity,
                lambda v, out: curl_of(self, v, out), self._spin, bool(self.turbulence_models),
                self.pressure_solver.iteration_totals, self._removed)
            self.health = health.HealthChecks(self.state, self.constants, self.launch,
                                              self.pressure_solver.max_iteration_streak)
            if scene.initial_packing is not None and particles is None:  # the blocks' particles relaxed before t = 0
                packed = packed_positions(scene, self.device, Simulation)
                wp.copy(self.fluid.x, wp.array(packed, dtype=wp.vec3, device=self.device), count=len(packed))
            # what the emitters and sinks see
            self._inflow_context = InflowContext(self.state, self.device, self.launch, self.reorder_particles,
                                                 self._emitted)
            if self.inflow is not None:  # the layers due at t = 0
                self.inflow.emit(self._inflow_context, 0.0)
            if halo is None:  # a subdomain's need its ghosts first (DecomposedSimulation); so that frame 0 has them
                with stage("initial neighbour lists"):
                    self.neighbours.update(self.fluid.x)
                with stage("initial densities"):
                    self._compute_density()
        if not bodies_move:  # they stay where they were sampled: no placing, integration or coupling
            self.moving_bodies = None
        self.on_instability = on_instability
        self._dt_scale = 1.0
        self.use_graph = self.device.is_cuda and wp.is_conditional_graph_supported() if use_graph is None else use_graph
        if halo is not None:
            self.use_graph = False  # exchanges wait on the other subdomains
        self._graph = None
        self._graph_generation = None
        self._graph_launches = Counter()

    def _preload(self, preload, fluid):
        """The set-up's one parallel compile (#43), after the host sampling (its errors come first, and the
        bodies and the ``fluid`` count tell which kernels of the bodies run) and before anything is launched. On a
        GPU, warpsph's precompiled kernels go into Warp's kernel cache first, whether or not it preloads
        (:func:`warpsph.precompiled.seed`)."""
        extra = [] if preload is None or isinstance(preload, bool) else list(preload)
        names = warmup.scene_modules(self.scene, bodies=self.bodies, fluid=fluid,
                                     decomposed=self.halo is not None) + extra
        if preload is True or (preload is not False and warmup.enabled()):
            warmup.preload(names, self.device)
        else:
            precompiled.seed(names, self.device)

    # -- the constants live in self.constants; these read them ----------------------------------------------
    support_radius = property(lambda self: self.constants.support_radius, doc="The kernel's support 4r [m].")
    fluid_volume = property(lambda self: self.constants.fluid_volume, doc="A fluid particle's volume (2r)^3 [m^3].")
    rest_density = property(lambda self: self.constants.rest_density, doc="The rest density rho0 [kg/m^3].")
    particle_mass = property(lambda self: self.constants.particle_mass, doc="A fluid particle's mass [kg].")
    viscous_dt = property(lambda self: self.constants.viscous_dt, doc="The explicit viscosity's stable dt [s].")
    max_viscous_substeps = property(lambda self: self.constants.max_viscous_substeps,
                                    doc="The most viscosity sub-steps in a step (1: none).")
    inside_lo = property(lambda self: self.constants.inside_lo, doc="The walled faces' lower corner (advection).")
    inside_hi = property(lambda self: self.constants.inside_hi, doc="The walled faces' upper corner (advection).")

    # -- the data lives in self.state; these read it ---------------------------------------------------
    fluid = property(lambda self: self.state.fluid, doc="The fluid's per-particle arrays (:class:`FluidParticles`).")
    capacity = property(lambda self: self.state.capacity, doc="Rows of every per-particle array.")
    allocations = property(lambda self: self.state.allocations, doc="Device bytes by owner.")
    dt = property(lambda self: self.state.dt, doc="This step's dt [s] (a device array of one).")
    dt_previous = property(lambda self: self.state.dt_previous)
    time_device = property(lambda self: self.state.time_device, doc="Simulated time [s] (a float64 device array of one).")
    steps_device = property(lambda self: self.state.steps_device)

    @property
    def on_instability(self) -> str:
        """What :meth:`run` does when a step fails its health check: "stop" (raise the :class:`InstabilityError`)
        or "reduce-dt" (redo the frame from its start with dt halved, up to ``health.RETRIES`` times); may be changed
        between frames.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05), on_instability="reduce-dt")
        sim.on_instability = "stop"
        ```
        """
        return self._on_instability

    @on_instability.setter
    def on_instability(self, value):
        if value not in ("stop", "reduce-dt"):
            raise ValueError(f'on_instability is "stop" or "reduce-dt", not {value!r}')
        self._on_instability = value

    @property
    def num_fluid(self) -> int:
        """Fluid particles now (rows 0 .. num_fluid - 1 of every per-particle array).

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        assert sim.positions().shape == (sim.num_fluid, 3)
        ```
        """
        return self.state.num_fluid

    @property
    def global_count(self) -> int:
        """Fluid particles in the whole simulation: ``num_fluid``, or the sum over the subdomains."""
        return self.num_fluid if self.halo is None else self.halo.global_count

    def exchange(self, *arrays):
        """Gives the ghost rows of per-particle ``arrays`` their owners' values before a neighbour pass
        reads them (a no-op without subdomains)."""
        if self.halo is not None:
            self.halo.exchange(arrays)

    def allreduce(self, *pairs, read=False):
        """Combines small device arrays over the subdomains, element by element, at one meeting: each pair is
        (array, ops) with ``ops[k]`` "s" (sum), "m" (max) or "-" (leave). ``read``: also return the combined
        values as numpy arrays (through the host); else None. A no-op without subdomains."""
        return None if self.halo is None else self.halo.allreduce(pairs, read)

    @property
    def step_count(self) -> int:
        return self.state.step_count

    @step_count.setter
    def step_count(self, value):
        self.state.step_count = value

    @property
    def frame(self) -> int:
        """The last output frame reached by :meth:`run`.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.run(frames=2)
        assert sim.frame == 2
        ```
        """
        return self.state.frame

    @frame.setter
    def frame(self, value):
        self.state.frame = value

    @property
    def gravity(self) -> wp.vec3:
        """Gravity [m/s^2]; may be changed between steps (a ramp, a tilting tank): setting it drops
        the captured CUDA graph, whose launches hold the value they were captured with.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        for tilt in (0.0, 0.5, 1.0):  # tilt the tank a little each frame
            sim.gravity = (tilt, -9.81, 0.0)
            sim.run(frames=sim.frame + 1)
        ```
        """
        return self._gravity

    @gravity.setter
    def gravity(self, value):
        self._gravity = wp.vec3(*[float(c) for c in value])
        self._graph = None

    # -- allocation and launch bookkeeping ---------------------------------------------------
    def zeros(self, owner, shape, dtype=float):
        return self.state.zeros(owner, shape, dtype)

    def per_particle(self, owner, dtype=float, data=None):
        """A per-fluid-particle array of ``capacity`` rows (:meth:`State.per_particle`)."""
        return self.state.per_particle(owner, dtype, data)

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
        return self.state.active(array)

    def host(self, array):
        """The particles' rows of a per-particle array, copied to the host."""
        return self.state.host(array)

    # public numpy accessors: copies of the active fluid particles (rows 0..num_fluid-1, in the
    # current sort order; ``ids()`` gives each row's stable id)
    def _copy(self, array):
        out = self.host(array)  # on the CPU, Warp's numpy() is a view of the particles' memory
        return out.copy() if self.device.is_cpu else out

    def positions(self):
        """Fluid particle positions [m] as a new (num_fluid, 3) float32 numpy array.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        x = sim.positions()
        print(x[:, 1].max())  # the highest particle
        ```
        """
        return self._copy(self.fluid.x)

    def velocities(self):
        """Fluid particle velocities [m/s] as a new (num_fluid, 3) float32 numpy array.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.run(frames=2)
        speed = (sim.velocities() ** 2).sum(axis=1) ** 0.5
        ```
        """
        return self._copy(self.fluid.v)

    def densities(self):
        """Fluid particle densities [kg/m^3] as a new (num_fluid,) float32 numpy array.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.step()
        print(sim.densities().mean() / sim.scene.fluid.density)  # about 1
        ```
        """
        return self._copy(self.fluid.density)

    def ids(self):
        """Stable particle ids (int32, unchanged by re-sorting) of the rows of :meth:`positions`.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.run(frames=2)
        x = sim.positions()[sim.ids().argsort()]  # rows in id order, frame after frame
        ```
        """
        return self._copy(self.fluid.ids)

    def field_values(self, name):
        """A published per-particle field (:meth:`fields`) of the rows of :meth:`positions`, as numpy.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.step()
        rho = sim.field_values("density")  # aligned with sim.positions()
        ```
        """
        return self._copy(self.fields()[name])

    def parts(self):
        """The simulations whose particles together make this one: itself (a DecomposedSimulation: its
        subdomains). Writers and diagnostics read each part's first ``num_fluid`` rows."""
        return [self]

    def kinetic_energy(self):
        """Kinetic energy of the fluid [J], summed on the host in float64.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        energy = []
        sim.run(frames=3, on_frame=lambda sim, frame: energy.append(sim.kinetic_energy()))
        ```
        """
        v = self.velocities().astype(np.float64)
        return 0.5 * self.particle_mass * float(np.sum(v * v))

    def array(self, owner, data, dtype):
        return self.state.array(owner, data, dtype)

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
        self.pressure_solver.reorder(order)
        for m in self.models:
            m.reorder(self.model_context, order)

    def _spin(self):
        """(angular velocity array, micro-inertia) of the first model that carries its own spin, or None."""
        return next((m.spin() for m in self.turbulence_models if m.spin() is not None), None)

    def _removed(self):
        """The particles removed so far, inside sinks and outside an open domain."""
        return self.inflow.removed_in_sinks + self.inflow.removed_outside if self.inflow is not None else 0

    def _emitted(self, first, count):
        """Rows ``first .. first + count - 1`` hold particles an emitter just added: the models mark them new."""
        for m in getattr(self, "models", ()):
            m.emitted(self.model_context, first, count)  # no history: skip their first correction

    # -- the step --------------------------------------------------------------------------------------
    def step(self):
        """One step with its models (VR paper Algorithm 2; SPlisHSPlasH's step order).

        The divergence correction of Algorithm 1 runs at the start of the step, on the
        densities of the new positions: it turns v^n (advected at the end of the last
        step) into the divergence-free v~ that the models refine. IISPH has no divergence
        correction and no free-surface pass (no-ops): its one solve is the density solve
        after the non-pressure forces, where DFSPH's is, as SPlisHSPlasH's TimeStepIISPH orders it.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.step()  # one adaptive time step
        print(sim.time, sim.statistics()["density_iterations"])
        ```
        """
        with wp.ScopedDevice(self.device):
            # t^n, read from the device once for the emitters and the bodies' poses
            now = self.time if self.inflow is not None or self.moving_bodies is not None else None
            if self.inflow is not None:
                with self.timer("inflow"):  # sinks remove, emitters add: the count changes here only
                    self.inflow.update(self._inflow_context, now)
            interval = self.scene.solver.sort_interval
            if interval and self.step_count % interval == 0:
                with self.timer("sort"):
                    self.sort_particles()
            if self.moving_bodies is not None:
                with self.timer("bodies"):  # boundary samples at the bodies' poses at t^n
                    self.moving_bodies.place(now)
                    self.neighbours.rebuild_boundary_grid()
            if self.halo is not None:
                with self.timer("halo"):  # particles cross to their subdomain; ghost rows from the others
                    self.halo.refresh(self)
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
            before = Counter(self.launches)
            with wp.ScopedCapture(device=self.device) as capture:
                self._solve_step()
            self._graph = capture.graph
            self._graph_generation = key
            self._graph_launches = self.launches - before  # what one replay launches
        else:
            self.launches.update(self._graph_launches)
        wp.capture_launch(self._graph)

    def _solve_step(self):
        f, n, t = self.fluid, self.num_fluid, self.timer
        with t("density"):  # rho^n, the DFSPH factor and the free surface at x^n (IISPH: rho^n only)
            self._compute_density()
            self.pressure_solver.detect_free_surface()
        with t("time_step"):  # CFL condition on |v^n + g dt^(n-1)| and the moving bodies' speeds (SPlisHSPlasH's)
            self.max_speed_sq.zero_()
            self.launch(compute_max_speed, REDUCE_THREADS, [f.v, n, self.gravity, self.dt, self.viscous_rate,
                                                            self.max_speed_sq])
            moving = self.boundary.v.shape[0]
            if moving:
                self.launch(compute_max_body_speed, REDUCE_THREADS, [self.boundary.v, moving, self.max_speed_sq])
            self.allreduce((self.max_speed_sq, "m" * self.max_speed_sq.shape[0]))
            tm = self.scene.time
            self.launch(compute_time_step, 1,
                        [self.max_speed_sq, self.scene.particle_diameter, tm.cfl, *self.scene.time_step_bounds,
                         tm.fixed_dt or 0.0, self.viscous_dt, self.max_viscous_substeps, self._dt_scale, self.dt_previous,
                         self.dt, *self.viscous_substeps])
        with t("divergence_solve"):  # v~ = correctDivergence(v)
            self.pressure_solver.correct_divergence()
        with t("non_pressure"):  # a_adv = a_vis; turbulence models refine v~ (Algorithm 2)
            f.acceleration.zero_()
            # zeta~ = curl v~, once for all models: in the viscosity pass when there is one
            if self.vorticity_field is not None and not any(m.computes_vorticity for m in self.models):
                self.vorticity_field.update(self)
            for model in self.models:
                model.step(self.model_context)
        with t("advection"):  # v_adv = v~ + dt (a_adv + g)
            self.launch(predict_velocity, n, [f.acceleration, self.gravity, self.dt, f.v])
            self.exchange(f.v)
        with t("density_solve"):  # projection: rho*(x + dt v_adv) -> rho0 (IISPH: its whole pressure solve)
            self.pressure_solver.correct_density()
        with t("integration"):  # x^{n+1} = x^n + dt v
            self.launch(advect_positions, n, [f.v, self.dt, self.neighbours.lower, self.neighbours.period, self.inside_lo,
                                              self.inside_hi, f.x])
            self.pressure_solver.shift_particles()  # particle shifting (no-op when off)
            self.launch(advance_clock, 1, [self.dt, self.time_device, self.steps_device])
        with t("health"):  # NaN/inf, escaped particles, runaway density: counted on the device
            self.health.check()

    def _place_volume_maps(self):
        """Each fluid particle's points of the volume maps at the bodies' poses now (before the boundary list)."""
        self.volume_maps.place(self.launch, self.fluid.x, self.num_fluid, self.moving_bodies, self.boundary,
                               self.constants)

    def update_densities(self):
        """Neighbour lists, densities (and DFSPH factors) for the current positions (the initial state, a
        restored checkpoint); the step computes its own."""
        with wp.ScopedDevice(self.device):
            self.neighbours.update(self.fluid.x)
            self._compute_density()

    def _compute_density(self):
        f = self.fluid
        self.launch(compute_density_and_factor, self.num_fluid,
                    [f.x, self.neighbours.lists, self.boundary.samples, self.fluid_volume, self.rest_density,
                     self.support_radius, f.density, f.factor, *self.pressure_solver.density_pass_outputs(),
                     self.scene.fluid.viscosity, self.scene.fluid.boundary_viscosity, self.viscous_rate])
        self.exchange(f.density)

    # -- host views -------------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time [s] (reads the device clock).

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.run(frames=2)
        print(f"t = {sim.time:.3f} s")  # 2 frames at 25 fps: 0.08 s
        ```
        """
        return float(self.time_device.numpy()[0])

    def check_health(self):
        """The first failed health check of the last step as an :class:`InstabilityError`, or None.

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.step()
        assert sim.check_health() is None  # healthy (run() raises it after a step)
        ```
        """
        return self.health.first_failure()

    # -- state: what a checkpoint keeps and a retried step restores -----------------------------------------
    def state_arrays(self):
        """Every device array that carries state from one step to the next, by name (``State.carried``)."""
        return dict(self.state.carried)

    def state_flags(self):
        """Host-side state: step and frame counters, the particle count and the models' flags."""
        out = self.state.counters()
        if self.inflow is not None:
            out.update(self.inflow.state())
        for m in self.turbulence_models:
            out.update({f"{m.name}.{k}": v for k, v in m.flags().items()})
        return out

    def restore_flags(self, flags):
        self.state.restore_counters(flags)
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

    def _advance_to(self, target, on_step=None):
        """Steps until ``time >= target``, checking health after every step (then ``on_step(self)``). With
        ``on_instability == "reduce-dt"`` a frame that fails is undone (to the state at its start,
        where the damage had not begun) and redone with dt halved, up to health.RETRIES times."""
        snapshot = self._snapshot() if self.on_instability == "reduce-dt" else None
        try:
            for attempt in range(health.RETRIES + 1):
                try:
                    while self.time < target - 1e-9:
                        self.step()
                        problem = self.check_health()
                        if problem is not None:
                            raise problem
                        if on_step is not None:
                            on_step(self)
                    return
                except InstabilityError:
                    if snapshot is None or attempt == health.RETRIES:
                        raise
                    self._restore(snapshot)
                    self._dt_scale *= 0.5
        finally:
            self._dt_scale = 1.0

    def run(self, frames=None, on_frame=None, until_time=None, on_step=None):
        """Advances to output frame ``frames`` at the scene's fps (or to ``until_time``), calling
        ``on_frame(sim, frame)`` after the initial state and each frame, and ``on_step(sim)`` after each step that
        passed its health check (a measurement over every step; with ``on_instability`` "reduce-dt" the steps of a
        frame that is redone are reported again). A simulation restored from a checkpoint continues after its last
        frame (``self.frame``).

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.run(frames=5, on_frame=lambda sim, frame: print(frame, sim.time))  # frames 0 (the start) .. 5
        sim.run(until_time=0.4)  # continues after frame 5
        ```
        """
        fps = self.scene.output.fps
        frames = self.scene.output.frames if frames is None and until_time is None else frames
        if until_time is not None:
            frames = int(np.ceil(until_time * fps - 1e-9))
        if on_frame is not None and self.frame == 0 and self.step_count == 0:
            on_frame(self, 0)
        for frame in range(self.frame + 1, frames + 1):
            target = frame / fps
            self._advance_to(target, on_step)
            self.frame = frame
            if on_frame is not None:
                on_frame(self, frame)
        return self

    def statistics(self):
        """Solver iterations per solve, the last average errors and the particles removed so far
        (inside sinks; outside an open domain).

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        sim.run(frames=1)
        print(sim.statistics())  # {'steps': ..., 'density_iterations': ..., 'density_error': ..., ...}
        ```
        """
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
        """Per-particle fields by name, for every writer (USD, checkpoints, plots).

        Example:

        ```python
        import warpsph

        sim = warpsph.Simulation(warpsph.load_scene("scenes/dam_break.json", scale=0.05))
        print(sorted(sim.fields()))  # ['density', ...]: Warp arrays over the rows
        ```
        """
        out = {"density": self.fluid.density}
        if self.vorticity_field is not None:
            out["vorticity"] = self.vorticity_field.vorticity
        for m in self.models:
            out.update(m.fields())
        return out
