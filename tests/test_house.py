"""Nothing writes into a Simulation from outside (issue #41, docs/notes/house.md "Who may touch what").

The parts around the stepper (inflow, bodies, health, packing, sweeps, benchmarks, ...) read what they need through
their own contexts or the public accessors; the fluid count, the bodies and the step are the simulation's to change.
This reads warpsph's source with ``ast`` (nothing is imported) and fails on an assignment to an attribute of a
simulation in any module but ``warpsph/simulation.py``: ``sim.X = ...`` (also ``+=``), ``self.sim.X = ...``,
``Simulation.X = ...`` (a class attribute patched), ``setattr(sim, ...)``, and ``s.X = ...`` where ``s`` runs over a
decomposed simulation's ``sims``. A simulation is recognised by its name (``sim``, ``_sim``, ``*_sim``, ``simulation``,
``subdomain``, ``part``, ``Simulation``; the loop variables over ``sims`` and ``parts()``). The public settings a
caller may change between frames (``ALLOWED``) are property setters of Simulation that check their value.
"""

import ast
import os
import re

ROOT = os.path.join(os.path.dirname(__file__), "..")
PACKAGE = os.path.join(ROOT, "warpsph")
OWNER = os.path.join("warpsph", "simulation.py")  # the class itself sets its own attributes
SIM = re.compile(r"^(_?sim|sims|simulation|\w+_sim|sim_\w+|subdomain|part|Simulation)$")
ALLOWED = {
    "gravity": "a ramp, a tilting tank: the setter drops the captured graph (docs/api/simulation.md)",
    "on_instability": "stop or reduce-dt, between frames (the CLI, the studies): the setter checks the value",
}


def _names_sim(node, loop_vars):
    """Whether ``node`` (an expression) names a simulation."""
    if isinstance(node, ast.Name):
        return bool(SIM.match(node.id)) or node.id in loop_vars
    if isinstance(node, ast.Attribute):  # self.sim, simulation.Simulation, ...
        return bool(SIM.match(node.attr))
    if isinstance(node, ast.Subscript):  # sims[0], self.sims[k]
        return _names_sim(node.value, loop_vars)
    return False


def _loop_vars(tree):
    """Names bound by ``for s in ...sims`` / ``for s in ...parts()`` (a decomposed simulation's subdomains)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.For, ast.comprehension)) and isinstance(node.target, ast.Name):
            it = node.iter.func if isinstance(node.iter, ast.Call) else node.iter
            name = it.attr if isinstance(it, ast.Attribute) else it.id if isinstance(it, ast.Name) else ""
            if name in ("sims", "parts"):
                out.add(node.target.id)
    return out


def writes(source):
    """[(line, text, attribute)] of the writes into a simulation in ``source`` (Python text)."""
    tree = ast.parse(source)
    loop_vars = _loop_vars(tree)
    found = []
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        for target in targets:
            for t in ast.walk(target):
                if isinstance(t, ast.Attribute) and isinstance(t.ctx, ast.Store) and _names_sim(t.value, loop_vars):
                    found.append((node.lineno, ast.unparse(node), t.attr))
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("setattr", "delattr")
                and node.args and _names_sim(node.args[0], loop_vars)):
            found.append((node.lineno, ast.unparse(node), None))
    return found


def _modules():
    for folder, _, files in os.walk(PACKAGE):
        if "kernels" in os.path.relpath(folder, ROOT).split(os.sep):
            continue
        for name in sorted(files):
            if name.endswith(".py"):
                yield os.path.join(folder, name)


def test_no_module_writes_into_a_simulation():
    bad = []
    for path in _modules():
        rel = os.path.relpath(path, ROOT)
        if rel == OWNER:
            continue
        with open(path) as f:
            for line, text, attribute in writes(f.read()):
                if attribute not in ALLOWED:
                    bad.append(f"{rel}:{line}: {text}")
    assert not bad, "writes into a Simulation from outside (give it a method, an option or a hook):\n" + "\n".join(bad)


def test_the_scan_finds_every_kind_of_write():
    caught = ["sim.num_fluid = n + k", "self.sim.moving_bodies = None", "sim.step = tracked", "sim.frame += 1",
              "simulation.Simulation.launch = timed", "Simulation.run = timed", "setattr(sim, 'step', f)",
              "for s in self.sims:\n    s.frame = 3", "self._sim.dt = 0", "sims[0].num_fluid = 4"]
    for text in caught:
        assert writes(text), text
    passed = ["sim.state.num_fluid = 3", "ctx.state.num_fluid = 3", "x = sim.num_fluid", "self.sim = sim",
              "setattr(owner, name, f)", "sim.fluid.v.zero_()", "for s in items:\n    s.frame = 3"]
    for text in passed:
        assert not writes(text), text


def test_allowed_settings_are_checked_property_setters():
    """What a caller may set is a property of Simulation with a setter (the class decides what a value does)."""
    with open(os.path.join(ROOT, OWNER)) as f:
        tree = ast.parse(f.read())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Simulation")
    setters = {n.name for n in cls.body if isinstance(n, ast.FunctionDef)
               for d in n.decorator_list if isinstance(d, ast.Attribute) and d.attr == "setter"}
    assert set(ALLOWED) <= setters, set(ALLOWED) - setters


def sim_names(source):
    """[(line, text)] of the places ``source`` names a simulation: ``sim``, ``self.sim``, ``_sim``, a parameter
    called so (what a pressure solver must not see: it has its ``SolverContext``)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        name = (node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute)
                else node.arg if isinstance(node, ast.arg) else None)
        if name is not None and SIM.match(name):
            found.append((node.lineno, ast.unparse(node)))
    return found


def test_the_pressure_solvers_see_their_context_not_the_simulation():
    """The solvers (warpsph/solvers/) are built with a ``SolverContext`` and read everything through it: no name of a
    simulation appears in their source (docs/notes/house.md "Who may touch what")."""
    folder = os.path.join(PACKAGE, "solvers")
    bad = []
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            with open(os.path.join(folder, name)) as f:
                bad += [f"warpsph/solvers/{name}:{line}: {text}" for line, text in sim_names(f.read())]
    assert not bad, "the pressure solvers read the simulation (add what they need to SolverContext):\n" + "\n".join(bad)
    assert sim_names("def __init__(self, sim):\n    self.sim = sim\n    n = self.sim.num_fluid")
    assert not sim_names("def __init__(self, ctx):\n    self.ctx = ctx\n    n = ctx.num_fluid")
