"""Numerical-stability stress matrix: one scene, one parameter changed per cell, does it blow up?

    warpsph stress --scale 0.05 --seconds 4 --out tools/results/stress_cpu_dam_break
    warpsph stress --axes alpha cfl --scale 0.05 --seconds 1.0 --out /tmp/stress   # a tiny run

Every cell is the scene as plain DFSPH (the scene's own models removed) with one change:

- ``alpha``: vorticity refinement with that alpha (VR paper; 1.0 is the paper's default),
- ``beta``: Rankine feedback with that beta,
- ``nu_t``: micropolar with that transfer coefficient,
- ``cfl``: the scene's ``time.cfl``,
- ``fixed_dt``: ``time.fixed_dt`` = that multiple of the CFL time step, the smallest dt the plain run took
  (the CFL rule at the fastest moment of the flow), i.e. a fixed step that many times above CFL.

The plain cell always runs first: it is the reference of the energy ratio and of the CFL dt. Per cell we
record whether it blew up (the simulator's health checks raise ``InstabilityError``: NaN, a particle
through a wall, density above 1.5 rho0, a solver at max_iterations for 50 steps; we record its step,
time, check, particle id and position and go on), the largest density error over the output frames
(max_i rho_i / rho0 - 1 of the per-frame density field) and the solver's last average error
(``sim.statistics()``), the mean density and divergence iterations per solve, and the kinetic energy at
the end relative to the plain cell's: the VR paper's Fig 7 criterion (a dam break settles; a model must
not keep, or add, energy the plain solver lets go). Also the mean kinetic energy over the last quarter
of the run (less sensitive to the phase of a slosh).

The cells are two scene-file sweeps (:mod:`warpsph.sweep`, a process per cell): the plain cell (every
step's dt read back for the CFL dt), then the others (``--workers N`` at once, ``--devices``, ``--executor
ray``). Their files go to OUT.sweep/plain and OUT.sweep/matrix; running the same command again runs only the
cells not finished there. A cell that raises anything but an instability is recorded as failed (and run again
next time).

Writes OUT.json, OUT.md (a table) and OUT.png (heat map; needs matplotlib; ``warpsph plot results OUT.json``
draws it again).
"""

import contextlib
import json
import logging
import tempfile
from pathlib import Path

import numpy as np

from warpsph.errors import SceneError
from warpsph.plots import _pyplot
from warpsph.scene import load_scene
from warpsph.sweep import add_executor_arguments, executor_arguments, records, run_sweep
from warpsph.validation import study_main

AXES = {  # name -> (default values, label)
    "alpha": ([0.0, 1.0, 1.2, 1.3, 2.0], "VR alpha"),
    "beta": ([0.0, 0.6, 1.0], "Rankine beta"),
    "nu_t": ([0.05, 0.2, 0.4], "micropolar nu_t"),
    "cfl": ([0.2, 0.4, 0.6, 0.8, 1.0], "CFL factor"),
    "fixed_dt": ([2.0, 4.0, 8.0], "fixed dt / CFL dt"),
}
MODEL_AXES = {"alpha": ("vorticity_refinement", "alpha"), "beta": ("rankine", "beta"),
              "nu_t": ("micropolar", "transfer_coefficient")}
REPO = Path(__file__).resolve().parents[2]

logger = logging.getLogger(__name__)


MEASURES = ["particles", "steps", "time_reached", "max_density_error_pct", "density_iterations", "ke_end",
            "blow_up_step", "wall_s"]


def cell_keys(axis=None, value=None, dt_ref=None):
    """The scene keys of a cell: plain DFSPH (the scene's own models removed) with one change (``axis`` None:
    the plain cell)."""
    keys = {"models": []}
    if axis in MODEL_AXES:
        kind, key = MODEL_AXES[axis]
        keys["models"] = [{"type": kind, key: value}]
    elif axis == "cfl":
        keys.update({"time.cfl": value, "time.fixed_dt": None})
    elif axis == "fixed_dt":
        keys["time.fixed_dt"] = value * dt_ref
    return keys


def sweep(scene_path, scale, seconds, cells, device="cpu", plain=False):
    """A scene-file sweep of the matrix's ``cells`` (their scene keys); ``plain``: also every step's dt."""
    return {"name": "stress-plain" if plain else "stress", "scene": str(Path(scene_path).resolve()), "scale": scale,
            "time": seconds, "cells": cells, "warm_up": False, "device": device,
            "measures": MEASURES + (["dt_min"] if plain else [])}


