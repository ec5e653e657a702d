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

What the stepper (:class:`~warpsph.simulation.Simulation`) calls on an instance, made with ``cls(sim)``:
``detect_free_surface()``, ``correct_divergence()``, ``correct_density()``, ``shift_particles()``,
``reorder(sim, order)``, ``density_pass_outputs()``, and for the statistics and the health check
``iteration_totals()``, ``last_errors()``, ``pressure_field()``, ``free_surface_count()`` and
``max_iteration_streak``; :class:`PressureSolver` has the do-nothing parts.
"""

from __future__ import annotations

SOLVERS = {}  # name -> class
DEFAULT_SOLVER = "dfsph"  # a scene's solver.method when it names none


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

    def reorder(self, sim, order):
        """Permutes its per-particle state when the fluid is re-sorted; nothing by default."""


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
