"""warpsph's own modules import each other without a cycle at module level (issue #41).

The graph is read from the source with ``ast``, nothing is imported: an edge A -> B for each statement that runs
when A is imported (the module's body, and the bodies of its top-level ``if``/``try``/``with``/``class``
statements, but not of functions, nor of ``if TYPE_CHECKING:``) and imports B, one of warpsph's modules.
``from pkg import name`` imports ``pkg.name`` when that is a module, else ``pkg``. Importing a submodule also
runs its parent packages' ``__init__``, which is not counted as an edge (every package's ``__init__`` would
otherwise close a cycle with the submodules it imports). Function-level imports run later, but they close cycles
all the same: ``test_no_import_cycles_with_function_level_imports`` counts them as edges, and
``test_function_level_imports_are_allowed`` keeps them to the short list ``LAZY`` (each with its reason).
"""

import ast
import fnmatch
import os

ROOT = os.path.join(os.path.dirname(__file__), "..")
# package -> its folder: kernels/ ships as warpsph.kernels (pyproject.toml, [tool.setuptools.package-dir])
PACKAGE_DIRS = {"warpsph": os.path.join(ROOT, "warpsph"), "warpsph.kernels": os.path.join(ROOT, "kernels")}


# The imports of warpsph's own modules that run in a function, not at import: (importer, imported; fnmatch
# patterns) -> why. Everything else is imported at module level (house.md, "Imports").
LAZY = {
    ("warpsph.scene", "warpsph.models"): "the models' Parameters live beside their kernels: `import warpsph` "
                                         "(which loads the scene schema) stays free of Warp",
    ("warpsph.solvers", "warpsph.solvers.dfsph"): "the shipped pressure solvers register on first use of the "
                                                  "registry: `import warpsph` stays free of Warp",
    ("warpsph.solvers", "warpsph.solvers.iisph"): "as warpsph.solvers.dfsph",
    ("warpsph.scene", "warpsph.io.splishsplash"): "a SPlisHSPlasH file's converter (numpy, sampling) loads when one "
                                                  "is read: `import warpsph` imports pydantic, not numpy",
    ("warpsph.io", "warpsph.io.recorder"): "`io.UsdWriter` on first use: `import warpsph.io` stays free of Warp and "
                                           "USD (README)",
    ("warpsph.cli", "warpsph.io.usd"): "the CLI's start-up (every verb, --version too) stays free of USD (pxr) ...",
    ("warpsph.cli", "warpsph.io.checkpoint"): "... and of HDF5: a verb loads the writers it uses",
    ("warpsph.cli", "warpsph.io.particles_h5"): "as warpsph.io.checkpoint",
    ("warpsph.io.recorder", "warpsph.io.usd"): "the CLI imports the recorder at start-up; USD and HDF5 load when a "
                                               "run writes them",
    ("warpsph.io.recorder", "warpsph.io.checkpoint"): "as warpsph.io.usd",
    ("warpsph.io.recorder", "warpsph.io.particles_h5"): "as warpsph.io.usd",
    ("warpsph.io.usd", "warpsph.io.frames"): "the cache process (a spawned process) imports warpsph.io.usd: Warp "
                                             "stays out of it",
    ("warpsph.surface", "warpsph.io.usd"): "the spawned mesher workers import warpsph.surface: USD, HDF5 and Warp "
                                           "load only where a worker uses them",
    ("warpsph.surface", "warpsph.io.particles_h5"): "as warpsph.io.usd",
    ("warpsph.surface", "warpsph.surface_clip"): "as warpsph.io.usd (Warp)",
    ("warpsph.surface", "warpsph.kernels.surface_preview"): "as warpsph.io.usd (Warp)",
    ("warpsph.validation.bench_job", "*"): "bench job times the start-up, its imports included, stage by stage",
}


def _modules():
    """{module name: (path, is_package)} for every .py file of warpsph (and warpsph.kernels)."""
    out = {}
    for package, folder in PACKAGE_DIRS.items():
        for dirpath, dirnames, filenames in os.walk(folder):
            dirnames[:] = sorted(d for d in dirnames if d != "__pycache__" and not d.startswith("."))
            rel = os.path.relpath(dirpath, folder)
            parts = [package] + ([] if rel == "." else rel.split(os.sep))
            if not os.path.exists(os.path.join(dirpath, "__init__.py")):
                continue
            for filename in sorted(filenames):
                if not filename.endswith(".py"):
                    continue
                path = os.path.join(dirpath, filename)
                if filename == "__init__.py":
                    out[".".join(parts)] = (path, True)
                else:
                    out[".".join(parts + [filename[:-3]])] = (path, False)
    return out