def cell_of(record):
    """The matrix's record of a cell from its sweep record (never raises for an instability or a failed cell)."""
    if record is None or record.get("status") not in ("done", "unstable"):
        error = "missing" if record is None else record.get("error", "failed")
        return {"blew_up": True, "error": error, "wall_s": (record or {}).get("elapsed_s", 0.0)}
    r = record["row"]
    out = {"blew_up": record["status"] == "unstable"}
    if out["blew_up"]:
        out["instability"] = r["instability"]
    out.update({key: r.get(key) for key in (
        "particles", "steps", "time_reached", "max_density_error_pct", "mean_density_error_pct",
        "solver_density_error_pct", "density_iterations", "divergence_iterations", "dt_mean", "ke_end",
        "ke_tail_mean", "ke_max", "kinetic_energy", "frame_times")})
    out["frames"] = len(r["kinetic_energy"])
    out["wall_s"] = r["setup_s"] + r["wall_s"] + (r.get("measure_s") or 0.0)  # the cell's set-up and run
    if r.get("dt_min") is not None:
        out["dt_min_step"] = r["dt_min"]
    return out


def stress(scene_path, scale=0.05, seconds=2.0, axes=None, values=None, device="cpu", log=print, sweep_dir=None,
           **executor):
    """Runs the matrix; returns the report (dict). ``values`` overrides an axis's values. ``executor``:
    run_sweep's executor, workers, devices, address, num_gpus, max_retries; the cells' files go to
    ``sweep_dir`` (plain/ and matrix/; None: a temporary folder)."""
    base = load_scene(scene_path, scale=scale)
    axes = list(AXES) if axes is None else list(axes)
    values = {a: list((values or {}).get(a) or AXES[a][0]) for a in axes}
    try:  # relative to the repository when it is in it
        name = str(Path(scene_path).resolve().relative_to(REPO))
    except ValueError:
        name = str(scene_path)
    report = {"scene": name, "scale": scale, "seconds": seconds, "radius": base.particle_radius,
              "cfl": base.time.cfl, "dt_bounds": list(base.time_step_bounds), "axes": values, "cells": []}
    executor.setdefault("devices", [device])
    with contextlib.ExitStack() as stack:
        if sweep_dir is None:
            sweep_dir = stack.enter_context(tempfile.TemporaryDirectory(prefix="stress-"))
        else:
            report["sweep"] = str(sweep_dir)
        spec = sweep(scene_path, scale, seconds, [cell_keys()], device, plain=True)
        run_sweep(spec, Path(sweep_dir) / "plain", log=log, **executor)
        plain = cell_of(records(spec, Path(sweep_dir) / "plain")[0][1])
        plain.update(name="plain DFSPH", axis=None, value=None)
        report["cells"].append(plain)
        report["particles"] = plain.get("particles")
        # the CFL dt: the smallest step the plain run took (the CFL rule at its fastest)
        dt_ref = plain.get("dt_min_step") or base.time_step_bounds[1]
        report["dt_cfl"] = dt_ref
        log(_line(plain))
        grid = [(axis, value) for axis in axes for value in values[axis]]
        keys = [cell_keys(axis, value, dt_ref) for axis, value in grid]
        unique = list({json.dumps(k, sort_keys=True): k for k in keys}.values())  # a value given twice runs once
        if unique:
            spec = sweep(scene_path, scale, seconds, unique, device)
            run_sweep(spec, Path(sweep_dir) / "matrix", log=log, **executor)
            done = {json.dumps(cell["params"], sort_keys=True): record
                    for cell, record in records(spec, Path(sweep_dir) / "matrix")}
        for (axis, value), k in zip(grid, keys):
            cell = cell_of(done[json.dumps(k, sort_keys=True)])
            cell.update(name=f"{axis} = {value:g}", axis=axis, value=value)
            if axis == "fixed_dt":
                cell["fixed_dt_s"] = value * dt_ref
            report["cells"].append(cell)
            log(_line(cell))
    ke_plain, tail_plain = plain.get("ke_end"), plain.get("ke_tail_mean")
    for cell in report["cells"]:
        ok = not cell["blew_up"] and "error" not in cell and ke_plain
        cell["ke_end_rel_dfsph"] = cell["ke_end"] / ke_plain if ok else None
        cell["ke_tail_rel_dfsph"] = cell["ke_tail_mean"] / tail_plain if ok and tail_plain else None
    return report


