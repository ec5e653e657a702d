"""Cost against accuracy (issue #5): wall time per simulated second against the error, per method,
resolution and solver tolerance, and the Pareto front of those points.

    warpsph pareto --device cpu --resolutions 24 36 --tolerances 0.05 0.01 --out tools/results/pareto_cpu.json
    warpsph pareto --device cuda --resolutions 96 192 384 --tolerances 0.05 0.01 --out tools/results/pareto_h100.json
    warpsph pareto --plot-only RESULTS.json [--out tools/results/pareto_h100.json]   # PNG (and table) here

The question it answers: for a given error budget, which method and resolution is cheapest?

Error (``--case``): ``lamb-oseen`` (default), the Lamb-Oseen vortex of warpsph/validation/lamb_oseen/ (its set-up,
measurements and summary; the functions are imported, not copied). The physical problem is the same at every
resolution: box L = 1 m, initial core radius sqrt(4 nu t0) = ``--core-radius`` metres (0.125 m, as
``warpsph validate lamb-oseen``: 3 spacings at 24 particles across), peak speed 0.5 m/s, nu = 0.01, T = 0.5 s. Only the box
depth is counted in spacings (6, quasi-2D: the flow does not depend on z). The primary error is the L1
error of u_theta at T, in % of the analytic peak speed at T; the peak-vorticity ratio (against the same
fit of the analytic field), the effective viscosity and the kinetic energy ratio are recorded too.
``taylor-green``: the Taylor-Green vortex of warpsph/validation/taylor_green/ (L = 1, U = 1, nu = 0.01, T = 0.3 s,
6 spacings deep, periodic) with the default solver, started from its particle packing (``--pack-steps``, set-up,
not timed): the error
is the L1 error of the velocity magnitude at T in % of the analytic peak speed at T; the kinetic energy error
KE(T)/KE_exact(T) - 1 is recorded too.

Optionally (``--dam-front R ...``, R in particles across the column width a) the Martin & Moyce dam-break
front of warpsph/validation/dam_front/ per method and tolerance: the RMS of Z/a after the best time shift,
with its own time per simulated second.

Timing: ``wall_per_sim_s`` = seconds of wall time per simulated second, around ``Simulation.run`` with
the device synchronised before and after; the per-frame measurements (11 frames) are timed on their own
(device synchronised at their start and end) and subtracted. Set-up (sampling, boundary volumes) is not
included, and every method runs a small warm-up simulation first so that no kernel compilation or module
load lands in a timed run (the CUDA graph capture of the run's own second step does: it is part of every
run). Recorded per point: fluid particles, steps, mean density and divergence iterations, ms per step.

Solver tolerance: the scene's ``solver.density_max_error`` (average density error in %; the divergence
tolerance stays at its default 0.1 %/s).

The points are the cells of a sweep (:mod:`warpsph.sweep`, each cell :func:`point` in a process of its own,
after its method's warm-up): ``--workers N`` runs N at once, ``--devices cuda:0,cuda:1`` spreads them,
``--executor ray`` runs them on a Ray cluster; one file per point goes to ``OUT.sweep/cells/`` and running the
same command again runs only the points not finished there. Then JSON (every point, device, Warp version,
commit), a markdown table beside it (``*.md``, with the Pareto-optimal points marked: no other point has both a
lower error and a lower time), and a PNG when matplotlib imports. Points are listed from the coarsest
resolution up.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import platform
import sys
import time
from pathlib import Path

from warpsph import tables
from warpsph.errors import SceneError
from warpsph.validation.cases import MIN_RESOLUTION, commit_info, timed_run
from warpsph.validation.lamb_oseen import (CORE_RADIUS as LAMB_OSEEN_CORE_RADIUS, L, build, kinetic_ratios, measure,
    summary)
from warpsph.simulation import InstabilityError
from warpsph.sweep import add_executor_arguments, executor_arguments, records, run_sweep
from warpsph.validation import study_main, taylor_green, taylor_green as tg
from warpsph.validation.dam_front import compare, dam_front
from warpsph.validation.taylor_green import PACK_STEPS, T_END

# name -> (label, scene "models" list)
METHODS = {
    "dfsph": ("DFSPH", []),
    "vr": ("DFSPH+VR α=1", [{"type": "vorticity_refinement", "alpha": 1.0}]),
    "rankine0.6": ("DFSPH+Rankine β=0.6", [{"type": "rankine", "beta": 0.6}]),
    "rankine1": ("DFSPH+Rankine β=1", [{"type": "rankine", "beta": 1.0}]),
    "micropolar": ("DFSPH+micropolar ν_t=0.05", [{"type": "micropolar", "transfer_coefficient": 0.05}]),
}

CASES = ("lamb-oseen", "taylor-green")
CORE_RADIUS = LAMB_OSEEN_CORE_RADIUS  # m: 3 spacings at 24 particles across L = 1 m
ERROR_KEY, TIME_KEY = "error_percent", "wall_per_sim_s"
DAM_ERROR_KEY, DAM_TIME_KEY = "dam_rms", "dam_wall_per_sim_s"

logger = logging.getLogger(__name__)


# --- the Pareto front -------------------------------------------------------------------------------

def pareto_flags(points, x=TIME_KEY, y=ERROR_KEY):
    """:func:`warpsph.tables.pareto_flags` of the study's measures (default: time per simulated second and
    error)."""
    return tables.pareto_flags(points, x, y)


def mark_pareto(points):
    for p, flag in zip(points, pareto_flags(points)):
        p["pareto"] = flag
    if any(DAM_ERROR_KEY in p for p in points):
        for p, flag in zip(points, pareto_flags(points, DAM_TIME_KEY, DAM_ERROR_KEY)):
            p["dam_pareto"] = flag
    return points


# --- timing -----------------------------------------------------------------------------------------

def warm_up_method(models, device, case="lamb-oseen"):
    """Loads (compiles) every kernel module a method uses, outside the timed runs: a tiny vortex, a few
    steps (the second captures the CUDA graph) and one measurement."""
    if case == "taylor-green":
        sim, ke0 = tg.build(models, resolution=8, device=device, solver=taylor_green_solver(0.05), pack_steps=2)
        for _ in range(3):
            sim.step()
        tg.measure(sim, ke0, 0.01)
    else:
        sim, p, edges = build(models, resolution=8, core=1.0, device=device, frames=10)
        for _ in range(3):
            sim.step()
        measure(sim, p, edges, sim.time)
    sim.check_health()
    sim.statistics()


def solver_stats(sim):
    s = sim.statistics()
    return {"steps": sim.step_count, "mean_density_iterations": s["density_iterations"],
            "mean_divergence_iterations": s["divergence_iterations"]}


# --- the two error measures ---------------------------------------------------------------------------

def lamb_oseen_point(models, resolution, tolerance, device, core_radius=CORE_RADIUS, nu=0.01, T=0.5, u_peak=0.5,
                     depth=6, frames=10, on_instability="stop", pack_steps=None):
    """One vortex run: error, timing and solver statistics (a dict; ``unstable`` when it blew up). It starts
    from the packing that ``warpsph validate lamb-oseen`` uses (``pack_steps``; None: its default)."""
    core = core_radius * resolution / L  # the validation tool takes the core in spacings
    pack_steps = PACK_STEPS if pack_steps is None else pack_steps
    start = time.perf_counter()
    sim, p, edges = build(models, resolution, nu, T, core, u_peak, depth, device, frames,
                          solver={"density_max_error": tolerance}, pack_steps=pack_steps)
    sim.on_instability = on_instability  # "reduce-dt": a failed frame is redone with dt halved (its cost counts)
    out = {"particles": sim.num_fluid, "boundary_particles": sim.num_boundary, "spacing": p["spacing"],
           "pack_steps": pack_steps, "core_spacings": core, "core_radius_m": p["core_radius_0"], "setup_s": time.perf_counter() - start}
    rows = []
    try:
        wall, measuring = timed_run(sim, lambda cb: sim.run(frames=frames, on_frame=cb),
                                    lambda s, f: rows.append(measure(s, p, edges, s.time)))
    except InstabilityError as exc:
        out.update(unstable=str(exc), unstable_step=exc.step, unstable_time=exc.time, **solver_stats(sim))
        return out
    s = summary(kinetic_ratios(rows), nu)
    simulated = rows[-1]["time"]
    out.update(solver_stats(sim))
    out.update(simulated_s=simulated, wall_s=wall, measure_s=measuring, wall_per_sim_s=wall / simulated,
               ms_per_step=1e3 * wall / max(sim.step_count, 1), error_percent=100.0 * s["l1_relative_end"],
               l1_error_m_per_s=s["l1_error_end"], omega_ratio=s["omega_ratio_end"],
               omega_curl_ratio=s["omega_curl_ratio_end"], omega_decay=s["omega_decay"],
               omega_decay_exact=s["omega_decay_exact"], nu_effective=s["nu_effective"], r_peak=s["r_peak_end"],
               r_peak_exact=s["r_peak_exact_end"], ke_ratio=s["ke_ratio_end"],
               centre_offset=s["centre_offset_end"],
               # the error's history and the final u_theta profile (annuli of one spacing), to see where it comes from
               frames={"time": [r["time"] for r in rows], "error_percent": [100.0 * r["l1_relative"] for r in rows],
                       "omega_ratio": [r["omega_ratio"] for r in rows], "ke_ratio": [r["ke_ratio"] for r in rows]},
               profile_end={"r": [round(v, 6) for v in p["r_bins"]], "u_theta": [round(v, 6) for v in rows[-1]["u_theta"]],
                            "u_theta_exact": [round(v, 6) for v in rows[-1]["u_theta_exact"]]})
    del sim
    return out


def taylor_green_solver(tolerance):
    """The Taylor-Green scene's "solver" keys: the default solver at the point's tolerance."""
    return {"density_max_error": tolerance}


def taylor_green_point(models, resolution, tolerance, device, nu=0.01, T=0.3, frames=10, on_instability="stop",
                       pack_steps=None):
    """One Taylor-Green run (default solver, packed start): error, timing and solver statistics."""
    pack_steps = tg.PACK_STEPS if pack_steps is None else pack_steps
    start = time.perf_counter()
    sim, ke0 = tg.build(models, resolution, nu, T, device, frames, taylor_green_solver(tolerance), pack_steps)
    sim.on_instability = on_instability
    out = {"particles": sim.num_fluid, "spacing": 1.0 / resolution, "pack_steps": pack_steps,
           "setup_s": time.perf_counter() - start}
    rows = []
    try:
        wall, measuring = timed_run(sim, lambda cb: sim.run(frames=frames, on_frame=cb),
                                    lambda s, f: rows.append(tg.measure(s, ke0, nu)))
    except InstabilityError as exc:
        out.update(unstable=str(exc), unstable_step=exc.step, unstable_time=exc.time, **solver_stats(sim))
        return out
    end = rows[-1]
    errors = [100.0 * r["l1_speed_error"] / float(tg.peak_speed(r["time"], nu)) for r in rows]
    ke_errors = [100.0 * (r["ke_ratio"] / r["ke_ratio_exact"] - 1.0) for r in rows]
    density = sim.host(sim.fluid.density)
    out.update(solver_stats(sim))
    out.update(simulated_s=end["time"], wall_s=wall, measure_s=measuring, wall_per_sim_s=wall / end["time"],
               ms_per_step=1e3 * wall / max(sim.step_count, 1), error_percent=errors[-1],
               ke_ratio=end["ke_ratio"], ke_ratio_exact=end["ke_ratio_exact"], ke_error_percent=ke_errors[-1],
               mean_density_ratio=float(density.mean() / sim.rest_density),
               max_density_ratio=float(density.max() / sim.rest_density),
               frames={"time": [r["time"] for r in rows], "error_percent": errors, "ke_error_percent": ke_errors})
    del sim
    return out


def dam_front_point(models, resolution, tolerance, device, T_end=6.0, depth=4):
    log = {}
    try:
        # the tolerance through the scene's keys, the run's wall time (front measurement subtracted) into log
        T, Z, sim = dam_front(resolution, device, T_end, models=models, depth=depth, timing=log,
                              overrides={"solver.density_max_error": tolerance})
    except InstabilityError as exc:
        return {"dam_resolution": resolution, "dam_unstable": str(exc)}
    c = compare(T, Z)
    simulated = sim.time
    return {"dam_resolution": resolution, "dam_particles": sim.num_fluid, "dam_steps": sim.step_count,
            "dam_simulated_s": simulated, "dam_wall_s": log["wall_s"], DAM_TIME_KEY: log["wall_s"] / simulated,
            "dam_mean_density_iterations": sim.statistics()["density_iterations"],
            DAM_ERROR_KEY: c["shifted_rms"], "dam_time_shift_T": c["time_shift_T"], "dam_raw_rms": c["raw_rms"]}


def point(method, resolution, tolerance, device="cpu", case="lamb-oseen", core_radius=CORE_RADIUS, nu=0.01, T=None,
          u_peak=0.5, depth=6, frames=10, on_instability="stop", pack_steps=None, dam_resolution=None, dam_T_end=6.0,
          warm_up=True):
    """One point of the study, a sweep cell (``warpsph.validation.pareto:point``): the method's warm-up (kernel
    loading kept out of the timed run), the vortex of ``case`` (``T`` None: 0.5 s Lamb-Oseen, 0.3 s Taylor-Green),
    and the dam front at ``dam_resolution`` when given. Returns the point (``unstable`` set: it blew up)."""
    label, models = METHODS[method]
    out = {"method": method, "label": label, "models": models, "resolution": resolution, "tolerance": tolerance}
    if warm_up:
        start = time.perf_counter()
        warm_up_method(models, device, case)
        out["warmup_s"] = time.perf_counter() - start
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    if case == "taylor-green":
        out.update(taylor_green_point(models, resolution, tolerance, device, nu, T_END if T is None else T, frames,
                                      on_instability, pack_steps))
    else:
        out.update(lamb_oseen_point(models, resolution, tolerance, device, core_radius, nu, 0.5 if T is None else T,
                                    u_peak, depth, frames, on_instability, pack_steps))
    if load is not None:  # host load before and after: other processes on the machine skew the timings
        out["load_average"] = [round(load, 2), round(os.getloadavg()[0], 2)]
    if dam_resolution:
        out.update(dam_front_point(models, dam_resolution, tolerance, device, dam_T_end))
    return out


def point_line(p):
    """A line saying how a point went."""
    head = f"{p['label']}, resolution {p['resolution']} ({p.get('particles') or 0:,} particles), tolerance {p['tolerance']} %: "
    if "unstable" in p:
        return head + f"unstable: {p['unstable']}"
    detail = (f"KE error {fmt(p['ke_error_percent'], '+.2f')} %, mean density {fmt(p['mean_density_ratio'], '.4f')}"
              if "ke_error_percent" in p else f"omega ratio {fmt(p['omega_ratio'], '.3f')}")
    line = (head + f"error {fmt(p[ERROR_KEY], '.2f')} %, {detail}, {p['steps']} steps, "
            f"{fmt(p['mean_density_iterations'], '.2f')} density it., {fmt(p['wall_s'], '.2f')} s wall "
            f"({fmt(p[TIME_KEY], '.3g')} s/s, {fmt(p['ms_per_step'], '.2f')} ms/step; measuring {fmt(p['measure_s'], '.2f')} s)")
    if "dam_unstable" in p:
        line += f"; dam front: unstable: {p['dam_unstable']}"
    elif DAM_ERROR_KEY in p:
        line += (f"; dam front (resolution {p['dam_resolution']}, {p['dam_particles']:,} particles): RMS "
                 f"{fmt(p[DAM_ERROR_KEY], '.3f')} a, {p['dam_steps']} steps, {fmt(p[DAM_TIME_KEY], '.3g')} s/s")
    return line


# --- report -----------------------------------------------------------------------------------------

def commit():
    """The commit (and uncommitted simulator files): warpsph's commit_info, so WARPSPH_COMMIT overrides git's where
    the checkout's .git is absent or stale (a copy of the working tree on another machine); PARETO_COMMIT, the
    older name, still does."""
    if os.environ.get("PARETO_COMMIT") and not os.environ.get("WARPSPH_COMMIT"):
        return {"commit": os.environ["PARETO_COMMIT"], "commit_from": "PARETO_COMMIT"}
    return commit_info()


def device_info(device):
    import warp as wp

    d = wp.get_device(device)
    info = {"device": d.name if d.is_cuda else "cpu", "device_alias": d.alias, "warp": wp.__version__,
            "python": platform.python_version(), "host": platform.node(), "cpu_count": os.cpu_count()}
    if not d.is_cuda:
        try:
            model = [line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")]
            info["cpu"] = f"{model[0]} ({len(model)} threads)" if model else platform.processor()
        except OSError:
            info["cpu"] = platform.processor()
    return info


def fmt(v, spec):
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def markdown(report):
    points = report["points"]
    dam = any("dam_resolution" in p for p in points)
    s = report["setup"]
    tg = report.get("case_key") == "taylor-green"
    if tg:
        mode = (f"confined mode, transport velocity {s['transport_velocity']:g}" if s.get("transport_velocity")
                else "default solver")  # older reports ran the confined mode
        flow = (f"Taylor-Green vortex (L = 1 m, U = 1 m/s, nu = {s['nu']:g}, T = {s['T']:g} s, periodic, depth 6 spacings; "
                f"{mode}, packed start of {s['pack_steps']} steps)")
        legend = ("error = L1 error of |u| at T in % of the analytic peak speed at T; KE error = KE(T)/KE_exact(T) - 1 "
                  "(above 0: the method kept more energy than the analytic decay); mean ρ = mean density / ρ0 at T; ")
    else:
        flow = (f"Lamb-Oseen vortex (L = {s['L']:g} m, core radius {s['core_radius_m']:g} m, peak speed {s['u_peak']:g} m/s, "
                f"nu = {s['nu']:g}, T = {s['T']:g} s, depth {s['depth_spacings']} spacings, periodic in z, packed start)")
        legend = ("error = L1 error of u_theta at T in % of the analytic peak speed; ω ratio = peak vorticity / analytic; "
                  "KE ratio = kinetic energy at T / at 0 (analytic decay keeps it below 1: above 1 the method injected energy); ")
    head = (f"{flow} on {report['device']}, Warp {report['warp']}, commit {report['commit']}"
            + (f" (uncommitted: {', '.join(report['uncommitted'])})" if report.get("uncommitted") else "") + ".\n"
            + legend + "s/s = wall seconds per simulated second (run only, synchronised). Pareto: no other point has "
            "both a lower error and a lower time.\n\n")
    measures = ["KE error %", "mean ρ"] if tg else ["ω ratio", "KE ratio"]
    cols = ["method", "resolution", "particles", "tolerance %", "error %", *measures, "steps", "density it.",
            "ms/step", "s wall / s sim", "Pareto"]
    if dam:
        cols += ["dam res.", "dam RMS Z/a", "dam s/s", "dam Pareto"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for p in sorted(points, key=lambda p: (p.get(TIME_KEY) is None, p.get(TIME_KEY) or 0.0)):
        if "unstable" in p:
            cells = [p["label"], p["resolution"], f"{p['particles']:,}", p["tolerance"], f"unstable: {p['unstable']}",
                     "", "", fmt(p.get("steps"), "d"), "", "", "", ""]
        else:
            if tg:
                values = [fmt(p["ke_error_percent"], "+.2f"), fmt(p["mean_density_ratio"], ".4f")]
            else:
                values = [fmt(p["omega_ratio"], ".3f"), fmt(p["ke_ratio"], ".3f") + (" (gain!)" if p["ke_ratio"] > 1 else "")]
            cells = [p["label"], p["resolution"], f"{p['particles']:,}", p["tolerance"], fmt(p[ERROR_KEY], ".2f"),
                     *values, p["steps"], fmt(p["mean_density_iterations"], ".2f"),
                     fmt(p["ms_per_step"], ".2f"), fmt(p[TIME_KEY], ".3g"), "**yes**" if p.get("pareto") else ""]
        if dam:
            cells += [p.get("dam_resolution", ""), p.get("dam_unstable") or fmt(p.get(DAM_ERROR_KEY), ".3f"),
                      fmt(p.get(DAM_TIME_KEY), ".3g"), "**yes**" if p.get("dam_pareto") else ""]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    front = [p for p in points if p.get("pareto")]
    front.sort(key=lambda p: p[TIME_KEY])
    tail = ["", "Pareto front, cheapest first (for an error budget E, take the first row with error ≤ E):", ""]
    tail += [f"- {p[ERROR_KEY]:.2f} % at {p[TIME_KEY]:.3g} s/s: {p['label']}, resolution {p['resolution']} "
             f"({p['particles']:,} particles), tolerance {p['tolerance']} %" for p in front]
    return head + "\n".join(lines) + "\n" + "\n".join(tail) + "\n"


def plot(report, out):
    """PNG: error against time per simulated second, a line per method and tolerance through its
    resolutions, the Pareto front in black (and the dam front in a second panel when measured)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import LogLocator, ScalarFormatter

    points = [p for p in report["points"] if p.get(TIME_KEY) is not None]
    dam = [p for p in report["points"] if p.get(DAM_TIME_KEY) is not None]
    if report.get("case_key") == "taylor-green":
        panels = [(TIME_KEY, ERROR_KEY, "pareto", "L1 error of |u| at T [% of peak speed]",
                   "Taylor–Green vortex (packed start)", points)]
    else:
        panels = [(TIME_KEY, ERROR_KEY, "pareto", "L1 error of u_θ at T [% of peak speed]",
                   "Lamb–Oseen vortex", points)]
    if dam:
        panels.append((DAM_TIME_KEY, DAM_ERROR_KEY, "dam_pareto", "RMS error of front Z/a (shifted)",
                       "Martin & Moyce dam front", dam))
    fig, axes = plt.subplots(1, len(panels), figsize=(7.5 * len(panels), 8.0 if len(panels) == 1 else 6.5),
                             squeeze=False)
    methods = list(dict.fromkeys(p["method"] for p in report["points"]))
    tolerances = sorted({p["tolerance"] for p in report["points"]}, reverse=True)
    markers = ["o", "s", "^", "D", "v"]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (xk, yk, flag, ylabel, title, pts) in zip(axes[0], panels):
        for m, method in enumerate(methods):
            for t, tol in enumerate(tolerances):
                res_key = "dam_resolution" if yk == DAM_ERROR_KEY else "resolution"
                line = sorted((p for p in pts if p["method"] == method and p["tolerance"] == tol),
                              key=lambda p: p[res_key])  # a line through the resolutions, coarsest first
                if not line:
                    continue
                ax.plot([p[xk] for p in line], [p[yk] for p in line], marker=markers[t % len(markers)],
                        ls="-" if t == 0 else "--", color=colours[m % len(colours)], ms=6, alpha=0.85,
                        label=f"{line[0]['label']}, tol {tol:g} %")
                for p in line:
                    ax.annotate(str(p[res_key]), (p[xk], p[yk]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        front = sorted((p for p in pts if p.get(flag)), key=lambda p: p[xk])
        if front:
            xs = [p[xk] for p in front]
            ys = [p[yk] for p in front]
            ax.step(xs + [max(p[xk] for p in pts) * 1.5], ys + [ys[-1]], where="post", color="k", lw=1.2,
                    label="Pareto front")
            ax.plot(xs, ys, "o", mfc="none", mec="k", ms=11, mew=1.2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):  # plain numbers on the log axes
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_locator(LogLocator(subs=(2, 3, 5)))
            axis.set_minor_formatter(ScalarFormatter())
        ax.tick_params(which="minor", labelsize=7)
        ax.set_xlabel("wall time per simulated second [s]")
        ax.set_ylabel(ylabel)
        ax.set_title(title + " (numbers: resolution)", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    one = len(panels) == 1  # one panel: a narrower legend and a two-line title
    fig.legend(handles, labels, loc="lower center", ncol=2 if one else 4, fontsize=7, frameon=False)
    fig.suptitle(f"{report['device']}, Warp {report['warp']}, commit {report['commit']};" + ("\n" if one else " ")
                 + "tolerance = solver density_max_error; circled: Pareto-optimal", fontsize=9)
    fig.tight_layout(rect=(0, 0.2 if one else 0.1, 1, 1))
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return Path(out)


def write(report, out, png=False):
    """JSON and markdown at ``out`` (and ``.md``); the PNG (``.png``) when asked and matplotlib imports."""
    out = Path(out)
    mark_pareto(report["points"])
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(report, indent=2, ensure_ascii=False) + "\n")
    tmp.replace(out)  # a run killed while writing keeps the previous complete file
    out.with_suffix(".md").write_text(markdown(report))
    if png:
        try:
            plot(report, out.with_suffix(".png"))
        except ImportError as exc:
            logger.warning(f"no PNG ({exc}); draw it elsewhere with --plot-only {out}")


# --- driver -----------------------------------------------------------------------------------------

def sweep(methods, resolutions, tolerances, device="cpu", case="lamb-oseen", core_radius=CORE_RADIUS, nu=0.01,
          T=None, u_peak=0.5, depth=6, frames=10, dam_resolutions=(), dam_T_end=6.0, on_instability="stop",
          pack_steps=None):
    """The study as a sweep (a dict for :func:`warpsph.sweep.run_sweep`): a cell per (resolution, tolerance,
    method), coarsest first, each :func:`point`; the dam front's resolutions go to the coarsest resolutions'
    points, one each."""
    dams = list(dam_resolutions) + [None] * max(0, len(resolutions) - len(dam_resolutions))
    dam_of = dict(zip(sorted(resolutions), dams))
    cells = [{"method": name, "resolution": res, "tolerance": tol, "dam_resolution": dam_of.get(res)}
             for res in sorted(resolutions) for tol in tolerances for name in methods]
    fixed = {"case": case, "nu": nu, "T": T, "frames": frames, "on_instability": on_instability,
             "dam_T_end": dam_T_end}
    if case == "taylor-green":
        fixed["pack_steps"] = pack_steps
    else:
        fixed.update(core_radius=core_radius, u_peak=u_peak, depth=depth)
    return {"name": f"pareto-{case}", "base": {"function": "warpsph.validation.pareto:point"}, "cells": cells,
            "fixed": fixed, "device": device,
            "measures": ["particles", ERROR_KEY, TIME_KEY, "steps", "mean_density_iterations", "ms_per_step",
                         DAM_ERROR_KEY, DAM_TIME_KEY]}


def study(methods, resolutions, tolerances, device="cpu", out=None, core_radius=CORE_RADIUS, nu=0.01, T=None,
          u_peak=0.5, depth=6, frames=10, dam_resolutions=(), dam_T_end=6.0, png=True, quiet=False,
          on_instability="stop", case="lamb-oseen", pack_steps=None, sweep_dir=None, **executor):
    """Runs every (resolution, tolerance, method) point as a cell of :func:`sweep` (``executor``: run_sweep's
    executor, workers, devices, address, num_gpus, max_retries); returns the report, written to ``out`` (and
    ``.md``, ``.png``). The cells' files go to ``sweep_dir`` (default ``out`` with the suffix .sweep; a
    temporary folder without ``out``): running again runs only the points not finished there. ``case``:
    "lamb-oseen" or "taylor-green" (then ``core_radius``, ``u_peak`` and ``depth`` do not apply; ``T`` None means
    0.3 s there, 0.5 s for Lamb-Oseen)."""
    import tempfile

    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    say = (lambda *a: None) if quiet else (lambda *a: logger.info(" ".join(map(str, a))))
    tg = case == "taylor-green"
    if tg:
        T = taylor_green.T_END if T is None else T
        depth = 6
        pack_steps = taylor_green.PACK_STEPS if pack_steps is None else pack_steps
        setup = {"L": L, "u_peak": 1.0, "nu": nu, "T": T, "depth_spacings": depth, "frames": frames,
                 "solver": taylor_green_solver("per point"),
                 "pack_steps": pack_steps, "pack_jitter_spacings": taylor_green.PACK_JITTER}
        description = "Taylor-Green vortex, periodic box, quasi-2D, default solver (warpsph/validation/taylor_green/)"
        error = "L1 error of |u| at T, % of the analytic peak speed at T"
    else:
        T = 0.5 if T is None else T
        setup = {"L": L, "core_radius_m": core_radius, "nu": nu, "T": T, "u_peak": u_peak, "depth_spacings": depth,
                 "frames": frames}
        description = "Lamb-Oseen vortex, box periodic in z, quasi-2D, no gravity (warpsph/validation/lamb_oseen/)"
        error = "L1 error of u_theta at T, % of the analytic peak speed at T"
    setup.update(dam_resolutions=list(dam_resolutions), dam_T_end=dam_T_end, on_instability=on_instability)
    report = {"benchmark": "pareto", "case": description, "case_key": case,
              **device_info(device), **commit(), "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]),
              "setup": setup, "error": error,
              "time": "wall seconds per simulated second, run only (device synchronised, per-frame measurement "
                      "subtracted, set-up and kernel compilation excluded)",
              "tolerance": "solver.density_max_error [%]", "pareto": "no other point has both lower error and lower time",
              "methods": {name: {"label": METHODS[name][0], "models": METHODS[name][1]} for name in methods},
              "points": []}
    spec = sweep(methods, resolutions, tolerances, device, case, core_radius, nu, T, u_peak, depth, frames,
                 dam_resolutions, dam_T_end, on_instability, pack_steps)
    executor.setdefault("devices", [device])
    started = time.perf_counter()
    with contextlib.ExitStack() as stack:
        if sweep_dir is None:
            sweep_dir = (Path(out).with_suffix(".sweep") if out else
                         Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="pareto-"))))
        say(f"device {report['device']}, Warp {report['warp']}; {len(spec['cells'])} points, cells in {sweep_dir}")
        run_sweep(spec, sweep_dir, log=None if quiet else say, **executor)
        failed = []
        for cell, record in records(spec, sweep_dir):
            if record is not None and record.get("status") in ("done", "unstable"):
                report["points"].append(record["row"])
                say("    " + point_line(record["row"]))
            else:
                failed.append({"cell": cell["params"], "error": (record or {}).get("error", "missing")})
    for p in report["points"]:
        if "warmup_s" in p:
            report.setdefault("warmup_s", {})
            report["warmup_s"][p["method"]] = report["warmup_s"].get(p["method"], 0.0) + p["warmup_s"]
    if out:
        report["sweep"] = str(sweep_dir)
    if failed:
        report["failed"] = failed
    report["elapsed_s"] = time.perf_counter() - started
    report["complete"] = not failed
    mark_pareto(report["points"])
    if out:
        write(report, out, png=png)
    return report


