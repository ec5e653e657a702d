"""Thin wrapper: the case lives in warpsph/validation/lamb_oseen.py (see its docstring; `warpsph validate` runs it
with the default solver over several resolutions)."""

import sys

from warpsph.validation.lamb_oseen import *  # noqa: F401,F403  (the names scripts imported from here)
from warpsph.validation.lamb_oseen import main

if __name__ == "__main__":
    sys.exit(main())
