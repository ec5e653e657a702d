"""Pressure solvers, each a plug-in, as the models are (:mod:`warpsph.models`).

This package is the registry and the base class; each shipped solver is a module of it with its kernels in
``kernels/``: :mod:`warpsph.solvers.dfsph` (DFSPH, the default) and :mod:`warpsph.solvers.iisph` (IISPH). A solver
is a class registered under the name scenes give in ``solver.method`` (``@register_solver("name")`` is the whole
registration; ``tests/test_solvers.py`` defines one in the test file). It declares what the rest of warpsph asks
of it, so that nothing else names a solver:

- ``Parameters``: its own keys of the scene's ``solver`` block, a schema class made with
  :func:`warpsph.scene.schema` and :func:`warpsph.scene.key` (units, ranges), as a model's; None: none. The
  block stays flat: the keys every solver reads (:class:`warpsph.scene.Solver`: ``method``, the density
  solve's tolerance and iterations, ``warm_start``, ...) beside the chosen solver's, and a key of another solver
  is refused naming it. ``scene.solver`` has both as attributes (``scene.solver.shifting`` with DFSPH);
- ``summary``: one line for the scene schema and the CLI's help;
- ``kernel_modules(scene)``: the Warp modules it launches (compiled before the first step, :mod:`warpsph.warmup`);
- ``bytes_per_particle(scene)``: device bytes per fluid particle of its arrays and of the fluid state it needs
  (the memory check before a run, :mod:`warpsph.resources`), and ``columns(scene)``: floats per particle it takes
  from the scratch pool it shares with the models;
- ``needs_factor``: whether the density pass writes DFSPH's factor for it;
- ``detects_free_surface``: whether it tells the free surface from the bulk (the viscosity runs its corrected
  operator in the bulk then, :meth:`~warpsph.models.viscosity.Viscosity.takes_corrected_operator`);
- ``splishsplash_method``: SPlisHSPlasH's ``Configuration.simulationMethod`` it stands for (the importer);
- ``decomposable``: whether it runs over subdomains (:mod:`warpsph.decomposition`);
- ``couples_bodies``: whether it moves the dynamic bodies inside its pressure iterations
  (:meth:`~warpsph.bodies.MovingBodies.couple`, strong coupling); else they take the step's impulses after it;
- ``solve_passes(divergence_iterations, density_iterations)``: its neighbour passes a step (the benchmark's k).

What the stepper (:class:`~warpsph.simulation.Simulation`) calls on an instance, made with ``cls(ctx)``:
``detect_free_surface()``, ``correct_divergence()``, ``correct_density()``, ``shift_particles()``,
``reorder(order)``, ``density_pass_outputs()``, and for the statistics and the health check
``iteration_totals()``, ``last_errors()``, ``pressure_field()``, ``free_surface_count()`` and
``max_iteration_streak``; :class:`PressureSolver` has the do-nothing parts.

``ctx`` is a :class:`SolverContext`: what a solver sees of the simulation, and nothing else (no models, no
inflow, no writers, not the simulation). A solver keeps it (``self.ctx``), allocates its arrays through
``ctx.zeros`` / ``ctx.per_particle`` (owner "pressure") and ``ctx.scratch``, registers what a step carries to the
next with ``ctx.state.carry``, and reads the rest through it when it runs: the fluid count, dt, the neighbour lists
and the gravity change after it is built.
"""

from __future__ import annotations

from dataclasses import dataclass

SOLVERS = {}  # name -> class
DEFAULT_SOLVER = "dfsph"  # a scene's solver.method when it names none


