"""Regenerates the figures of result files from their JSON (the PNGs are not kept in the repository).

    python tools/plot_results.py tools/results/*.json            # each OUT.json -> OUT*.png beside it
    python tools/plot_results.py --out-dir /tmp/figs tools/results/stress_h100_dam_break.json

Knows the validation reports (Taylor-Green, Lamb-Oseen, hydrostatic, Martin & Moyce dam front: their
``figures(report)``), the Pareto studies, the stress matrices and the multi-size benchmarks; other JSON files
are skipped with a line saying so. Needs matplotlib.
"""

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the sibling tools (stress, plot_scaling)


def figures_of(report):
    """The validation module whose report this is, or None."""
    from warpsph.validation import dam_front, hydrostatic, lamb_oseen, taylor_green

    case = report.get("case", "") if isinstance(report, dict) else ""
    if case.startswith("Taylor-Green"):
        return taylor_green.figures
    if case.startswith("Lamb-Oseen"):
        return lamb_oseen.figures
    if case.startswith("Martin & Moyce"):
        return dam_front.figures
    if isinstance(report, dict) and "probe_pressure" in report:
        return hydrostatic.figures
    return None


def plot(path, out_dir=None):
    """The PNGs of one result file; returns their paths ([] when the kind is unknown)."""
    path = Path(path)
    report = json.loads(path.read_text())
    out = (Path(out_dir) / path.name) if out_dir else path
    png = out.with_suffix(".png")
    if isinstance(report, list) and report and "ms_per_step" in report[0]:
        import plot_scaling

        return [plot_scaling.plot(report, png)]
    if isinstance(report, dict) and "points" in report:
        from warpsph.validation.pareto import plot as pareto_plot

        return [pareto_plot(report, png)]
    if isinstance(report, dict) and "cells" in report and "axes" in report:
        import stress

        stress.heat_map(report, png)
        return [png]
    figures = figures_of(report)
    if figures is None:
        return []
    from warpsph.plots import draw_figures

    return draw_figures(out, figures(report))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", nargs="+", help="result JSON files")
    parser.add_argument("--out-dir", help="write the PNGs here instead of beside the JSON")
    args = parser.parse_args(argv)
    for path in args.results:
        pngs = plot(path, args.out_dir)
        print(f"{path}: " + (", ".join(str(p) for p in pngs) if pngs else "no figure for this kind of file"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