def _is_type_checking(test):
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _import_statements(body, top_level=True):
    """The import statements of ``body``: (node, runs at import) for each, descending into compound statements."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, top_level
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield from _import_statements(node.body, False)
        elif isinstance(node, ast.If) and _is_type_checking(node.test):
            yield from _import_statements(node.orelse, top_level)  # the TYPE_CHECKING branch never runs
        else:
            for field in ("body", "orelse", "finalbody", "handlers", "cases"):
                children = getattr(node, field, None)
                if isinstance(children, list):
                    yield from _import_statements(children, top_level)


def _resolve(node, module, is_package, modules):
    """The warpsph modules that an import statement of ``module`` imports."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names if alias.name in modules]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module
    out = []
    for alias in node.names:
        if f"{target}.{alias.name}" in modules:
            out.append(f"{target}.{alias.name}")
        elif target in modules:
            out.append(target)
    return out


def import_graph():
    """({module: set of the warpsph modules it imports at module level}, [(module, line, target) at function
    level])."""
    modules = _modules()
    graph, function_level = {}, []
    for module, (path, is_package) in modules.items():
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), filename=path)
        edges = set()
        for node, top_level in _import_statements(tree.body):
            for target in _resolve(node, module, is_package, modules):
                if target == module:
                    continue
                if top_level:
                    edges.add(target)
                else:
                    function_level.append((module, node.lineno, target))
        graph[module] = edges
    return graph, function_level


def cyclic_components(graph):
    """The strongly connected components of ``graph`` of more than one module (each a set): the modules of
    each import one another, directly or not."""
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def strongconnect(v):  # Tarjan, iterative
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        while work:
            node, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.add(w)
                        if w == node:
                            break
                    if len(component) > 1:
                        components.append(component)

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return components


def find_cycles(graph):
    """The cycles of ``graph``: one shortest cycle through each strongly connected component of more than one
    module, as a list of module names (first == last)."""
    cycles = []
    for component in cyclic_components(graph):
        start = min(component)
        # breadth-first from start back to start, inside the component: a shortest cycle through it
        parents, frontier, found = {start: None}, [start], None
        while frontier and found is None:
            nxt = []
            for u in frontier:
                for w in sorted(graph[u] & component):
                    if w == start:
                        found = u
                        break
                    if w not in parents:
                        parents[w] = u
                        nxt.append(w)
                if found is not None:
                    break
            frontier = nxt
        path, u = [], found
        while u is not None:
            path.append(u)
            u = parents[u]
        cycles.append(path[::-1] + [start])
    return sorted(cycles)


def full_graph():
    """The import graph with the function-level imports as edges too."""
    graph, function_level = import_graph()
    full = {module: set(edges) for module, edges in graph.items()}
    for module, _, target in function_level:
        full[module].add(target)
    return full


def _lazy_reason(module, target):
    for (importer, imported), why in LAZY.items():
        if fnmatch.fnmatchcase(module, importer) and fnmatch.fnmatchcase(target, imported):
            return why
    return None


def test_graph_reads_the_package():
    graph, _ = import_graph()
    assert "warpsph.simulation" in graph and "warpsph.kernels.pressure" in graph and "warpsph.io.usd" in graph
    assert "warpsph.kernels.particles" in graph["warpsph.kernels.pressure"]  # from .particles import ...
    assert "warpsph.log" in graph["warpsph"]  # from . import log as _log: the module, not the package


def test_find_cycles():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycles({"a": {"b"}, "b": {"c", "a"}, "c": {"a"}}) == [["a", "b", "a"]]
    assert find_cycles({"a": {"b"}, "b": {"a"}, "c": {"d"}, "d": {"c"}}) == [["a", "b", "a"], ["c", "d", "c"]]


def test_no_import_cycles_at_module_level():
    graph, _ = import_graph()
    cycles = find_cycles(graph)
    components = sorted(sorted(c) for c in cyclic_components(graph))
    assert not cycles, ("import cycles at module level:\n" + "\n".join(" -> ".join(c) for c in cycles)
                        + "\nin all, the modules of each cycle:\n" + "\n".join(", ".join(c) for c in components))


def test_no_import_cycles_with_function_level_imports():
    """A function-level import hides a cycle from the import machinery, not from the design: counted here."""
    graph = full_graph()
    components = cyclic_components(graph)
    cycles = find_cycles(graph)
    assert not components, ("import cycles through function-level imports:\n" + "\n".join(" -> ".join(c) for c in cycles)
                            + "\nin all, the modules of each cycle:\n"
                            + "\n".join(", ".join(sorted(c)) for c in components))


def test_function_level_imports_are_allowed():
    """Every import of warpsph's own modules inside a function is in LAZY, with its reason; every entry of LAZY is
    still used."""
    _, function_level = import_graph()
    stray = sorted({(module, line, target) for module, line, target in function_level
                    if _lazy_reason(module, target) is None})
    assert not stray, ("function-level imports of warpsph's modules (move them to module level, or add the pair "
                       "to LAZY with its reason):\n" + "\n".join(f"{m}:{line} imports {t}" for m, line, t in stray))
    unused = [pair for pair in LAZY if not any(fnmatch.fnmatchcase(m, pair[0]) and fnmatch.fnmatchcase(t, pair[1])
                                               for m, _, t in function_level)]
    assert not unused, f"LAZY entries no import uses any more: {unused}"
