"""Regenerates the figures of result files from their JSON (the PNGs are not kept in the repository).

    warpsph plot results tools/results/*.json            # each OUT.json -> OUT*.png beside it
    warpsph plot results --out-dir /tmp/figs tests/data/stress_cpu_falling_blocks.json

Knows the validation reports (Taylor-Green, Lamb-Oseen, hydrostatic, Martin & Moyce dam front: their
``figures(report)``), the Pareto studies, the stress matrices, the multi-size benchmarks and the tables of
``warpsph sweep`` (DIR/table.json -> table.pareto.png when it has a time and an error measure, and
table.heat_map.png); other JSON files are skipped with a line saying so. Needs matplotlib.
"""

import json
import sys
from pathlib import Path

from warpsph.errors import SceneError
from warpsph.plots import draw_figures, sweep_figures
from warpsph.validation import dam_front, hydrostatic, lamb_oseen, study_main, taylor_green
from warpsph.validation.bench import scaling_plot
from warpsph.validation.pareto import plot as pareto_plot
from warpsph.validation.stress import heat_map


def figures_of(report):
    """The validation module whose report this is, or None."""
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


def read_report(path):
    """The JSON of a result file; SceneError for a missing or unreadable one."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise SceneError(path, "", "no such result file") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SceneError(path, "", f"not a JSON result file ({exc})") from None


def plot(path, out_dir=None):
    """The PNGs of one result file; returns their paths ([] when the kind is unknown)."""
    path = Path(path)
    report = read_report(path)
    out = (Path(out_dir) / path.name) if out_dir else path
    png = out.with_suffix(".png")
    if isinstance(report, list) and report and "ms_per_step" in report[0]:
        return [scaling_plot(report, png)]
    if isinstance(report, dict) and "points" in report:
        return [pareto_plot(report, png)]
    if isinstance(report, dict) and "sweep" in report and "rows" in report:  # warpsph sweep's table.json
        return sweep_figures(report, out.with_suffix(""))
    if isinstance(report, dict) and "cells" in report and "axes" in report:
        heat_map(report, png)
        return [png]
    figures = figures_of(report)
    if figures is None:
        return []
    return draw_figures(out, figures(report))


def add_arguments(parser):
    """The command's options (``warpsph plot results`` and ``main``)."""
    parser.add_argument("results", nargs="+", metavar="RESULT.json", help="result JSON files")
    parser.add_argument("--out-dir", help="write the PNGs here instead of beside the JSON")


def command(args):
    """Draws every file's figures; prints a line per file."""
    if args.out_dir:
        if Path(args.out_dir).exists() and not Path(args.out_dir).is_dir():
            raise SceneError(args.out_dir, "--out-dir", "is a file; --out-dir names a folder")
        Path(args.out_dir).mkdir(parents=True, exist_ok=True)
    for path in args.results:
        pngs = plot(path, args.out_dir)
        print(f"{path}: " + (", ".join(str(p) for p in pngs) if pngs else "no figure for this kind of file"))
    return 0


def main(argv=None):
    return study_main(__doc__, add_arguments, command, argv)


if __name__ == "__main__":
    sys.exit(main())
