"""Thin wrapper: the benchmark lives in warpsph/validation/bench.py (``warpsph bench steps``; see its docstring)."""

import sys

from warpsph.validation.bench import *  # noqa: F401,F403  (the names scripts imported from here)
from warpsph.validation.bench import main

if __name__ == "__main__":
    sys.exit(main())