def merge(reports):
    """One report from several runs of the same set-up on the same device (e.g. one per tolerance, each
    within a time limit): their points in order; a point given twice (method, resolution, tolerance) is
    kept from the later file."""
    first = reports[0]
    for r in reports[1:]:
        for key in ("setup", "device", "warp"):
            if r[key] != first[key]:
                raise SystemExit(f"cannot merge runs with a different {key}: {first[key]} / {r[key]}")
    if len(reports) == 1:
        return first
    points = {}
    for r in reports:
        for p in r["points"]:
            points[(p["method"], p["resolution"], p["tolerance"])] = p
    merged = dict(first)
    merged.update(points=list(points.values()), complete=all(r.get("complete") for r in reports),
                  methods={k: v for r in reports for k, v in r["methods"].items()},
                  commit=", ".join(dict.fromkeys(r["commit"] for r in reports)),
                  command=[r["command"] for r in reports], elapsed_s=sum(r.get("elapsed_s", 0.0) for r in reports))
    return merged


def add_arguments(parser):
    """The study's options (``warpsph pareto`` and ``main``)."""
    parser.add_argument("--device", default="cpu", help="cpu (default), cuda or cuda:N")
    parser.add_argument("--resolutions", type=int, nargs="+", default=[24, 36],
                        help="particles across L = 1 m (fluid particles: resolution^2 x depth)")
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.05, 0.01],
                        help="solver.density_max_error [%%]")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--core-radius", type=float, default=CORE_RADIUS, help="initial core radius sqrt(4 nu t0) [m]")
    parser.add_argument("--nu", type=float, default=0.01)
    parser.add_argument("--case", choices=CASES, default="lamb-oseen", help="the flow whose error is measured")
    parser.add_argument("--T", type=float, help="simulated time [s] (default: 0.5 Lamb-Oseen, 0.3 Taylor-Green)")
    parser.add_argument("--pack-steps", type=int, help="Taylor-Green: steps of the particle packing (default "
                                                      "warpsph.validation.taylor_green.PACK_STEPS)")
    parser.add_argument("--u-peak", type=float, default=0.5, help="initial peak speed [m/s]")
    parser.add_argument("--depth", type=int, default=6, help="box depth in particle spacings")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--dam-front", type=int, nargs="+", default=[], metavar="R",
                        help="also the dam-break front, at R particles across a, one R per resolution (the "
                             "coarsest resolution's points get the first R; resolutions without one skip it)")
    parser.add_argument("--dam-T-end", type=float, default=6.0, help="dam break to T = t sqrt(2g/a)")
    parser.add_argument("--on-instability", choices=["stop", "reduce-dt"], default="stop",
                        help="stop: record the point as unstable; reduce-dt: redo a failed frame with dt halved "
                             "(up to 4 times, as warpsph run --on-instability reduce-dt)")
    parser.add_argument("--out", help="JSON file (markdown .md beside it, PNG .png when matplotlib imports)")
    parser.add_argument("--plot-only", metavar="RESULTS", nargs="+",
                        help="draw the PNG (and table) of JSON made elsewhere; with --out, write JSON, table and PNG "
                             "there; several files (same set-up and device, e.g. one per tolerance) are merged")
    parser.add_argument("--no-plot", action="store_true", help="no PNG")
    add_executor_arguments(parser)


