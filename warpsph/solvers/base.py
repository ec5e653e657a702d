"""The pressure solvers' base class, context and registry (:mod:`warpsph.solvers` re-exports them and loads the shipped
solvers on first use): a solver module imports this one to register, and this one imports none of them."""

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


# device bytes per fluid particle the shipped solvers declare (their ``bytes_per_particle``)
FLUID_STATE = 12 + 12 + 8 + 4 + 4 + 12  # x, v, ids, density, factor, acceleration
SOLVER = 4 * 4  # stiffness, error, two warm-start pressures
CORRECTED = 24 + 4 + 12  # DFSPH's corrected kernel gradient L_i (six floats), the corrected factor and grad C
IISPH_FLUID_STATE = FLUID_STATE - 4  # IISPH: no factor
IISPH_SOLVER = 4  # its warm-start pressure (its scratch columns are the pool shared with the models)
