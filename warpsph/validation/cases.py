"""The runner behind ``warpsph validate CASE --resolutions N ... [--methods ...] [--solver iisph] --device DEV --json OUT``.

Every case runs with the default solver settings (no "solver" keys in its scene but ``solver.method`` when
``--solver`` names one); a method adds only its model.
One row per (method, resolution), with at least: case, method, resolution, particles, error_pct,
error_units, wall_s, steps (and setup_s and the case's own measurements).

``error_pct`` per case (``ERRORS``):

- taylor-green: L1 error of |u| over the particles at T = 0.3 s, in % of the analytic peak speed at T
  (L = 1 m, U = 1 m/s, nu = 0.01, periodic box 6 spacings deep, started from the particle packing of
  ``taylor_green.PACK_STEPS`` steps; resolution = particles across L);
- lamb-oseen: L1 error of u_theta (annuli of one spacing, r < 0.35 L) at T = 0.5 s, in % of the analytic
  peak speed at T (L = 1 m, core radius 0.125 m at every resolution, peak speed 0.5 m/s, nu = 0.01,
  periodic in z, 6 spacings deep, started from the scene's ``initial_packing`` of ``PACK_STEPS`` steps;
  resolution = particles across L);
- hydrostatic: |mean density error| of the particles deeper than one support radius, in % of rho0, after
  1.5 s (0.4 m cube; resolution = particles across the cube);
- vortex-surface: as lamb-oseen, but the box is filled to 0.88 L under gravity along -y: the vortex lies below a
  free surface (``lamb_oseen.SURFACE_FILL``);
- standing-wave: |frequency error| of the first sloshing mode of a tank 1 m long and 0.5 m deep against linear
  theory, w^2 = g k tanh(k h), in %; its amplitude decay against 2 nu k^2 beside it (``decay_error_pct``;
  resolution = particles along the tank);
- dam-front: RMS error of the front Z/a against Martin & Moyce (1952), no time shift (the best shift is
  reported beside it), in units of the column width a (not a percentage: ``error_units`` "a"; resolution =
  particles across a);
- tank-at-rest: a sealed 0.4 m cube of water and pools filled to 95, 93 and 88 % resting under gravity for 5 s:
  the largest speed over each tank's last second, in % of sqrt(g H), the worst of the four (each tank's speed,
  density error and surface count in ``tanks``; resolution = particles across the side);
- sinking-sphere: the terminal speed of a sphere (D = 0.1 m, 3000 kg/m^3) sinking on the axis of a square tank 6 D
  wide, against Stokes-Oseen drag with Haberman & Sayre's wall factor (``sinking``): distance from the middle of the
  band that the square's inscribed and equal-area tubes give, in %; resolution = particles across D;
- poiseuille: a channel's steady flow between two walls with ``fluid.boundary_viscosity`` 2 nu (``poiseuille``): the
  slip of its fitted parabola's no-slip planes beyond the walls, in particle spacings (``error_units`` "spacings");
  resolution = particles across the 0.2 m channel.

Every row reports the summation density's unremoved error away from the free surface at the end
(``density_error_mean_pct``, :func:`density_error`).

``wall_s``: seconds of the time stepping alone, device synchronised before and after, the per-frame
measurements subtracted; set-up (sampling, the Taylor-Green packing) is ``setup_s``. Every method first
runs a tiny warm-up so that no module load lands in a timed row (a CUDA run's graph capture does: it is
part of every run).
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from .taylor_green import METHODS, PACK_STEPS
from . import lamb_oseen as lo, taylor_green as tg
from ..errors import SceneError
from ..simulation import InstabilityError
from .dam_front import DEPTH, T_END, compare, dam_front
from .hydrostatic import SIDE, hydrostatic
from .rest import FILLS, tank_at_rest
from .poiseuille import poiseuille
from .sinking import sinking_sphere
from .standing_wave import standing_wave
from warpsph.kernels.free_surface import BAND, SURFACE

CASES = ("taylor-green", "lamb-oseen", "vortex-surface", "standing-wave", "hydrostatic", "dam-front", "tank-at-rest",
         "sinking-sphere", "poiseuille")
MIN_RESOLUTION = 4
FRAMES = 10  # measurements per vortex run (and frame 0)

ERRORS = {
    "taylor-green": ("%", "L1 error of |u| at T = 0.3 s, % of the analytic peak speed at T"),
    "lamb-oseen": ("%", "L1 error of u_theta (annuli of one spacing, r < 0.35 m) at T = 0.5 s, % of the analytic "
                        "peak speed at T"),
    "vortex-surface": ("%", "L1 error of u_theta (annuli of one spacing, r < 0.35 m) at T = 0.5 s, % of the analytic "
                            "peak speed at T, below a free surface under gravity"),
    "standing-wave": ("%", "|frequency error| of the first sloshing mode against linear theory, %"),
    "hydrostatic": ("%", "|mean density error| of the particles deeper than one support radius after 1.5 s, % of rho0"),
    "dam-front": ("a", "front RMS error: RMS of Z/a against Martin & Moyce (1952), no time shift, in units of the "
                       "column width a (not a percentage)"),
    "tank-at-rest": ("%", "largest speed over the last of 5 s at rest under gravity, % of sqrt(g H), the worst of a "
                          "sealed tank and pools filled to 95 / 93 / 88 %"),
    "sinking-sphere": ("%", "terminal speed of a sphere sinking on the axis of a square tank against Stokes-Oseen drag "
                            "with Haberman & Sayre's wall factor: distance from the middle of the band the square's "
                            "inscribed and equal-area tubes give, %"),
    "poiseuille": ("spacings", "slip of a channel's flow between two walls (fluid.boundary_viscosity 2 nu): the no-slip "
                               "planes of its fitted parabola against the walls, in particle spacings (not a percentage)"),
}
RESOLUTION_MEANS = {"taylor-green": "particles across L = 1 m", "lamb-oseen": "particles across L = 1 m",
                    "vortex-surface": "particles across L = 1 m", "standing-wave": "particles along the 1 m tank",
                    "hydrostatic": "particles across the 0.4 m water cube", "dam-front": "particles across the column width a",
                    "tank-at-rest": "particles across the 0.4 m tank",
                    "sinking-sphere": "particles across the sphere's 0.1 m diameter",
                    "poiseuille": "particles across the 0.2 m channel"}


def timed_run(sim, run, on_frame=None):
    """Calls ``run(callback)`` (which runs ``sim`` and calls ``callback(sim, frame)`` per frame) with the device
    synchronised around it; ``on_frame``'s own time (synchronised at its start and end) is subtracted.
    Returns (wall seconds of the run alone, seconds spent in on_frame)."""
    import warp as wp

    spent = [0.0]

    def callback(s, frame):
        wp.synchronize_device(sim.device)  # the run's own work ends here
        start = time.perf_counter()
        if on_frame is not None:
            on_frame(s, frame)
        wp.synchronize_device(sim.device)
        spent[0] += time.perf_counter() - start

    wp.synchronize_device(sim.device)
    start = time.perf_counter()
    run(callback)
    wp.synchronize_device(sim.device)
    return time.perf_counter() - start - spent[0], spent[0]


def _finite(v):
    return float(v) if v is not None and math.isfinite(float(v)) else None


# --- the cases: (models, resolution, device) -> the row's measurements ----------------------------------

def taylor_green_row(models, resolution, device, overrides=None):
    start = time.perf_counter()
    sim, ke0 = tg.build(models, resolution, tg.NU, tg.T_END, device, FRAMES, pack_steps=tg.PACK_STEPS,
                        overrides=overrides)
    setup = time.perf_counter() - start
    rows = []
    wall, _ = timed_run(sim, lambda cb: sim.run(frames=FRAMES, on_frame=cb), lambda s, f: rows.append(tg.measure(s, ke0, tg.NU)))
    end = rows[-1]
    peak = float(tg.peak_speed(end["time"], tg.NU))
    density = sim.host(sim.fluid.density)
    return {"particles": sim.num_fluid, "error_pct": 100.0 * end["l1_speed_error"] / peak, "wall_s": wall,
            "steps": sim.step_count, "setup_s": setup, "time": end["time"], "l1_speed_error": end["l1_speed_error"],
            "peak_speed_exact": peak, "ke_ratio": end["ke_ratio"], "ke_ratio_exact": end["ke_ratio_exact"],
            "ke_error_pct": 100.0 * (end["ke_ratio"] / end["ke_ratio_exact"] - 1.0),
            "mean_density_ratio": float(density.mean() / sim.rest_density), "pack_steps": tg.PACK_STEPS,
            "error_pct_frames": [100.0 * r["l1_speed_error"] / float(tg.peak_speed(r["time"], tg.NU)) for r in rows],
            **density_error(sim)}


def density_error(sim):
    """The summation density's error at the current positions, unremoved (no mean taken out), over the fluid
    away from the free surface and its band (the whole fluid where the solver does not detect a surface):
    (mean of rho / rho0 - 1, mean of |rho / rho0 - 1|), in %."""
    sim.update_densities()
    sim.pressure_solver.detect_free_surface()
    error = sim.host(sim.fluid.density).astype(np.float64) / sim.rest_density - 1.0
    flags = getattr(sim.pressure_solver, "surface", None)
    if flags is not None:
        flags = sim.host(flags)
        error = error[(flags != int(SURFACE)) & (flags != int(BAND))]
    return {"density_error_mean_pct": 100.0 * float(error.mean()),
            "density_error_mean_abs_pct": 100.0 * float(np.abs(error).mean())}


def lamb_oseen_row(models, resolution, device, overrides=None, free_surface=False):
    core = lo.CORE_RADIUS * resolution / lo.L  # build takes the core in spacings
    start = time.perf_counter()
    sim, p, edges = lo.build(models, resolution, lo.NU, lo.T_END, core, lo.U_PEAK, lo.DEPTH, device, FRAMES,
                             pack_steps=PACK_STEPS, overrides=overrides, free_surface=free_surface)
    setup = time.perf_counter() - start
    rows = []
    budget = lo.AngularMomentumBudget(sim, p["centre"]) if hasattr(sim.pressure_solver, "pressure_sum") else None
    wall, _ = timed_run(sim, lambda cb: sim.run(frames=FRAMES, on_frame=cb, on_step=budget),
                     lambda s, f: rows.append(lo.measure(s, p, edges, s.time)))
    angular = {} if budget is None else budget.shares(rows[0], rows[-1])
    wall -= 0.0 if budget is None else budget.seconds
    s = lo.summary(lo.kinetic_ratios(rows), lo.NU)
    return {"particles": sim.num_fluid, "error_pct": 100.0 * s["l1_relative_end"], "wall_s": wall,
            "steps": sim.step_count, "setup_s": setup, "time": rows[-1]["time"], "core_radius_m": p["core_radius_0"],
            "core_spacings": core, "l1_error_m_per_s": s["l1_error_end"], "omega_ratio": s["omega_ratio_end"],
            "omega_curl_ratio": s["omega_curl_ratio_end"], "omega_decay": s["omega_decay"],
            "omega_decay_exact": s["omega_decay_exact"], "nu_effective": s["nu_effective"], "r_peak": s["r_peak_end"],
            "r_peak_exact": s["r_peak_exact_end"], "ke_ratio": s["ke_ratio_end"],
            "ke_exact_ratio": s["ke_exact_ratio_end"], "centre_offset": s["centre_offset_end"],
            "angular_momentum_ratio": s["angular_momentum_ratio_end"],
            **{f"angular_momentum_{k}": v for k, v in angular.items() if k != "angular_momentum_ratio"},
            "error_pct_frames": [100.0 * r["l1_relative"] for r in rows], **density_error(sim)}


def vortex_surface_row(models, resolution, device, overrides=None):
    return lamb_oseen_row(models, resolution, device, overrides, free_surface=True)


def standing_wave_row(models, resolution, device, overrides=None):
    timing = {}

    def on_run(sim, run, record):
        timing["wall_s"], _ = timed_run(sim, run, record)

    start = time.perf_counter()
    t, amplitude, sim, s = standing_wave(resolution, device, models=models, overrides=overrides, on_run=on_run)
    total = time.perf_counter() - start
    return {"particles": sim.num_fluid, "error_pct": abs(s["frequency_error_pct"]), "wall_s": timing["wall_s"],
            "steps": sim.step_count, "setup_s": total - timing["wall_s"], **s,
            "amplitude_end": float(amplitude[-1]), **density_error(sim)}


def hydrostatic_row(models, resolution, device, overrides=None):
    start = time.perf_counter()
    r = hydrostatic(radius=SIDE / (2 * resolution), device=device, models=models, overrides=overrides)
    total = time.perf_counter() - start
    return {"particles": r["particles"], "error_pct": 100.0 * abs(r["density_error_mean"]), "wall_s": r["wall_s"],
            "steps": r["steps"], "setup_s": total - r["wall_s"], "radius": r["radius"], "T": r["T"],
            "density_error_mean_pct": 100.0 * r["density_error_mean"],
            "density_error_mean_abs_pct": 100.0 * r["density_error_mean_abs"],
            "density_error_max_pct": 100.0 * r["density_error_max"], "max_speed": r["max_speed"],
            "mid_depth_pressure_ratio": r["mid_depth_pressure_ratio"],
            "probe_pressure_rms_error_pct": 100.0 * r["probe_pressure_rms_error_relative"]}


def dam_front_row(models, resolution, device, overrides=None):
    timing = {}
    start = time.perf_counter()
    T, Z, sim = dam_front(resolution, device, T_END, models=models, depth=DEPTH, timing=timing, overrides=overrides)
    total = time.perf_counter() - start
    c = compare(T, Z)
    return {"particles": sim.num_fluid, "error_pct": c["raw_rms"], "wall_s": timing["wall_s"],
            "steps": sim.step_count, "setup_s": total - timing["wall_s"], "front_rms_shifted": c["shifted_rms"],
            "front_rms_raw": c["raw_rms"], "time_shift_T": c["time_shift_T"], "points": c["shifted_points"],
            "depth": DEPTH, "T_end": T_END, **density_error(sim)}


def tank_at_rest_row(models, resolution, device, overrides=None):
    tanks, wall, steps, particles = [], 0.0, 0, 0
    start = time.perf_counter()
    for fill in FILLS:
        timing = []
        r = tank_at_rest(resolution, fill, device, models=models, overrides=overrides,
                         on_run=lambda sim, run: timing.append(timed_run(sim, lambda cb: run())[0]))
        sim = r.pop("sim")
        tanks.append({**r, **density_error(sim)})
        wall, steps, particles = wall + timing[0], steps + r["steps"], particles + r["particles"]
    worst = max(t["max_speed_over_sqrt_gH"] for t in tanks)
    return {"particles": particles, "error_pct": 100.0 * worst, "wall_s": wall, "steps": steps,
            "setup_s": time.perf_counter() - start - wall, "tanks": tanks,
            "density_error_mean_pct": max((t["density_error_mean_pct"] for t in tanks), key=abs)}


def _one_run_row(case, models, resolution, device, overrides=None):
    """The row of a case that is one run of ``case(resolution, device, models=, overrides=, on_run=)``, which
    returns its measurements with the simulation under "sim": the run timed alone."""
    timing = []
    start = time.perf_counter()
    r = case(resolution, device, models=models, overrides=overrides,
             on_run=lambda sim, run: timing.append(timed_run(sim, lambda cb: run())[0]))
    sim = r.pop("sim")
    return {**r, "wall_s": timing[0], "setup_s": time.perf_counter() - start - timing[0], **density_error(sim)}


def sinking_sphere_row(models, resolution, device, overrides=None):
    return _one_run_row(sinking_sphere, models, resolution, device, overrides)


def poiseuille_row(models, resolution, device, overrides=None):
    return _one_run_row(poiseuille, models, resolution, device, overrides)


ROWS = {"taylor-green": taylor_green_row, "lamb-oseen": lamb_oseen_row, "vortex-surface": vortex_surface_row,
        "standing-wave": standing_wave_row, "hydrostatic": hydrostatic_row, "dam-front": dam_front_row,
        "tank-at-rest": tank_at_rest_row, "sinking-sphere": sinking_sphere_row,
        "poiseuille": poiseuille_row}


def warm_up(models, device, overrides=None):
    """Loads every kernel module a method uses outside the timed rows: a tiny vortex, a few steps (the second
    captures the CUDA graph) and one measurement."""
    sim, p, edges = lo.build(models, resolution=8, core=1.0, device=device, frames=FRAMES, overrides=overrides)
    for _ in range(3):
        sim.step()
    lo.measure(sim, p, edges, sim.time)
    sim.check_health()


# --- metadata and output ------------------------------------------------------------------------------

def device_info(device):
    import warp as wp

    d = wp.get_device(device)
    if d.is_cuda:
        name = d.name
    else:
        name = platform.processor() or "cpu"
        try:
            model = [line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")]
            if model:
                name = f"{model[0]} ({len(model)} threads)"
        except OSError:
            pass
    return {"device": name, "device_alias": d.alias, "warp": wp.__version__, "python": platform.python_version(),
            "host": platform.node()}


def commit_info():
    """The simulator's git commit (WARPSPH_COMMIT overrides it, e.g. on a copy of the tree without .git) and
    its uncommitted simulator files; the commit is None when unknown."""
    if os.environ.get("WARPSPH_COMMIT"):
        return {"commit": os.environ["WARPSPH_COMMIT"]}
    root = Path(__file__).resolve().parent.parent.parent
    if not (root / ".git").exists():
        return {"commit": None}
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10)
        if head.returncode != 0:
            return {"commit": None}
        status = subprocess.run(["git", "status", "--porcelain", "--", "warpsph", "kernels"], cwd=root,
                                capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return {"commit": None}
    return {"commit": head.stdout.strip(), "uncommitted": [line[3:] for line in status.splitlines() if line[:2].strip()]}


def _clean(value):
    """JSON without NaN/Infinity (written as null)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (np.floating, np.integer)):
        return _clean(value.item())
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def write_json(report, out):
    """Writes ``report`` to ``out`` atomically (a temporary file beside it, then renamed)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(_clean(report), f, indent=2, ensure_ascii=False)
            f.write("\n")
        os.replace(tmp, out)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def table(rows):
    """A small plain-text table of the rows."""
    head = ["case", "method", "resolution", "particles", "error", "steps", "wall s"]
    lines = [head]
    for r in rows:
        unit = " %" if r.get("error_units") == "%" else " " + str(r.get("error_units", ""))
        error = f"unstable: {r['unstable']}" if r.get("unstable") else (
            "—" if r.get("error_pct") is None else f"{r['error_pct']:.4g}{unit}")
        method = r["method"] if r.get("solver", "dfsph") == "dfsph" else f"{r['method']} ({r['solver']})"
        lines.append([r["case"], method, str(r["resolution"]), f"{r['particles']:,}" if r.get("particles") else "—",
                      error, str(r.get("steps", "—")), "—" if r.get("wall_s") is None else f"{r['wall_s']:.2f}"])
    widths = [max(len(line[k]) for line in lines) for k in range(len(head))]
    return "\n".join("  ".join(c.ljust(w) if k < 2 else c.rjust(w) for k, (c, w) in enumerate(zip(line, widths))).rstrip()
                     for line in lines)


def validate(case, resolutions, methods=("dfsph",), device="cpu", out=None, log=None, command=None, solver=None):
    """Runs ``case`` at every resolution with every method (the default solver; a method adds its model);
    returns the report. With ``out`` the JSON is written (atomically) after every row, ``complete`` false
    until the last. ``log``: a function taking a line of progress (None: silent); ``command``: recorded;
    ``solver``: the pressure solver (scene key ``solver.method``, "dfsph" or "iisph"; None: the default)."""
    import warp as wp

    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; expected one of {', '.join(CASES)}")
    say = log or (lambda line: None)
    units, definition = ERRORS[case]
    overrides = {"solver.method": solver} if solver else None
    report = {"benchmark": "warpsph validate", "case": case, **device_info(device), **commit_info(),
              "command": command, "solver": {"method": solver} if solver else "default (no solver keys)",
              "definitions": {"resolution": RESOLUTION_MEANS[case], "error_pct": definition, "error_units": units,
                              "wall_s": "time stepping alone, device synchronised, per-frame measurements subtracted",
                              "setup_s": "scene sampling and set-up (the Taylor-Green packing included), not timed in wall_s"},
              "methods": {name: METHODS[name] for name in methods}, "resolutions": list(resolutions),
              "rows": [], "complete": False}
    started = time.perf_counter()
    for name in methods:
        t0 = time.perf_counter()
        warm_up(METHODS[name], device, overrides)
        report.setdefault("warmup_s", {})[name] = time.perf_counter() - t0
    grid = [(res, name) for res in resolutions for name in methods]
    for k, (res, name) in enumerate(grid, 1):
        say(f"[{k}/{len(grid)}] {case} {name} resolution {res} ...")
        row = {"case": case, "method": name, "resolution": res, "error_units": units, "solver": solver or "dfsph"}
        try:
            row.update(ROWS[case](METHODS[name], res, device, overrides))
        except InstabilityError as exc:
            row.update(particles=None, error_pct=None, wall_s=None, steps=exc.step, unstable=str(exc),
                       unstable_time=exc.time)
        wp.synchronize_device(device)
        row["error_pct"] = _finite(row.get("error_pct"))
        report["rows"].append(row)
        report["complete"] = k == len(grid)
        report["elapsed_s"] = time.perf_counter() - started
        if row.get("unstable"):
            say(f"    unstable: {row['unstable']}")
        else:
            say(f"    {row['particles']:,} particles, error {row['error_pct']:.4g} {units}, {row['steps']} steps, "
                f"{row['wall_s']:.2f} s")
        if out is not None:
            write_json(report, out)
    return report


# --- command-line input ---------------------------------------------------------------------------------

def check_arguments(case, resolutions, json_path):
    """The command line's CASE and --resolutions (strings) checked before anything runs; returns
    (case, [int resolutions], --json as a Path or None: the CLI checks it as every verb's output file).
    Raises :class:`warpsph.errors.SceneError` naming the option."""
    if case not in CASES:
        raise SceneError("", "CASE", f"unknown case '{case}'; expected one of {', '.join(CASES)}")
    values = []
    for text in resolutions:
        try:
            n = int(str(text).strip())
        except ValueError:
            raise SceneError("", "--resolutions", f"expected integers >= {MIN_RESOLUTION} ({RESOLUTION_MEANS[case]}), "
                                                  f"got '{text}'") from None
        if n < MIN_RESOLUTION:
            raise SceneError("", "--resolutions", f"expected integers >= {MIN_RESOLUTION} ({RESOLUTION_MEANS[case]}), "
                                                  f"got {n}")
        values.append(n)
    return case, values, None if json_path is None else Path(json_path)
