"""``python -m warpsph``: the command line (:mod:`warpsph.cli`)."""

import sys

from warpsph.cli import main

sys.exit(main())
