"""The documentation site (mkdocs.yml, docs/) builds with warnings as errors: a broken link or anchor,
an API reference (mkdocstrings) or a cross-reference to something that does not exist fails.
Offline and without Warp on the GPU (the API pages are read statically by griffe)."""

import importlib.util
import os
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
pytestmark = pytest.mark.skipif(bool(MISSING), reason=f"the docs build needs {', '.join(MISSING)}: "
                                                      f"pip install -e '.[docs]' (the test extra has them)")


def build(root, site):
    """``mkdocs build --strict`` of the site under ``root`` into ``site``; the completed process."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site),
                           "--config-file", str(root / "mkdocs.yml")],
                          cwd=root, env=env, capture_output=True, text=True, timeout=600)


def test_site_builds_strict(tmp_path):
    site = tmp_path / "site"
    done = build(ROOT, site)
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
