"""The validation cases' layout (issue #41): each case of ``warpsph validate`` is a package of its own with a README
and, where its reference is data, a ``reference.json`` loaded through the package (so a wheel carries it); the
package list and package data of pyproject.toml name them all; every result file a case's README names exists."""

import json
import re
import subprocess
import sys
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from warpsph.validation.cases import CASES
from warpsph.validation.dam_front import MARTIN_MOYCE
from warpsph.validation.sinking import wall_factor

ROOT = Path(__file__).resolve().parent.parent
VALIDATION = ROOT / "warpsph" / "validation"
# ``warpsph validate`` case -> its package under warpsph/validation/
FOLDERS = {"taylor-green": "taylor_green", "lamb-oseen": "lamb_oseen", "vortex-surface": "lamb_oseen",
           "standing-wave": "standing_wave", "hydrostatic": "hydrostatic", "dam-front": "dam_front",
           "tank-at-rest": "rest", "sinking-sphere": "sinking",
           "poiseuille": "poiseuille"}
# the cases that bring a command line of their own (``python -m warpsph.validation.NAME``)
COMMANDS = ("taylor_green", "lamb_oseen", "hydrostatic", "dam_front")


def _pyproject():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _results_branch():
    """The file names under tools/results/ on the ``results`` branch (empty where this clone lacks it)."""
    done = subprocess.run(["git", "ls-tree", "-r", "--name-only", "results", "tools/results/"], cwd=ROOT,
                          capture_output=True, text=True)
    return {Path(line).name for line in done.stdout.split()} if done.returncode == 0 else set()


def test_every_case_is_a_package_with_a_readme_that_names_its_command():
    assert set(FOLDERS) == set(CASES)
    for case, folder in FOLDERS.items():
        package = VALIDATION / folder
        assert (package / "__init__.py").is_file(), case
        assert not (VALIDATION / f"{folder}.py").exists(), f"{folder}.py beside the package {folder}/"
        readme = (package / "README.md").read_text()
        assert f"warpsph validate {case} " in readme, f"{folder}/README.md does not show `warpsph validate {case}`"
        for heading in ("**Compared:**", "**Reference:**", "**The numbers:**", "**Results:**"):
            assert heading in readme, f"{folder}/README.md lacks {heading}"
        if folder in COMMANDS:
            assert (package / "__main__.py").is_file() and f"python -m warpsph.validation.{folder}" in readme
    index = (VALIDATION / "README.md").read_text()
    for case, folder in FOLDERS.items():
        assert f"`{case}`" in index and f"`{folder}/`" in index, case


def test_reference_data_loads_through_the_package():
    """importlib.resources, as an installed wheel reads it: the Martin & Moyce points and Haberman & Sayre's wall
    factor are the data files' numbers."""
    dam = json.loads(resources.files("warpsph.validation.dam_front").joinpath("reference.json").read_text())
    points = np.array(dam["series"]["a = 2.25 in"]["points"])
    assert points.shape == (12, 2) and np.array_equal(points, MARTIN_MOYCE)
    assert "Martin" in dam["reference"] and "1952" in dam["reference"]
    assert np.all(np.diff(points, axis=0) > 0)  # T and the front both advance
    sinking = json.loads(resources.files("warpsph.validation.sinking").joinpath("reference.json").read_text())
    assert "Haberman" in sinking["reference"]
    r = 0.1
    expected = (sum(c * r ** int(n) for n, c in sinking["wall_factor"]["numerator"].items())
                / sum(c * r ** int(n) for n, c in sinking["wall_factor"]["denominator"].items()))
    assert wall_factor(r) == pytest.approx(expected, rel=1e-15)


def test_pyproject_ships_every_package_and_its_data():
    """Every folder of warpsph/ with an __init__.py is in [tool.setuptools] packages (the list is explicit), and
    every file of a validation case that is not Python is in its package data."""
    config = _pyproject()
    packages = set(config["packages"])
    for init in (ROOT / "warpsph").rglob("__init__.py"):
        folder = init.parent.relative_to(ROOT)
        if folder.parts[:2] == ("warpsph", "kernels"):  # kernels/ ships as warpsph.kernels (package-dir)
            continue
        assert ".".join(folder.parts) in packages, f"{folder} is not in pyproject.toml's packages"
    data = config.get("package-data", {})
    for path in VALIDATION.rglob("*"):
        if path.is_dir() or path.suffix in (".py", ".pyc") or "__pycache__" in path.parts:
            continue
        package = ".".join(path.parent.relative_to(ROOT).parts)
        assert path.name in data.get(package, []), f"{path.relative_to(ROOT)} is not in {package}'s package-data"


def test_the_result_files_a_case_names_exist():
    """A result file a case's README names is in tools/results/ or tests/data/, or on the results branch (where this
    clone has it)."""
    archived = _results_branch()
    for folder in sorted(set(FOLDERS.values())):
        readme = (VALIDATION / folder / "README.md").read_text()
        for name in re.findall(r"`([\w./-]+\.json)`", readme):
            if "/" not in name or name.startswith("tools/results/"):
                base = Path(name).name
                if base == "reference.json":
                    assert (VALIDATION / folder / base).is_file(), (folder, name)
                    continue
                here = (ROOT / "tools" / "results" / base).is_file()
                assert here or base in archived or not archived, f"{folder}/README.md names {name}: not found"
            else:
                assert (ROOT / name).is_file(), f"{folder}/README.md names {name}: not found"


@pytest.mark.parametrize("folder", COMMANDS)
def test_a_case_runs_as_a_module(folder):
    done = subprocess.run([sys.executable, "-m", f"warpsph.validation.{folder}", "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: python -m warpsph.validation.{folder}")