def main(argv=None):
    return study_main(__doc__, add_arguments, command, argv)


def check_arguments(args):
    """SceneError naming the option for a value the study cannot run with."""
    if args.plot_only:
        if len(args.plot_only) > 1 and not args.out:
            raise SceneError("", "--out", "merging several --plot-only files needs --out")
        for f in args.plot_only:
            if not Path(f).is_file():
                raise SceneError(f, "--plot-only", "no such file")
    elif not args.out:
        raise SceneError("", "--out", "required (or --plot-only)")
    if args.out and (not str(args.out) or Path(args.out).is_dir()):
        raise SceneError(args.out, "--out", "is a directory; --out names the JSON file to write")
    if len(args.dam_front) > len(args.resolutions):
        raise SceneError("", "--dam-front", "give at most one --dam-front resolution per --resolutions entry")
    for option, values in (("--resolutions", args.resolutions), ("--dam-front", args.dam_front)):
        if any(n < MIN_RESOLUTION for n in values):
            raise SceneError("", option, f"expected integers >= {MIN_RESOLUTION}, got {' '.join(map(str, values))}")
    for option, values in (("--tolerances", args.tolerances), ("--nu", [args.nu]), ("--core-radius", [args.core_radius]),
                           ("--T", [] if args.T is None else [args.T]), ("--dam-T-end", [args.dam_T_end])):
        if any(not 0 < v < math.inf for v in values):
            raise SceneError("", option, f"expected finite values > 0, got {' '.join(f'{v:g}' for v in values)}")
    for option, value, low in (("--depth", args.depth, 1), ("--frames", args.frames, 1),
                               ("--pack-steps", 0 if args.pack_steps is None else args.pack_steps, 0)):
        if value < low:
            raise SceneError("", option, f"expected an integer >= {low}, got {value}")


def command(args):
    """Runs the study (or, with ``--plot-only``, draws a finished one) for the parsed options."""
    check_arguments(args)
    if args.plot_only:
        report = merge([json.loads(Path(f).read_text()) for f in args.plot_only])
        out = Path(args.out or args.plot_only[0])
        if args.out:
            write(report, out)
        else:
            mark_pareto(report["points"])
        png = plot(report, out.with_suffix(".png"))
        print(f"wrote {png}" + (f", {out}, {out.with_suffix('.md')}" if args.out else ""))
        return 0
    report = study(args.methods, args.resolutions, args.tolerances, args.device, args.out, args.core_radius, args.nu,
                   args.T, args.u_peak, args.depth, args.frames, args.dam_front, args.dam_T_end, png=not args.no_plot,
                   on_instability=args.on_instability, case=args.case, pack_steps=args.pack_steps,
                   **executor_arguments(args))
    print(markdown(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
