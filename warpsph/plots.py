"""PNG plots with matplotlib (optional: ``pip install "warpsph[plot]"``).

- :func:`plot_energy`: energy and enstrophy over time for several runs (like Fig 7 of the VR paper);
- :func:`plot_slice`: particles in a thin slab coloured by vorticity magnitude (like Fig 4 of both papers);
- :func:`sweep_figures`: a sweep's table as a Pareto plot (time against error, log-log) and a heat map of outcomes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from warpsph.errors import SceneError
from warpsph.diagnostics import read_csv
from warpsph.tables import pareto_flags, value_text


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise SceneError("", "plot", 'needs matplotlib: pip install "warpsph[plot]" (or pip install matplotlib)') from None
    return plt


def _save(fig, out):
    """fig.savefig with a clear error for a bad --out (missing folder, unknown image format)."""
    plt = _pyplot()
    try:
        fig.savefig(out, dpi=120)
    except (OSError, ValueError) as exc:
        raise SceneError(out, "--out", f"cannot write the plot ({getattr(exc, 'strerror', None) or exc})") from None
    finally:
        plt.close(fig)
    return Path(out)


def stats_path(run) -> Path:
    """The diagnostics CSV of a run given as OUT.usdc/.usda or as the CSV itself."""
    run = Path(run)
    path = run if run.suffix == ".csv" else run.with_suffix(".stats.csv")
    if not path.is_file():
        raise SceneError(path, "", "no diagnostics file here (warpsph run writes OUT.stats.csv beside OUT)")
    return path


def plot_energy(runs, out, labels=None):
    plt = _pyplot()
    paths = [stats_path(r) for r in runs]
    labels = labels or [p.name.replace(".stats.csv", "") for p in paths]
    if len(labels) != len(paths):
        raise SceneError("", "--labels", "give one label per run")
    panels = [("kinetic_energy", "kinetic energy [J]"), ("total", "kinetic + potential [J]"),
              ("rotational_energy", "rotational energy [J]"), ("enstrophy", "enstrophy [m^3/s^2]")]
    tables = []
    for path in paths:
        try:
            data = read_csv(path)
            data["total"] = data["kinetic_energy"] + data["potential_energy"]
            [data[key] for key, _ in panels + [("time", "")]]
        except (KeyError, ValueError, UnicodeDecodeError):
            raise SceneError(path, "", "not a warpsph diagnostics CSV, or one without rows") from None
        tables.append(data)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for data, label in zip(tables, labels):
        for ax, (key, title) in zip(axes.flat, panels):
            ax.plot(data["time"], data[key], label=label)
            ax.set_title(title)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    axes.flat[0].legend()
    fig.tight_layout()
    return _save(fig, out)


def xy_plot(out, curves, xlabel, ylabel, figsize=(6, 4)):
    """Curves ``(x, y, style, label)`` in one PNG (the validation tools' figures)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=figsize)
    for x, y, style, label in curves:
        ax.plot(x, y, style, label=label, ms=3)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend()
    fig.tight_layout()
    return _save(fig, out)


def draw_figures(out, figures):
    """The PNGs of a validation report at ``out`` (OUT.json -> OUT{suffix}.png), from its ``figures(report)``:
    a list of (suffix, curves, xlabel, ylabel, figsize). Returns the paths."""
    out = Path(out)
    return [xy_plot(out.with_name(out.stem + suffix + ".png"), curves, xlabel, ylabel, figsize)
            for suffix, curves, xlabel, ylabel, figsize in figures]


def write_report(report, out, figures):
    """A validation report as JSON at ``out`` and, when matplotlib is present, its figures beside it (the
    JSON alone regenerates them: ``warpsph plot results OUT.json``)."""
    Path(out).write_text(json.dumps(report, indent=2) + "\n")
    try:
        draw_figures(out, figures)
    except SceneError:  # no matplotlib: the JSON is the result
        pass


AXES = {"x": 0, "y": 1, "z": 2}


def plot_slice(points, values, out, axis="z", thickness=None, title="", label="vorticity magnitude [1/s]"):
    """Particles within ``thickness`` (centred) of the mid-plane normal to ``axis``, coloured by
    ``values``; returns (path, particles shown)."""
    plt = _pyplot()
    points = np.asarray(points)
    a = AXES[axis]
    mid = 0.5 * (points[:, a].min() + points[:, a].max())
    if thickness is None:
        thickness = 0.05 * (points[:, a].max() - points[:, a].min() + 1e-9)
    slab = np.abs(points[:, a] - mid) <= 0.5 * thickness
    u, v = [k for k in range(3) if k != a]
    fig, ax = plt.subplots(figsize=(9, 5))
    shown = ax.scatter(points[slab, u], points[slab, v], c=np.asarray(values)[slab], s=4, cmap="viridis")
    fig.colorbar(shown, ax=ax, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("xyz"[u] + " [m]")
    ax.set_ylabel("xyz"[v] + " [m]")
    ax.set_title((title + "\n" if title else "") + f"|{axis} - {mid:.3g}| <= {thickness / 2:.3g} m: {int(slab.sum())} particles")
    fig.tight_layout()
    return _save(fig, out), int(slab.sum())


def slice_from_cache(cache, frame, axis, out):
    """plot_slice of one frame of a USD cache: vorticity magnitude, or speed when there is none."""
    from pxr import Usd, UsdGeom

    try:
        stage = Usd.Stage.Open(str(cache))
    except Exception:  # pxr raises Tf.ErrorException for a missing or foreign file
        stage = None
    if stage is None:
        raise SceneError(cache, "", "cannot open the USD cache")
    points_prim = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    if not points_prim:
        raise SceneError(cache, "", "no particles (/World/Fluid) in this file: not a warpsph cache")
    samples = points_prim.GetPointsAttr().GetTimeSamples()
    if float(frame) not in samples:
        last = int(samples[-1]) if samples else None
        raise SceneError(cache, "--frame", f"no frame {frame} in the cache (frames 0..{last})")
    points = np.array(points_prim.GetPointsAttr().Get(frame))
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        raise SceneError(cache, "--frame", f"{int((~finite).sum())} of the {len(points)} particle positions of frame "
                                           f"{frame} are NaN or infinite (an unstable run's frame): plot an earlier one")
    primvar = UsdGeom.PrimvarsAPI(points_prim.GetPrim()).GetPrimvar("vorticity_magnitude")
    velocities = points_prim.GetVelocitiesAttr().Get(frame)
    if primvar and primvar.Get(frame) is not None:
        values, label = np.array(primvar.Get(frame)), "vorticity magnitude [1/s]"
    elif velocities is not None:
        values, label = np.linalg.norm(np.array(velocities), axis=1), "speed [m/s]"
    else:  # a cache written with --fields points only
        values, label = points[:, 1], "height [m] (no velocities in the cache)"
    widths = points_prim.GetWidthsAttr().Get(frame)
    if widths is None or len(widths) == 0:
        raise SceneError(cache, "", "no particle widths in this cache: not a warpsph cache")
    diameter = float(np.array(widths)[0])
    return plot_slice(points, values, out, axis, thickness=2.0 * diameter, label=label,
                      title=f"{Path(cache).name}, frame {frame}")


SWEEP_TIMES = ("wall_per_sim_s", "wall_s")  # the time and error measures a sweep's Pareto plot takes, first found
SWEEP_ERRORS = ("error_percent", "error_pct")
SWEEP_SIZES = ("resolution", "scale", "particle_radius")  # the key a Pareto line goes through
OUTCOME_COLOURS = {"done": "#59a14f", "unstable": "#e15759", "failed": "#9d9d9d", "missing": "#ffffff"}


def _first(keys, choices):
    return next((k for k in choices if k in keys), None)


def _positive(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v > 0


def sweep_figures(table, out):
    """The PNGs of a sweep's table (``table.json`` of ``warpsph sweep``) at the prefix ``out``: OUT.pareto.png when
    it has a time and an error measure (:data:`SWEEP_TIMES`, :data:`SWEEP_ERRORS`), and OUT.heat_map.png.
    Returns the paths."""
    out = Path(out)
    paths = []
    if _first(table["measures"], SWEEP_TIMES) and _first(table["measures"], SWEEP_ERRORS):
        paths.append(sweep_pareto(table, out.with_name(out.name + ".pareto.png")))
    paths.append(sweep_heat_map(table, out.with_name(out.name + ".heat_map.png")))
    return paths


def sweep_pareto(table, out, x=None, y=None):
    """Log-log: a time measure (default wall_per_sim_s, else wall_s) against an error measure (error_percent, else
    error_pct), a line per method (per value of the varied keys but the size) through its sizes (resolution, scale or
    particle_radius, annotated); circled: the Pareto-optimal cells (no other has both a lower time and error). A
    varied ``case`` gets a panel per case."""
    plt = _pyplot()
    x = x or _first(table["measures"], SWEEP_TIMES)
    y = y or _first(table["measures"], SWEEP_ERRORS)
    if x is None or y is None:
        raise SceneError(out, "", f"the table has no time ({', '.join(SWEEP_TIMES)}) or no error measure "
                                  f"({', '.join(SWEEP_ERRORS)})")
    rows = [r for r in table["rows"] if _positive(r.get(x)) and _positive(r.get(y))]
    size = _first(table["axes"], SWEEP_SIZES)
    panel = "case" if "case" in table["axes"] else None
    others = [k for k in table["axes"] if k not in (size, panel)]
    panels = {}
    for r in rows:
        panels.setdefault(value_text(r.get(panel)) if panel else table["case"], []).append(r)
    fig, axes = plt.subplots(1, max(len(panels), 1), figsize=(7.5 * max(len(panels), 1), 6), squeeze=False)
    for ax, (title, here) in zip(axes[0], panels.items() or [(table["case"], [])]):
        groups = {}
        for r in here:
            groups.setdefault(tuple(json.dumps(r.get(k), sort_keys=True) for k in others), []).append(r)
        for n, line in enumerate(groups.values()):
            line.sort(key=lambda r: (r.get(size) is None, r.get(size) or 0))
            label = ", ".join(f"{k} {value_text(line[0].get(k))}" for k in others) or "cells"
            ax.plot([r[x] for r in line], [r[y] for r in line], "o-", color=f"C{n % 10}", ms=6, alpha=0.85, label=label)
            for r in line:
                if size is not None:
                    ax.annotate(value_text(r.get(size)), (r[x], r[y]), fontsize=7, xytext=(3, 3),
                                textcoords="offset points")
        front = sorted((r for r, flag in zip(here, pareto_flags(here, x, y)) if flag), key=lambda r: r[x])
        if front:
            ax.plot([r[x] for r in front], [r[y] for r in front], "o", mfc="none", mec="k", ms=12, mew=1.2,
                    label="Pareto-optimal")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(f"{table['sweep']}: {title}" + (f" (numbers: {size})" if size else ""), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        if here:
            ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, out)


def sweep_heat_map(table, out, measure=None):
    """Outcome per cell, coloured green (done), red (unstable: its blow-up step), grey (failed) or white (missing).
    With two varied keys, every value of the first against every value of the second; otherwise a row per varied
    key and a square per value, standing for every cell with that value (the worst outcome, and how many blew up).
    The text gives ``measure`` (default the table's first numeric measure that differs between cells)."""
    from matplotlib.patches import Patch, Rectangle

    plt = _pyplot()
    rows, axes = table["rows"], table["axes"]
    if measure is None:  # the first numeric measure that differs between cells, else the first numeric one
        numeric = [m for m in table["measures"] if any(_positive(r.get(m)) or r.get(m) == 0 for r in rows)
                   and all(not isinstance(r.get(m), (list, dict, str)) for r in rows)]
        measure = next((m for m in numeric if len({r.get(m) for r in rows}) > 1), numeric[0] if numeric else None)

    def values(key):
        seen = {}
        for r in rows:
            if r.get(key) is not None:
                seen.setdefault(json.dumps(r[key], sort_keys=True), r[key])
        return list(seen.items())

    def square(cells):
        counts = {s: sum(c["status"] == s for c in cells) for s in OUTCOME_COLOURS}
        status = next(s for s in ("unstable", "failed", "missing", "done") if counts[s] or s == "done")
        if len(cells) == 1:
            c = cells[0]
            if c["status"] == "unstable":
                step = c.get("blow_up_step") or c.get("steps")
                return status, "blew up" + (f"\nstep {step}" if step is not None else "")
            return status, "" if measure is None else f"{measure}\n{value_text(c.get(measure))}"
        if counts["unstable"] or counts["failed"]:
            return status, f"{counts['unstable']}/{len(cells)} blew up" + (f", {counts['failed']} failed" if counts["failed"] else "")
        return status, f"{len(cells)} cells"

    grid = []  # (row label, [(column label, status, text)])
    if len(axes) == 2 and all(r.get(axes[0]) is not None and r.get(axes[1]) is not None for r in rows):
        cols = values(axes[1])
        for key, value in values(axes[0]):
            line = []
            for ckey, cvalue in cols:
                here = [r for r in rows if json.dumps(r[axes[0]], sort_keys=True) == key
                        and json.dumps(r[axes[1]], sort_keys=True) == ckey]
                status, text = square(here) if here else ("missing", "")
                line.append((f"{axes[1]} {value_text(cvalue)}", status, text))
            grid.append((f"{axes[0]} {value_text(value)}", line))
    else:
        for axis in axes or []:
            line = []
            for key, value in values(axis):
                status, text = square([r for r in rows if json.dumps(r.get(axis), sort_keys=True) == key])
                line.append((value_text(value), status, text))
            if line:
                grid.append((axis, line))
        if not grid:
            status, text = square(rows)
            grid.append(("all cells", [("", status, text)]))
    width = max(len(line) for _, line in grid)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.9 * width + 2.5), 1.2 + 0.9 * len(grid)))
    for n, (_, line) in enumerate(grid):
        for k, (label, status, text) in enumerate(line):
            ax.add_patch(Rectangle((k, n), 1, 1, facecolor=OUTCOME_COLOURS[status], edgecolor="k", lw=0.5))
            ax.text(k + 0.5, n + 0.5, "\n".join(t for t in (label, text) if t), ha="center", va="center", fontsize=7,
                    color="white" if status == "unstable" else "black")
    ax.set_xlim(0, width)
    ax.set_ylim(len(grid), 0)
    ax.set_yticks([n + 0.5 for n in range(len(grid))], [name for name, _ in grid])
    ax.set_xticks([])
    ax.legend(handles=[Patch(facecolor=c, edgecolor="k", label=s) for s, c in OUTCOME_COLOURS.items()],
              loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=4, fontsize=8, frameon=False)
    ax.set_title(f"{table['sweep']}: {table['case']}, outcome per cell", fontsize=10)
    fig.tight_layout()
    return _save(fig, out)
