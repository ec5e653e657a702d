"""Thin wrapper: the case lives in warpsph/validation/hydrostatic.py (see its docstring; `warpsph validate` runs it
with the default solver over several resolutions)."""

import sys

from warpsph.validation.hydrostatic import *  # noqa: F401,F403  (the names scripts imported from here)
from warpsph.validation.hydrostatic import main

if __name__ == "__main__":
    sys.exit(main())
