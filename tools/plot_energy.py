"""Energy over time for several runs in one PNG (like Fig 7 of the VR paper).

    python tools/plot_energy.py out/dfsph.stats.csv out/vr.stats.csv --labels DFSPH VR --out energy.png

Reads the diagnostics CSVs that ``warpsph run`` writes beside its USD cache and plots
kinetic, kinetic + potential, and rotational energy and enstrophy against time.
Needs matplotlib (``pip install matplotlib``), which the simulator itself does not.
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from warpsph.diagnostics import read_csv  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("csv", nargs="+", help="diagnostics CSV files (*.stats.csv)")
    parser.add_argument("--labels", nargs="+", help="one label per file (default: file names)")
    parser.add_argument("--out", default="energy.png")
    args = parser.parse_args(argv)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.exit("plot_energy: matplotlib is needed for plots: pip install matplotlib")
    labels = args.labels or [Path(p).name.replace(".stats.csv", "") for p in args.csv]
    if len(labels) != len(args.csv):
        sys.exit("plot_energy: give one label per CSV file")
    panels = [("kinetic_energy", "kinetic energy [J]"), ("total", "kinetic + potential [J]"),
              ("rotational_energy", "rotational energy [J]"), ("enstrophy", "enstrophy [m^3/s^2]")]
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for path, label in zip(args.csv, labels):
        data = read_csv(path)
        data["total"] = data["kinetic_energy"] + data["potential_energy"]
        for ax, (key, title) in zip(axes.flat, panels):
            ax.plot(data["time"], data[key], label=label)
            ax.set_title(title)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    axes.flat[0].legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
