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

from .base import DEFAULT_SOLVER, SOLVERS, PressureSolver, SolverContext, register_solver  # noqa: F401


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
