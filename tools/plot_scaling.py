"""Step time against particle count from a multi-size benchmark JSON (tools/bench_dam_break.py).

    python tools/plot_scaling.py tools/results/scaling_dam_break_h100.json --out tools/results/scaling_dam_break_h100.png
"""

import argparse
import json

from warpsph.plots import _pyplot


def plot(runs, out):
    """The figure of the benchmark's runs (a list, one per size) as the PNG ``out``."""
    n = [r["fluid_particles"] for r in runs]
    ms = [r["ms_per_step"] for r in runs]
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.loglog(n, ms, "o-", label="ms per step")
    ax.loglog(n, [ms[1] * k / n[1] for k in n], "--", color="gray", label="linear through 1M")
    ax.set_xlabel("fluid particles")
    ax.set_ylabel("ms per step")
    ax.set_title(f"{runs[0]['scene']} on {runs[0]['device']}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    print(plot(json.load(open(args.results)), args.out))


if __name__ == "__main__":
    main()
