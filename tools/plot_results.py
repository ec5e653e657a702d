"""Thin wrapper: ``warpsph plot results RESULT.json ...`` (warpsph/validation/results.py) draws a result file's
figures from its JSON."""

import sys

from warpsph.validation.results import main

if __name__ == "__main__":
    sys.exit(main())
