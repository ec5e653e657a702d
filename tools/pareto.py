"""Thin wrapper: the cost-against-accuracy study lives in warpsph/validation/pareto.py (see its docstring)."""

import sys

from warpsph.validation.pareto import *  # noqa: F401,F403  (the names scripts imported from here)
from warpsph.validation.pareto import main

if __name__ == "__main__":
    sys.exit(main())
