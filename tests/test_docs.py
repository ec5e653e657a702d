"""The documentation site (mkdocs.yml, docs/) builds with warnings as errors: a broken link or anchor,
an API reference (mkdocstrings) or a cross-reference to something that does not exist fails.
Offline and without Warp on the GPU (the API pages are read statically by griffe)."""

import importlib
import importlib.util
import inspect
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _installed(module):
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # its parent package is missing
        return False


MISSING = [m for m in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python") if not _installed(m)]
pytestmark = [pytest.mark.skipif(bool(MISSING), reason=f"the docs build needs {', '.join(MISSING)}: "
                                                       f"pip install -e '.[docs]' (the test extra has them)"),
              pytest.mark.slow]  # each test builds the site (seconds)


def build(root, site):
    """``mkdocs build --strict`` of the site under ``root`` into ``site``; the completed process."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site),
                           "--config-file", str(root / "mkdocs.yml")],
                          cwd=root, env=env, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site of this checkout, built once: (the completed build, the site folder)."""
    folder = tmp_path_factory.mktemp("docs") / "site"
    return build(ROOT, folder), folder


def test_site_builds_strict(site):
    done, site = site
    assert done.returncode == 0, done.stdout + done.stderr
    for page in ("index.html", "getting-started/index.html", "scene-reference/index.html", "output/index.html",
                 "models/vorticity-refinement/index.html", "validation/index.html", "notes/solver/index.html"):
        assert (site / page).is_file(), page
    simulation = (site / "api/simulation/index.html").read_text()
    for name in ("Simulation", "positions", "kinetic_energy", "run"):
        assert name in simulation, name
    assert "UsdWriter" in (site / "api/io/index.html").read_text()
    assert "particle_radius" in (site / "scene-reference/index.html").read_text()


def copy_site(tmp_path):
    """A copy of the site's sources (the packages linked, not copied) to break."""
    root = tmp_path / "src"
    shutil.copytree(ROOT / "docs", root / "docs")
    shutil.copy(ROOT / "mkdocs.yml", root / "mkdocs.yml")
    for package in ("warpsph", "kernels"):
        (root / package).symlink_to(ROOT / package, target_is_directory=True)
    return root


@pytest.mark.parametrize("page, text, expected", [
    ("index.md", "\n[a page](no-such-page.md)\n", "no-such-page.md"),
    ("index.md", "\n[an anchor](guide.md#no-such-anchor)\n", "no-such-anchor"),
    ("index.md", "\n[a symbol][warpsph.scene.NoSuchThing]\n", "warpsph.scene.NoSuchThing"),
    ("api/warpsph.md", "\n::: warpsph.no_such_module\n", "warpsph.no_such_module"),
], ids=["link", "anchor", "cross-reference", "mkdocstrings"])
def test_broken_docs_fail_the_build(tmp_path, page, text, expected):
    root = copy_site(tmp_path)
    with open(root / "docs" / page, "a") as f:
        f.write(text)
    done = build(root, tmp_path / "site")
    assert done.returncode != 0
    assert expected in done.stdout + done.stderr


PUBLIC_MODULES = ("warpsph", "warpsph.io", "warpsph.models", "warpsph.surface")
INTERNAL = ({f"warpsph.simulation.Simulation.{name}" for name in (
    "exchange", "allreduce", "per_particle", "scratch", "active", "host", "permute", "parts", "global_count",
    "sort_particles", "reorder_particles", "update_densities", "state_arrays", "state_flags", "restore_flags", "launch",
    "array", "zeros")}
    | {f"warpsph.scene.{name}" for name in ("parse_dataclass", "parse_model", "key", "schema", "shown", "read_text",
                                            "parse_json", "key_path", "with_overrides", "rescale", "model_types")}
    | {f"warpsph.io.usd.{name}" for name in ("UsdPointCache", "UsdClipCache", "frame_writer", "write_host_frame",
                                             "check_space", "run_metadata", "body_meshes", "write_surface")}
    | {f"warpsph.surface.{name}" for name in ("BackgroundMesher", "ProcessMesher", "mesher_for", "require_pysplashsurf")}
    | {"warpsph.decomposition.Subdomain", "warpsph.decomposition.device_names",
       "warpsph.decomposition.DecomposedSimulation.reads_directly", "warpsph.simulation.StageTimer"})


def documented(site):
    """The dotted paths of the objects the API pages document (their headings' ids)."""
    ids = set()
    for page in (site / "api").glob("*/index.html"):
        ids.update(re.findall(r'id="(warpsph(?:\.[A-Za-z_][A-Za-z0-9_]*)*)"', page.read_text()))
    return ids


def exported(module_name):
    """(the name under the module, the path where it is defined) of each name in a public module's __all__."""
    module = importlib.import_module(module_name)
    for name in module.__all__:
        obj = getattr(module, name)
        if isinstance(obj, str):  # __version__
            continue
        where = obj.__name__ if inspect.ismodule(obj) else (
            f"{obj.__module__}.{obj.__qualname__}" if hasattr(obj, "__qualname__") else f"{module_name}.{name}")
        yield f"{module_name}.{name}", where


def test_the_api_reference_is_the_public_api_with_docstrings(site):
    """The API pages show the public modules' exports (the surface API too), each with a docstring, and nothing
    internal: no _name and none of the methods and helpers that serve the command line or the stepper."""
    griffe = pytest.importorskip("griffe", reason="reading the API pages' objects needs griffe (mkdocstrings-python installs it)")
    done, site = site
    assert done.returncode == 0, done.stdout + done.stderr
    ids = documented(site)
    assert not sorted(i for i in ids if any(part.startswith("_") for part in i.split("."))), ids
    assert not sorted(ids & INTERNAL)
    for module in PUBLIC_MODULES:
        for name, where in exported(module):
            assert {name, where} & ids, f"{name} ({where}) is public but not in the API reference"
    package = griffe.GriffeLoader(search_paths=[str(ROOT)]).load("warpsph")
    for path in sorted(ids - {"warpsph"}):
        obj = package[path.removeprefix("warpsph.")]
        assert obj.docstring is not None and obj.docstring.value.strip(), f"{path} has no docstring"


def listed_members():
    """The dotted paths of the members the API pages list by name (``members:`` of a ``:::`` directive)."""
    import yaml

    listed = set()
    for page in (ROOT / "docs" / "api").glob("*.md"):
        for target, block in re.findall(r"^::: (\S+)\n((?:[ \t]+\S.*\n?)*)", page.read_text(), re.MULTILINE):
            members = ((yaml.safe_load(block) or {}).get("options") or {}).get("members")
            listed.update(f"{target}.{name}" for name in members or ())
    return listed


def test_every_public_name_on_the_api_pages_has_an_example(site):
    """Each public module, each module-level name on the API pages (class, function, exception, constant) and each
    class member a page lists by name has an example in its docstring (an ``Example:`` with a fenced python block:
    tests/test_api_examples.py runs them). A class's other members are shown by the class's example, and the
    submodules that only group a page's names by theirs."""
    griffe = pytest.importorskip("griffe", reason="reading the API pages' objects needs griffe (mkdocstrings-python installs it)")
    from test_api_examples import examples

    done, site = site
    assert done.returncode == 0, done.stdout + done.stderr
    package = griffe.GriffeLoader(search_paths=[str(ROOT)]).load("warpsph")
    listed = listed_members()
    needed, missing = [], []
    for path in sorted(documented(site)):
        obj = package if path == "warpsph" else package[path.removeprefix("warpsph.")]
        if (path in PUBLIC_MODULES if obj.is_module else obj.parent.is_module or path in listed):
            needed.append(path)
            if not examples(obj.docstring.value if obj.docstring else ""):
                missing.append(path)
    assert len(needed) > 60, needed  # the enumeration itself works
    assert not missing, f"{len(missing)} of {len(needed)} public names on the API pages have no example: {missing}"
