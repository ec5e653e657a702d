"""PNG plots with matplotlib (optional: ``pip install "warpsph[plot]"``).

- :func:`plot_energy`: energy and enstrophy over time for several runs (like Fig 7 of the VR paper);
- :func:`plot_slice`: particles in a thin slab coloured by vorticity magnitude (like Fig 4 of both papers).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from warpsph.errors import SceneError


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
    from warpsph.diagnostics import read_csv

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
    import json

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
    points = points_prim.GetPointsAttr().Get(frame)
    primvar = UsdGeom.PrimvarsAPI(points_prim.GetPrim()).GetPrimvar("vorticity_magnitude")
    if primvar and primvar.Get(frame) is not None:
        values, label = np.array(primvar.Get(frame)), "vorticity magnitude [1/s]"
    else:
        values, label = np.linalg.norm(np.array(points_prim.GetVelocitiesAttr().Get(frame)), axis=1), "speed [m/s]"
    diameter = float(np.array(points_prim.GetWidthsAttr().Get(frame))[0])
    return plot_slice(np.array(points), values, out, axis, thickness=2.0 * diameter, label=label,
                      title=f"{Path(cache).name}, frame {frame}")
