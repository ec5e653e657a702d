"""Energy over time for several runs in one PNG: same as ``warpsph plot energy`` (kept for scripts).

    python tools/plot_energy.py out/dfsph.stats.csv out/vr.stats.csv --labels DFSPH VR --out energy.png
"""

import sys

from warpsph.cli import main

if __name__ == "__main__":
    sys.exit(main(["plot", "energy", *sys.argv[1:]]))