def _line(cell):
    head = f"{cell['name']:22s}"
    if "error" in cell and not cell.get("steps"):
        return head + " ERROR " + cell["error"]
    status = "stable"
    if cell["blew_up"]:
        i = cell.get("instability")
        status = (f"BLEW UP step {i['step']} t {i['time']:.3f} s: {i['check']}" if i else "FAILED " + cell.get("error", ""))
    return (head + f" {status}; max density error {_fmt(cell['max_density_error_pct'], '.2f')} %, iterations "
            f"{_fmt(cell['density_iterations'], '.2f')}/{_fmt(cell['divergence_iterations'], '.2f')}, KE end "
            f"{_fmt(cell['ke_end'], '.4g')} J, {cell['steps']} steps, {cell['wall_s']:.1f} s")


def _fmt(v, spec):
    return "—" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def markdown(report):
    lines = [f"Stress matrix: `{report['scene']}` at scale {report['scale']} ({report['particles']} fluid particles, "
             f"r = {report['radius'] * 1000:.1f} mm), {report['seconds']} s simulated; CFL dt (smallest step of the "
             f"plain run) {report['dt_cfl'] * 1000:.2f} ms, dt bounds {report['dt_bounds'][0] * 1000:.2f}.."
             f"{report['dt_bounds'][1] * 1000:.2f} ms.", "",
             "| cell | blew up | max density error % | solver avg error % | density it. | divergence it. | "
             "KE end / DFSPH | KE last quarter / DFSPH | steps | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for c in report["cells"]:
        if c["blew_up"]:
            i = c.get("instability")
            blew = (f"**yes**: step {i['step']}, t = {i['time']:.3f} s, {i['check']}, particle {i['particle_id']}"
                    if i else "**failed**: " + c.get("error", ""))
        else:
            blew = "error: " + c["error"] if "error" in c else "no"
        name = c["name"] + (f" ({c['fixed_dt_s'] * 1000:.2f} ms)" if "fixed_dt_s" in c else "")
        lines.append(f"| {name} | {blew} | {_fmt(c.get('max_density_error_pct'), '.2f')} | "
                     f"{_fmt(c.get('solver_density_error_pct'), '.3f')} | {_fmt(c.get('density_iterations'), '.2f')} | "
                     f"{_fmt(c.get('divergence_iterations'), '.2f')} | {_fmt(c.get('ke_end_rel_dfsph'), '.3f')} | "
                     f"{_fmt(c.get('ke_tail_rel_dfsph'), '.3f')} | {c.get('steps', 0)} | {c['wall_s']:.1f} |")
    return "\n".join(lines) + "\n"


def heat_map(report, out):
    """Rows: axes, columns: their values; three panels (KE of the last quarter / DFSPH, max density error, density
    iterations); a blown-up cell is black with the time it failed."""
    plt = _pyplot()
    rows = [("plain", [c for c in report["cells"] if c["axis"] is None])]
    rows += [(a, [c for c in report["cells"] if c["axis"] == a]) for a in report["axes"]]
    width = max(len(cells) for _, cells in rows)
    panels = [("ke_tail_rel_dfsph", "kinetic energy, mean of the last quarter / plain DFSPH", "coolwarm", ".2f"),
              ("max_density_error_pct", "max density error [%]", "viridis", ".1f"),
              ("density_iterations", "density iterations / solve", "viridis", ".1f")]
    fig, axes = plt.subplots(len(panels), 1, figsize=(max(1.6 * width + 2.5, 7.5), 1.0 + 0.55 * len(rows) * len(panels) + 0.6 * len(panels)))
    for ax, (key, title, cmap, spec) in zip(np.atleast_1d(axes), panels):
        grid = np.full((len(rows), width), np.nan)
        for r, (_, cells) in enumerate(rows):
            for k, c in enumerate(cells):
                if not c["blew_up"] and c.get(key) is not None:
                    grid[r, k] = c[key]
        image = np.ma.masked_invalid(grid)
        colours = plt.get_cmap(cmap).copy()
        colours.set_bad("white")
        kwargs = {}
        if key == "ke_tail_rel_dfsph" and np.isfinite(grid).any():
            span = max(abs(np.log10(np.nanmax(grid))), abs(np.log10(np.nanmin(grid))), 0.05)
            from matplotlib.colors import LogNorm

            kwargs["norm"] = LogNorm(10 ** -span, 10 ** span)
        shown = ax.imshow(image, cmap=colours, aspect="auto", **kwargs)
        fig.colorbar(shown, ax=ax)
        for r, (_, cells) in enumerate(rows):
            for k, c in enumerate(cells):
                label = "plain" if c["axis"] is None else f"{c['value']:g}"
                if c["blew_up"]:
                    ax.add_patch(plt.Rectangle((k - 0.5, r - 0.5), 1, 1, color="black"))
                    t = c.get("instability", {}).get("time")
                    text = f"{label}\nblew up" + (f"\nt={t:.2f}s" if t is not None else "")
                    ax.text(k, r, text, ha="center", va="center", color="white", fontsize=7)
                else:
                    colour = "black"
                    if c.get(key) is not None and np.isfinite(c[key]):
                        red, green, blue, _ = shown.cmap(shown.norm(c[key]))
                        colour = "white" if 0.299 * red + 0.587 * green + 0.114 * blue < 0.45 else "black"
                    ax.text(k, r, f"{label}\n{_fmt(c.get(key), spec)}", ha="center", va="center", fontsize=7, color=colour)
        ax.set_yticks(range(len(rows)), [AXES[a][1] if a in AXES else "plain DFSPH" for a, _ in rows])
        ax.set_xticks([])
        ax.set_title(title)
    fig.suptitle(f"{Path(report['scene']).name}, scale {report['scale']}, {report['particles']} particles, "
                 f"{report['seconds']} s")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def write(report, out):
    """OUT.json, OUT.md and OUT.png for the prefix ``out`` (a .json/.md/.png suffix is dropped)."""
    out = Path(out)
    if out.suffix in (".json", ".md", ".png"):
        out = out.with_suffix("")
    out.parent.mkdir(parents=True, exist_ok=True)
    (out.parent / (out.name + ".json")).write_text(json.dumps(report, indent=1) + "\n")
    (out.parent / (out.name + ".md")).write_text(markdown(report))
    try:
        heat_map(report, out.parent / (out.name + ".png"))
    except Exception as exc:  # noqa: BLE001 - no matplotlib: the JSON and the table are the result
        logger.warning(f"no heat map: {exc}")


def add_arguments(parser):
    """The matrix's options (``warpsph stress`` and ``main``)."""
    parser.add_argument("--scene", default=str(REPO / "scenes" / "dam_break.json"), help="scene file (default the dam break)")
    parser.add_argument("--scale", type=float, default=0.05, help="particle-count scale (load_scene)")
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated time per cell [s]")
    parser.add_argument("--axes", nargs="+", choices=list(AXES), default=list(AXES))
    for axis, (defaults, label) in AXES.items():
        parser.add_argument("--" + axis.replace("_", "-"), nargs="+", type=float, dest=axis,
                            help=f"{label} values (default {' '.join(f'{v:g}' for v in defaults)})")
    parser.add_argument("--device", default="cpu", help="cpu (default), cuda or cuda:N")
    parser.add_argument("--out", help="output prefix: OUT.json, OUT.md, OUT.png (and the cells in OUT.sweep/)")
    add_executor_arguments(parser)


def check_arguments(args):
    """SceneError naming the option for a value the matrix cannot run with."""
    if not Path(args.scene).is_file():
        raise SceneError(args.scene, "--scene", "no such scene file")
    for option, value in (("--scale", args.scale), ("--seconds", args.seconds)):
        if not 0 < value < np.inf:
            raise SceneError("", option, f"expected a finite number > 0, got {value:g}")
    for axis in AXES:
        if any(not np.isfinite(v) for v in getattr(args, axis) or ()):
            raise SceneError("", "--" + axis.replace("_", "-"), "expected finite values")
    for axis in ("cfl", "fixed_dt"):
        if any(not v > 0 for v in getattr(args, axis) or ()):
            raise SceneError("", "--" + axis.replace("_", "-"), "expected values > 0")


def main(argv=None):
    return study_main(__doc__, add_arguments, command, argv)


def command(args):
    """Runs the matrix for the parsed options; prints the table, writes ``--out``."""
    check_arguments(args)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    executor = executor_arguments(args)
    values = {a: getattr(args, a) for a in AXES if getattr(args, a)}
    prefix = Path(args.out).with_suffix("") if args.out and Path(args.out).suffix in (".json", ".md", ".png") else args.out
    report = stress(args.scene, args.scale, args.seconds, args.axes, values, args.device,
                    sweep_dir=Path(f"{prefix}.sweep") if args.out else None, **executor)
    report.update(device=args.device, warp=wp.__version__)
    print(markdown(report))
    if args.out:
        write(report, args.out)
    return 0


if __name__ == "__main__":
    main()
