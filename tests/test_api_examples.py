"""The usage examples in the public API's docstrings run as written.

An example is an ``Example:`` line followed by a fenced ```` ```python ```` block. Each is self-contained (its own
imports, a small scene: ``scale=`` or a tiny dict) and runs from a folder where ``scenes/`` is the repository's
(so ``"scenes/dam_break.json"`` works) and every file it writes lands in a temporary folder. It runs on the CPU
(Warp's default device is set to "cpu"); a model it registers is unregistered after it. A line ``# needs: MODULE`` in an example skips it when MODULE is not
installed (``# needs: pysplashsurf``). tests/test_docs.py checks that every public name on the API pages has one.
"""

import importlib.util
import re
import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = re.compile(r"^Example:\s*\n\s*\n?```python\n(.*?)\n```", re.MULTILINE | re.DOTALL)
NEEDS = re.compile(r"#\s*needs:\s*([\w.]+)")


def examples(docstring):
    """The code of each example in a docstring's text (griffe's cleaned value or ``inspect.cleandoc``'s)."""
    return [m.group(1) for m in EXAMPLE.finditer(docstring or "")]


def documented_objects():
    """(dotted path, docstring) of every module, class, function and attribute that warpsph defines (griffe reads
    the sources; nothing is imported), aliases left out."""
    griffe = pytest.importorskip("griffe", reason="reading the docstrings needs griffe (mkdocstrings-python installs it)")
    package = griffe.GriffeLoader(search_paths=[str(ROOT)]).load("warpsph")
    found, todo = [], [package]
    while todo:
        obj = todo.pop()
        found.append((obj.path, obj.docstring.value if obj.docstring else ""))
        todo.extend(member for member in obj.members.values() if not member.is_alias)
    return sorted(found)


def collected():
    if importlib.util.find_spec("griffe") is None:
        return [pytest.param(None, None, marks=pytest.mark.skip(reason="collecting the examples needs griffe"))]
    cases = []
    for path, docstring in documented_objects():
        for n, code in enumerate(examples(docstring)):
            cases.append(pytest.param(path, code, id=path + (f"#{n + 1}" if n else "")))
    return cases


@pytest.mark.slow  # some seventy examples, a simulation of a few hundred particles in many (about a minute)
@pytest.mark.parametrize("path, code", collected())
def test_api_example_runs(path, code, tmp_path, monkeypatch):
    import warp as wp

    for module in NEEDS.findall(code):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"the example of {path} needs {module}")
    (tmp_path / "scenes").symlink_to(ROOT / "scenes", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    script = tmp_path / "example.py"  # a file, so that a @wp.kernel in an example finds its source
    script.write_text(code + "\n")
    from warpsph.models import REGISTRY

    registered = dict(REGISTRY)  # a plug-in an example registers is gone after it
    before = wp.get_device()
    wp.set_device("cpu")
    try:
        runpy.run_path(str(script), run_name="example_" + re.sub(r"\W", "_", path))
    finally:
        wp.set_device(before)
        REGISTRY.clear()
        REGISTRY.update(registered)
