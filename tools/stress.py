"""Thin wrapper: the stress matrix lives in warpsph/validation/stress.py (``warpsph stress``; see its docstring)."""

import sys

from warpsph.validation.stress import *  # noqa: F401,F403  (the names scripts imported from here)
from warpsph.validation.stress import main

if __name__ == "__main__":
    sys.exit(main())