@dataclass(frozen=True)
class SolverContext:
    """What a pressure solver sees of the simulation, built by it (``Simulation``) once: the state, the constants,
    the scene's solver block, the boundary samples, the calls it launches and allocates with, the subdomains'
    exchanges, and the dynamic bodies it couples. Values that change after it is built are read when used: the
    fluid's arrays, count and clock through :attr:`state` (:attr:`fluid`, :attr:`num_fluid`, :attr:`dt`,
    :attr:`dt_previous`), and the neighbour lists, the global count and the gravity through their calls."""

    state: object  # warpsph.state.State: the fluid's arrays and count, the clock, ``carry`` and ``host``
    constants: object  # warpsph.state.Constants: volume, rest density, support, spacing, the walled faces
    parameters: object  # the scene's solver block (``scene.solver``: the common keys and the solver's own)
    boundary: object  # warpsph.simulation.BoundaryParticles (``.samples``: the kernels' Boundary struct)
    neighbour_lists: object  # () -> the kernels' Neighbours struct of this step (rebuilt as the lists grow)
    lower: object  # wp.vec3: the domain's lower corner, where the positions' wrap starts
    period: object  # wp.vec3: the domain's period per axis (0: none)
    launch: object  # (kernel, dim, inputs): on the simulation's device, counted
    scratch: object  # (dtype, column) -> a per-particle view of the scratch pool shared with the models
    permute: object  # (array, order): array[:] = array[order] over the fluid's rows (re-sorting, sinks)
    exchange: object  # (*arrays): the ghost rows' values from their owners (a no-op without subdomains)
    allreduce: object  # (*pairs, read=False): small arrays combined over the subdomains (None without them)
    global_count: object  # () -> fluid particles in the whole simulation (over every subdomain)
    gravity: object  # () -> wp.vec3 [m/s^2]: the gravity now (it may change between steps)
    max_speed_sq: object  # device array of two: this step's [max |v|^2, the CFL speed^2] (compute_max_speed)
    bodies: object = None  # warpsph.bodies.MovingBodies whose dynamic bodies move inside the pressure
    # iterations (``respond``, ``couple``, ``coupling["residual"]``), or None (none, or they do not move)

    OWNER = "pressure"  # the allocation report's owner of what a solver allocates

    fluid = property(lambda self: self.state.fluid, doc="The fluid's per-particle arrays (x, v, density, ...).")
    num_fluid = property(lambda self: self.state.num_fluid, doc="Rows that hold particles now.")
    dt = property(lambda self: self.state.dt, doc="This step's dt [s], a device array of one.")
    dt_previous = property(lambda self: self.state.dt_previous, doc="The last step's dt [s], a device array of one.")

    def zeros(self, shape, dtype=float):
        """A zeroed device array of the solver's (owner "pressure")."""
        return self.state.zeros(self.OWNER, shape, dtype)

    def per_particle(self, dtype=float):
        """A per-particle array of the solver's (owner "pressure"; zeroed where an emitter adds rows)."""
        return self.state.per_particle(self.OWNER, dtype)

    def host(self, array):
        """The particles' rows of a per-particle array, copied to the host."""
        return self.state.host(array)


def register_solver(name):
    """Class decorator that makes a pressure solver available to scenes as ``solver.method: name``.
    Re-registering a name replaces it."""

    def wrap(cls):
        cls.name = name
        SOLVERS[name] = cls
        return cls

    return wrap


class PressureSolver:
    """Base class: the declarations a solver makes and the do-nothing parts of the stepper's interface."""

    name = "solver"
    Parameters = None  # its own keys of the scene's solver block (a schema class), or None
    summary = ""
    needs_factor = False
    detects_free_surface = False
    scratch_columns = 0
    splishsplash_method = None
    decomposable = False
    couples_bodies = False

    @classmethod
    def columns(cls, scene):
        """Floats per particle it takes from the scratch pool (shared with the models)."""
        return cls.scratch_columns

    @classmethod
    def pool_columns(cls, scene):
        """Scratch columns the memory check adds for it (those its ``bytes_per_particle`` does not count)."""
        return cls.columns(scene)

    @staticmethod
    def kernel_modules(scene):
        """Names of the Warp modules it launches for ``scene``."""
        return []

    @staticmethod
    def bytes_per_particle(scene):
        """Device bytes per fluid particle it needs for ``scene``: the fluid state it reads and its own arrays."""
        return 0

    @staticmethod
    def solve_passes(divergence_iterations, density_iterations):
        """Neighbour passes of its solves in a step with these mean iteration counts (the benchmark's k)."""
        return 0

    def detect_free_surface(self):
        """Classifies the particles (surface, band, bulk) before the solves; nothing by default."""

    def correct_divergence(self):
        """The divergence solve on the velocities; nothing by default."""

    def shift_particles(self):
        """Particle shifting after the solves; nothing by default."""

    def __init__(self, ctx):
        self.ctx = ctx  # what it sees of the simulation (:class:`SolverContext`)

    def reorder(self, order):
        """Permutes its per-particle state when the fluid is re-sorted (``self.ctx.permute``); nothing by default."""


def solver_classes():
    """{name: class} of the registered pressure solvers (the shipped ones imported, so registered)."""
    from warpsph.solvers import dfsph, iisph  # noqa: F401  (register dfsph and iisph)

    return dict(SOLVERS)


def solver_class(name):
    """The registered class of ``solver.method`` ``name`` (KeyError when there is none)."""
    return solver_classes()[name]


def solver_names():
    """The names scenes may give in ``solver.method``, the default (dfsph) first."""
    names = list(solver_classes())
    return sorted(names, key=lambda n: (n != DEFAULT_SOLVER, n))


def solver_keys():
    """{key: [names of the solvers whose ``Parameters`` have it]} over the registered solvers, in
    :func:`solver_names`' order: the solver-specific keys of a scene's solver block."""
    out = {}
    classes = solver_classes()
    for name in solver_names():
        params = classes[name].Parameters
        for key in getattr(params, "__pydantic_fields__", {}) if params is not None else ():
            out.setdefault(key, []).append(name)
    return out
