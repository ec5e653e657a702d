"""Thin wrapper: the case lives in warpsph/validation/taylor_green.py (see its docstring; `warpsph validate` runs it
with the default solver over several resolutions)."""

import sys

from warpsph.validation.taylor_green import *  # noqa: F401,F403  (the names scripts imported from here)
from warpsph.validation.taylor_green import main

if __name__ == "__main__":
    sys.exit(main())
