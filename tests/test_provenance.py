"""The commit recorded by the benchmarks and validation: one helper, WARPSPH_COMMIT first (#24: a copy of the tree
on the GPU machine has a stale .git, and the tools recorded its commit)."""

import re
from pathlib import Path

from warpsph.validation.cases import commit_info

ROOT = Path(__file__).resolve().parent.parent


def test_warpsph_commit_overrides_git(monkeypatch):
    monkeypatch.setenv("WARPSPH_COMMIT", "0123abc")
    assert commit_info() == {"commit": "0123abc"}


def test_git_commit_without_the_variable(monkeypatch):
    monkeypatch.delenv("WARPSPH_COMMIT", raising=False)
    info = commit_info()
    if (ROOT / ".git").exists():
        assert re.fullmatch(r"[0-9a-f]{4,40}", info["commit"] or "") and isinstance(info["uncommitted"], list)
    else:
        assert info == {"commit": None}


def test_tools_record_the_commit_through_commit_info():
    """No tool asks git itself: each records warpsph's commit_info (so WARPSPH_COMMIT reaches every report)."""
    sources = [ROOT / "tools" / "bench_internals.py"]  # kernels and floor (were profile_kernels.py, probe_floor.py)
    sources += [ROOT / "warpsph" / "validation" / f"{name}.py" for name in ("bench_job", "bench", "pareto")]
    for source in sources:
        name, text = source.stem, source.read_text()
        assert "rev-parse" not in text, name
        assert "commit_info" in text, name
