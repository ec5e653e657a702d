"""The papers' energy figures as tables (#21), from a finished scene-file sweep's cell files; and the VR paper's
Table 1 (cost per scene) from `warpsph bench steps` files.

    python -m warpsph.validation.paper_tables vr-fig7 sweeps/vr_fig7_cpu.json OUT_DIR --json tools/results/vr_fig7_cpu.json
    python -m warpsph.validation.paper_tables blocks sweeps/rankine_fig11_cpu.json OUT_DIR --json tools/results/rankine_fig11_cpu.json
    python -m warpsph.validation.paper_tables table1 BENCH_DIR --json tools/results/vr_table1_h100.json
    python -m warpsph.validation.paper_tables calm sweeps/rankine_fig3_cpu.json OUT_DIR --json tools/results/rankine_fig3_cpu.json
    python -m warpsph.validation.paper_tables vr-fig4 sweeps/vr_fig4_cpu.json OUT_DIR --times 1,2 --json tools/results/vr_fig4_cpu.json

Reads each cell's per-frame series (``kinetic_energy``, ``rotational_energy``, ``frame_times``; see
warpsph/sweep.py) and writes a small JSON (no per-particle data; the energy series thinned to 0.2 s) and the
markdown table beside it (same name, .md).

vr-fig7 (VR paper Fig 7, the Fig 8 dam break): the first cell is the baseline (DFSPH). Columns: E/E_DFSPH at
t = 2, 4, 6, 8, 10 s, E the fluid's kinetic energy averaged over a window of +-WINDOW s around t (the last one
[10 - 2 WINDOW, 10]); the mean over [2, 8] s of the per-frame ratio; "settled": the kinetic energy averaged over
[9, 10] s is at most SETTLE_FACTOR times DFSPH's over the same second (the paper's criterion: "the energy values
after 10 s ... are very close to the DFSPH values", the methods that "have higher energy than DFSPH" do not
settle); and that window's energy over the run's peak (how calm the fluid is in absolute terms).

vr-fig10 (VR paper Fig 10, hemisphere): as vr-fig7 at t = 2.5, 5, ..., 15 s, the means over [0, 15] s (flowing)
and [15, end] s (after), settled over the sweep's last second; times past a run's end give None.

table1 (VR paper Table 1): ms/step of DFSPH, micropolar and VR per scene from BENCH_DIR/table1_<scene>_<model>.json,
the models' overheads, and the paper's minutes and overheads beside them.

blocks (Rankine paper Figs 11-12, falling blocks): per cell the kinetic energy's peak and its time, the energy
at the end over the baseline's (the cell without a model on the same pressure solver), the rotational energy
(Fig 12's second curve) at the peak and at the end, and the rotational/linear ratio.

calm (Rankine paper Figs 3 and 13: how fast the fluid calms down once the stirring body stops): t_s, the stop, is
the last keyframe time of the scene's moving bodies (the first cell's scene; ``--stop T`` overrides it, and is
needed where a body spins or drifts without end). Per cell: E_s, the kinetic energy of the frame nearest t_s (one
frame, not a window mean: a window would mix the stirring before t_s with the decay after it); the calm-down
times, the first frame after t_s whose energy is below 10 % and below 1 % of E_s, as time after t_s (None: not
within the run, or the cell blew up first); those times over the baseline's (the first cell, DFSPH); the 10 % time
against the baseline's E_s (one threshold for every cell: a cell with more energy at the stop has a higher own
threshold); E_end (the mean over the last 0.4 s) over E_s; the stirring's energy (the mean over the second before
t_s) and the model's rotational energy at t_s (not part of E).

vr-fig4 (VR paper Fig 4: the vorticity magnitude of the particles of a 2D slice of the Fig 3 board scene, DFSPH
against MP and VR): runs the sweep's cells itself (a scene-file sweep; not `warpsph sweep`, whose cell files keep
no per-particle data), one worker, to each of --times, and keeps each cell's particles (x, zeta, volume) at those
times in OUT_DIR/cells/<id>.npz (a later call with the same cells and times reads them instead of running). zeta
is the SPH curl of v at the frame for every method (warpsph.diagnostics.vorticity_now: fresh lists, the curl the
models use; not the models' own field, the curl of v~ inside the step). Per time, region and cell: the particles
in the region, |zeta|'s mean, 90th and 99th percentiles and maximum, the enstrophy 1/2 sum V |zeta|^2 (V = m / rho,
the stats CSV's definition, over the region's particles), and mean, p90, p99 and enstrophy over the first cell's
(DFSPH) in the same region at the same time. Regions: each --slab AXIS=CENTRE[:HALF] (|x_AXIS - CENTRE| < HALF;
CENTRE "mid": the domain's mid-plane; HALF default the particle radius: one layer of particles, the paper's 2D
slice), then all the fluid.
"""

import argparse
import json
from pathlib import Path

import numpy as np
from warpsph.device import init_warp
from warpsph.diagnostics import vorticity_now
from warpsph.simulation import InstabilityError, Simulation
from warpsph.sweep import cells, cells_commit, load_sweep, records, scene_of
from warpsph.validation.cases import commit_info, device_info
from warpsph.validation.taylor_green import METHODS

TIMES = (2.0, 4.0, 6.0, 8.0, 10.0)
CALM_LEVELS = (0.1, 0.01)   # calm: E below 10 % and 1 % of the energy at the stop
END_WINDOW = 0.4      # s: E_end, the mean over the run's last END_WINDOW seconds (blocks, calm)
FIG10_TIMES = (2.5, 5.0, 7.5, 10.0, 12.5, 15.0)
WINDOW = 0.2          # s either side of each time
SETTLE_FACTOR = 1.5   # "very close to DFSPH": within 1.5x of its kinetic energy over the last second


def label(models):
    if not models:
        return "DFSPH"
    m = models[0]
    if m["type"] == "vorticity_refinement":
        return f"VR alpha = {m['alpha']:g}"
    if m["type"] == "micropolar":
        return f"micropolar nu_t = {m['transfer_coefficient']:g}"
    if m["type"] == "rankine":
        return f"Rankine beta = {m['beta']:g}"
    return m["type"]


def cell_label(params, fixed=()):
    """The method's name, then the cell's other keys (not those the sweep holds for every cell)."""
    text = label(METHODS[params["method"]] if "method" in params else params.get("models", []))
    if params.get("solver.method") == "iisph":
        text = "IISPH" if text == "DFSPH" else f"{text} (IISPH)"
    other = {k: v for k, v in params.items() if k not in ("method", "models", "solver.method", *fixed)}
    return text + "".join(f", {k} = {v}" for k, v in other.items())


def load(sweep, out):
    spec = load_sweep(sweep)
    rows = []
    pairs = records(spec, out)
    for cell, record in pairs:
        if record is None:
            rows.append({"label": cell_label(cell["params"], spec["fixed"]), "status": "missing"})
            continue
        r = record["row"]
        rows.append({"label": cell_label(cell["params"], spec["fixed"]), "params": cell["params"], "status": record["status"],
                     "unstable": r.get("unstable"), "particles": r["particles"], "steps": r["steps"],
                     "time_reached": r["time_reached"], "wall_s": round(r["wall_s"], 1),
                     "t": np.array(r["frame_times"]), "ke": np.array(r["kinetic_energy"]),
                     "rot": np.array(r.get("rotational_energy") or [0.0] * len(r["kinetic_energy"])),
                     "ens": np.array(r.get("enstrophy") or [0.0] * len(r["kinetic_energy"])),
                     "wake": None if r.get("region_enstrophy") is None else np.array(r["region_enstrophy"]),
                     "particles_end": r.get("particles_end", r["particles"]),
                     "device": record.get("device"), "warp": record.get("warp")})
    meta = {"sweep": str(sweep), "scene": spec["scene"], "scale": spec["scale"], "time": spec["time"],
            "fixed": spec["fixed"], **cells_commit([record for _, record in pairs])}
    return meta, rows


def window_mean(t, e, lo, hi):
    sel = (t >= lo - 1e-9) & (t <= hi + 1e-9)
    return float(np.mean(e[sel])) if sel.any() else None


def thin(t, e, step=0.2):
    """[time, value] at the frames nearest to 0, step, 2 step, ... (frame times end on the step that crosses
    the frame's time, so they are not exact multiples)."""
    picks = sorted({int(np.argmin(np.abs(t - m))) for m in np.arange(0.0, t[-1] + step / 2, step)})
    return [[round(float(t[k]), 3), float(f"{e[k]:.4g}")] for k in picks]


def ratio(a, b):
    return None if a is None or b is None or b <= 0 else a / b


def head(r):
    """The columns every figure table starts with: the method, its status, size and cost."""
    return {"method": r["label"], "status": r["status"], "particles": r["particles"], "steps": r["steps"],
            "wall_s": r["wall_s"]}


def missing(r):
    """The row of a cell whose file is not there."""
    return {"method": r["label"], "status": "missing"}


def end_mean(t, e):
    """The mean over the run's last END_WINDOW seconds."""
    return window_mean(t, e, t[-1] - END_WINDOW, t[-1])


def energy_table(meta, rows, times, means):
    """Each cell's kinetic energy against the first cell's (DFSPH): window ratios at ``times`` (None past either
    run's end), per-frame ratio means over ``means`` ((lo, hi), hi None: to the end), and the sweep's last second
    against DFSPH's ("settled") and the run's peak."""
    base = rows[0]  # DFSPH as the scene file has it
    lo_s, hi_s = meta["time"] - 1.0, meta["time"]
    tail_key = f"E[{lo_s:g},{hi_s:g}]"
    out = []
    for r in rows:
        if r["status"] == "missing":
            out.append(missing(r))
            continue
        row = head(r)
        end = min(meta["time"], r["t"][-1], base["t"][-1])
        for T in times:
            lo, hi = (T - WINDOW, T + WINDOW) if T + WINDOW < end - 1e-9 else (T - 2 * WINDOW, T)
            row[f"E/E_DFSPH t={T:g}"] = None if T > end + 1e-6 else \
                ratio(window_mean(r["t"], r["ke"], lo, hi), window_mean(base["t"], base["ke"], lo, hi))
        n = min(len(r["t"]), len(base["t"]))
        t = r["t"][:n]
        for lo, hi in means:
            key = f"mean E/E_DFSPH [{lo:g},{'end' if hi is None else f'{hi:g}'}]"
            hi = end if hi is None else hi
            sel = (t >= lo - 1e-9) & (t <= hi + 1e-9) & (base["ke"][:n] > 0)
            row[key] = float(np.mean(r["ke"][:n][sel] / base["ke"][:n][sel])) \
                if sel.any() and lo < end - 1e-6 and hi <= end + 1e-6 else None
        tail = window_mean(r["t"], r["ke"], lo_s, hi_s)
        row[f"{tail_key} / E_DFSPH[{lo_s:g},{hi_s:g}]"] = settle = \
            ratio(tail, window_mean(base["t"], base["ke"], lo_s, hi_s))
        row[f"{tail_key} / E_max"] = ratio(tail, float(r["ke"].max()))
        row["E_max (J)"] = float(r["ke"].max())
        row["settled"] = False if r["status"] == "unstable" else None if settle is None else bool(settle <= SETTLE_FACTOR)
        out.append(with_series(row, r, {"kinetic_energy": "ke"}))
    return out


def vr_fig7(meta, rows):
    return energy_table(meta, rows, TIMES, [(2.0, 8.0)])


def vr_fig10(meta, rows):
    """VR Fig 10 (hemisphere): the paper's "more energy than DFSPH when the fluid is flowing (t in [0, 15])"."""
    return energy_table(meta, rows, FIG10_TIMES, [(0.0, 15.0), (15.0, None)])


def _solver(r):
    return (r.get("params") or {}).get("solver.method", "dfsph")


def blocks(meta, rows):
    """Each cell against the baseline (no model) of its own pressure solver."""
    bases = {_solver(r): r for r in rows if r["status"] != "missing" and not r["params"].get("models")}
    out = []
    for r in rows:
        if r["status"] == "missing" or _solver(r) not in bases:
            out.append(missing(r))
            continue
        base = bases[_solver(r)]
        k = int(np.argmax(r["ke"]))
        end, end_rot = end_mean(r["t"], r["ke"]), end_mean(r["t"], r["rot"])
        row = {**head(r), "peak E (J)": float(r["ke"][k]), "peak time (s)": float(r["t"][k]),
               "peak / baseline peak": ratio(float(r["ke"][k]), float(base["ke"].max())),
               "E_end (J)": end,
               "E_end / baseline E_end": ratio(end, end_mean(base["t"], base["ke"])),
               "E_end / peak E": ratio(end, float(r["ke"][k])),
               "E_rot at peak (J)": float(r["rot"][k]), "E_rot peak (J)": float(r["rot"].max()),
               "E_rot end (J)": end_rot, "E_rot/E end": ratio(end_rot, end)}
        for T in (1.0, 2.0, 4.0, 6.0, 8.0, 10.0):
            if T <= r["t"][-1] + 1e-9:
                row[f"E/E_base t={T:g}"] = ratio(window_mean(r["t"], r["ke"], T - WINDOW, min(T + WINDOW, r["t"][-1])),
                                                window_mean(base["t"], base["ke"], T - WINDOW, min(T + WINDOW, base["t"][-1])))
        out.append(with_series(row, r))
    return out


ENERGIES = {"kinetic_energy": "ke", "rotational_energy": "rot"}


def with_series(row, r, series=ENERGIES):
    """``row`` with the cell's instability note and its ``series`` ({name: the cell's key}) every 0.2 s."""
    if r["status"] == "unstable":
        row["unstable"] = r["unstable"]
    for name, key in series.items():
        row[f"{name}_every_0.2s"] = thin(r["t"], r[key])
    return row


def stop_time(sweep):
    """calm's t_s: the last keyframe time of the moving bodies of the sweep's first cell's scene (a drift's end
    too, a spin's spin_end + spin_down, the last of its spin_rates); None when no body has keyframes, or one spins or
    drifts to the run's end (give --stop)."""
    times = []
    for body in scene_of(cells(load_sweep(sweep))[0]).obstacles:
        m = body.motion
        if m is None:
            continue
        drifts, spins = any(m.velocity) or any(m.acceleration), m.angular_velocity != 0.0
        if (spins and m.spin_end is None) or (drifts and m.end is None):
            return None
        if m.spin_rates and (m.spin_repeat or m.spin_rates[-1].rate != 0.0):
            return None
        times += (([m.keyframes[-1].time] if m.keyframes else []) + ([m.end] if drifts else [])
                  + ([m.spin_end + m.spin_down] if spins else []) + ([m.spin_rates[-1].time] if m.spin_rates else []))
    return max(times, default=None)


def calm_times(t, e, t_s, e_ref=None):
    """(E_s, {level: time after t_s of the first frame after t_s with E < level E_ref, None if none}) for
    CALM_LEVELS; E_s the energy of the frame nearest t_s, E_ref E_s unless given (None, and no times, when the
    run ended before t_s)."""
    if t[-1] < t_s - WINDOW:
        return None, dict.fromkeys(CALM_LEVELS)
    k = int(np.argmin(np.abs(t - t_s)))
    e_s = float(e[k])
    times = {}
    for level in CALM_LEVELS:
        below = np.nonzero(e[k + 1:] < level * (e_s if e_ref is None else e_ref))[0]
        times[level] = float(t[k + 1 + below[0]] - t_s) if below.size else None
    return e_s, times


def calm(meta, rows):
    """Rankine Figs 3 and 13: per cell the calm-down times after the stop meta["stop_time"], against the first
    cell's (DFSPH)."""
    t_s = meta["stop_time"]
    base = rows[0] if rows[0]["status"] != "missing" else None
    base_e, base_times = calm_times(base["t"], base["ke"], t_s) if base else (None, dict.fromkeys(CALM_LEVELS))
    out = []
    for r in rows:
        if r["status"] == "missing":
            out.append(missing(r))
            continue
        e_s, times = calm_times(r["t"], r["ke"], t_s)
        row = {**head(r), "E stirring (J)": window_mean(r["t"], r["ke"], t_s - 1.0, t_s), "E_s (J)": e_s,
               "E_rot,s (J)": calm_times(r["t"], r["rot"], t_s)[0]}
        for level in CALM_LEVELS:
            row[f"calm {level:.0%} (s)"] = times[level]
        for level in CALM_LEVELS:
            row[f"calm {level:.0%} / DFSPH"] = ratio(times[level], base_times[level])
        common = calm_times(r["t"], r["ke"], t_s, base_e)[1][CALM_LEVELS[0]] if base_e else None
        row[f"calm {CALM_LEVELS[0]:.0%} of DFSPH's E_s (s)"] = common
        row["E_end / E_s"] = ratio(end_mean(r["t"], r["ke"]), e_s)
        row["run end (s)"] = float(r["t"][-1])
        out.append(with_series(row, r))
    return out


def river(meta, rows):
    """Rankine Fig 7 (river tunnel): enstrophy and kinetic energy over the last second, per particle too."""
    out = []
    for r in rows:
        if r["status"] == "missing":
            out.append(missing(r))
            continue
        t_end = r["t"][-1]
        row = {"method": r["label"], "status": r["status"], "particles (end)": r["particles_end"],
               "steps": r["steps"], "wall_s": r["wall_s"],
               "enstrophy, last 1 s": window_mean(r["t"], r["ens"], t_end - 1.0, t_end),
               "KE (J), last 1 s": window_mean(r["t"], r["ke"], t_end - 1.0, t_end)}
        row["enstrophy per particle"] = ratio(row["enstrophy, last 1 s"], float(r["particles_end"] or 0))
        if r["wake"] is not None:  # the sweep's region (the wake behind the hemisphere)
            row["wake enstrophy, last 1 s"] = window_mean(r["t"], r["wake"], t_end - 1.0, t_end)
        out.append(with_series(row, r, {"enstrophy": "ens"}))
    base = next((x for x in out if x["method"] in ("DFSPH", "IISPH")), None)
    for x in out:
        for key in ("enstrophy", "wake enstrophy"):
            if base and x.get(f"{key}, last 1 s") is not None:
                x[f"{key} / baseline"] = ratio(x[f"{key}, last 1 s"], base[f"{key}, last 1 s"])
    return out


# VR paper Table 1: scene file, experiment, figure, fluid particles, total minutes with DFSPH / micropolar / VR
TABLE1 = [("dam_break_board", "Board", 3, 1_180_000, (2401.2, 2565.9, 2565.1)),
          ("stirring_rod", "Stirring", 5, 1_390_000, (2399.9, 2864.4, 2693.4)),
          ("hemisphere", "Sphere", 9, 899_800, (1657.4, 1715.2, 1827.2)),
          ("dam_break_pillars", "Pillars", 11, 457_000, (156.4, 188.3, 218.5)),
          ("propeller", "Propeller", 12, 1_290_000, (1782.1, 2309.1, 2338.9))]
TABLE1_MODELS = (("DFSPH", "none"), ("MP", "micropolar"), ("VR", "vorticity_refinement"))


def overhead(t, base):
    return None if t is None or not base else round(100 * (t / base - 1), 1)


def table1(folder):
    """VR Table 1 from ``table1_<scene>_<model>.json`` (``warpsph bench steps``): ms/step per model, the models'
    overhead over DFSPH, the paper's minutes and overheads beside them. A missing file, or one whose ``model`` is
    not its name's, leaves its column None (listed under "not used")."""
    rows, benches, skipped = [], [], []
    for scene, name, fig, paper_n, minutes in TABLE1:
        row, ms = {"experiment": name, "figure": fig, "particles": None}, {}
        for short, model in TABLE1_MODELS:
            f = Path(folder) / f"table1_{scene}_{model}.json"
            b = json.loads(f.read_text()) if f.is_file() else None
            b = b[0] if isinstance(b, list) else b
            if b and b.get("model", model) != model:  # a bench that ran another model (e.g. the scene's own)
                skipped.append(f"{f.name} ran {b['model']}")
                b = None
            if b:
                benches.append(b)
                row["particles"] = row["particles"] or b.get("fluid_particles")
            ms[short] = row[f"{short} ms/step"] = round(b["ms_per_step"], 3) if b else None
        paper = dict(zip(ms, minutes))
        for short in ("MP", "VR"):
            row[f"{short} overhead %"] = overhead(ms[short], ms["DFSPH"])
        row["paper particles"] = paper_n
        for short in ms:
            row[f"paper {short} min"] = paper[short]
        for short in ("MP", "VR"):
            row[f"paper {short} overhead %"] = overhead(paper[short], paper["DFSPH"])
        rows.append(row)
    meta = {k: ", ".join(sorted({str(b.get(k)) for b in benches})) or None for k in ("device", "warp", "commit")}
    return {"folder": str(folder), **meta, "not used": skipped}, rows


# --- VR paper Fig 4: vorticity magnitude in a slice -------------------------------------------------------------

AXES = "xyz"


def parse_slab(text):
    """--slab AXIS=CENTRE[:HALF] -> (axis index, centre or None (the domain's mid-plane), half or None (the
    particle radius))."""
    axis, _, rest = text.partition("=")
    centre, _, half = rest.partition(":")
    if axis not in AXES or not centre:
        raise ValueError(f"expected AXIS=CENTRE[:HALF] (AXIS x, y or z; CENTRE metres or mid), got {text!r}")
    return AXES.index(axis), None if centre == "mid" else float(centre), float(half) if half else None


def slab_regions(slabs, scene):
    """[(name, axis, centre, half)] of the parsed slabs on ``scene`` (mid-plane and radius filled in), then all
    the fluid (axis None)."""
    out = []
    for axis, centre, half in slabs:
        d = scene.domain
        centre = 0.5 * (d.min[axis] + d.max[axis]) if centre is None else centre
        half = scene.particle_radius if half is None else half
        out.append((f"|{AXES[axis]} - {centre:g}| < {half:.3g}", axis, centre, half))
    return out + [("all fluid", None, None, None)]


def vorticity_stats(magnitude, volume):
    """|zeta|'s mean, 90th and 99th percentiles and maximum, and the enstrophy 1/2 sum V |zeta|^2, of the given
    particles (None for none)."""
    n = len(magnitude)
    if n == 0:
        return {"particles": 0, "mean |zeta| (1/s)": None, "p90 |zeta|": None, "p99 |zeta|": None,
                "max |zeta|": None, "enstrophy": None}
    p90, p99 = np.percentile(magnitude, [90, 99])
    return {"particles": n, "mean |zeta| (1/s)": float(np.mean(magnitude)), "p90 |zeta|": float(p90),
            "p99 |zeta|": float(p99), "max |zeta|": float(np.max(magnitude)),
            "enstrophy": float(0.5 * np.sum(volume * magnitude ** 2))}


def region_mask(x, axis, centre, half):
    return np.ones(len(x), bool) if axis is None else np.abs(x[:, axis] - centre) < half


def _fig4_key(t):
    return f"{t:g}"


def fig4_cell(cell, times, device):
    """Runs one scene cell to each of ``times``; returns (record, {time key: (x, zeta, volume)})."""
    import time as clock

    t0 = clock.perf_counter()
    sim = Simulation(scene_of(cell), device=device)
    record = {"id": cell["id"], "params": cell["params"], "status": "done", "particles": sim.num_fluid,
              "setup_s": round(clock.perf_counter() - t0, 1), "times": {}}
    arrays, t0 = {}, clock.perf_counter()
    try:
        for t in sorted(times):
            sim.run(until_time=t)
            x, zeta, volume = vorticity_now(sim)
            arrays[_fig4_key(t)] = (x, zeta, volume)
            d = sim.scene.domain  # particles past the domain's faces (not yet the health check's margin)
            outside = int(np.sum(np.any((x < np.asarray(d.min)) | (x > np.asarray(d.max)), axis=1)))
            record["times"][_fig4_key(t)] = {"time_reached": sim.time, "steps": sim.step_count,
                                             "wall_s": round(clock.perf_counter() - t0, 1), "outside_domain": outside,
                                             "removed": sim.inflow.removed_in_sinks if sim.inflow is not None else 0}
    except InstabilityError as exc:
        record.update(status="unstable", unstable=str(exc))
    record.update(steps=sim.step_count, time_reached=sim.time, wall_s=round(clock.perf_counter() - t0, 1))
    return record, arrays


def fig4_records(sweep, out, times, device=None):
    """(meta, [(label, record, arrays)]) for the sweep's cells, each run (or read from OUT/cells) to ``times``."""
    spec = load_sweep(sweep)
    if spec.get("kind") != "scene":
        raise ValueError("vr-fig4 takes a scene-file sweep (scene, scale, cells)")
    device = device or spec.get("device") or "cpu"
    init_warp()
    folder = Path(out) / "cells"
    folder.mkdir(parents=True, exist_ok=True)
    keys = [_fig4_key(t) for t in times]
    results = []
    for cell in cells(spec):
        path = folder / f"{cell['id']}.json"
        record = json.loads(path.read_text()) if path.is_file() else None
        if record and record["params"] == cell["params"] and all(  # stored, or past where the run blew up
                k in record["times"] or (record["status"] == "unstable" and t > record["time_reached"])
                for k, t in zip(keys, times)):
            with np.load(path.with_suffix(".npz")) as f:
                arrays = {k: (f[f"x_{k}"], f[f"zeta_{k}"], f[f"volume_{k}"]) for k in record["times"]}
        else:
            print(f"running {cell_label(cell['params'], spec['fixed'])} to t = {', '.join(keys)} s", flush=True)
            record, arrays = fig4_cell(cell, times, device)
            record.update(device_info(device))
            record.update(commit_info())
            np.savez_compressed(path.with_suffix(".npz"), **{f"{name}_{k}": a for k, v in arrays.items()
                                                             for name, a in zip(("x", "zeta", "volume"), v)})
            path.write_text(json.dumps(record, indent=1) + "\n")
        results.append((cell_label(cell["params"], spec["fixed"]), record, arrays))
    done = [r for _, r, _ in results]
    meta = {"sweep": str(sweep), "scene": spec["scene"], "scale": spec["scale"], "time": max(times),
            "fixed": spec["fixed"], **cells_commit(done), "device": done[0].get("device"), "warp": done[0].get("warp"),
            "times": list(times)}
    return meta, results, cells(spec)[0]


def vr_fig4(results, regions, times):
    """The table: per time, region and cell the vorticity statistics, and the ratios to the first cell's (DFSPH)
    in the same region at the same time. ``results``: [(label, record, {time key: (x, zeta, volume)})]."""
    rows = []
    for t in times:
        k = _fig4_key(t)
        for name, axis, centre, half in regions:
            base = None
            for n, (label_, record, arrays) in enumerate(results):
                row = {"t (s)": t, "region": name, "method": label_}
                if k not in arrays:
                    row.update(vorticity_stats([], []))
                    row["status"] = record["status"]
                else:
                    x, zeta, volume = arrays[k]
                    sel = region_mask(x, axis, centre, half)
                    row.update(vorticity_stats(np.linalg.norm(zeta[sel], axis=1), volume[sel]))
                if n == 0:
                    base = row
                for key, short in (("mean |zeta| (1/s)", "mean"), ("p90 |zeta|", "p90"), ("p99 |zeta|", "p99"),
                                   ("enstrophy", "enstrophy")):
                    row[f"{short} / DFSPH"] = ratio(row[key], base[key])
                rows.append(row)
    return rows


def fig4_runs(results, times):
    """Per cell: its run (status, particles, steps, wall time), where the fluid is at each time (the front, the
    99th percentile of x) and how many particles are past the domain's faces (into the walls' stand-off)."""
    out = []
    sinks = any(m.get("removed") for _, record, _ in results for m in record["times"].values())
    for label_, record, arrays in results:
        row = {"method": label_, "status": record["status"], "particles": record["particles"],
               "steps": record["steps"], "time reached (s)": round(record["time_reached"], 4),
               "wall_s": record["wall_s"]}
        for t in times:
            k = _fig4_key(t)
            row[f"front x at t={k} (m)"] = float(np.percentile(arrays[k][0][:, 0], 99)) if k in arrays else None
        for t in times:
            row[f"past the walls at t={_fig4_key(t)}"] = record["times"].get(_fig4_key(t), {}).get("outside_domain")
        if sinks:  # a sweep with sinks (fixed "sinks") that removed fluid
            for t in times:
                row[f"removed by t={_fig4_key(t)}"] = record["times"].get(_fig4_key(t), {}).get("removed")
        if record.get("unstable"):
            row["unstable"] = record["unstable"]
        out.append(row)
    return out


def fig4_markdown(title, meta, runs, rows, note):
    lines = ["", "Runs (front: the 99th percentile of the fluid's x; past the walls: fluid particles beyond the "
                 "domain's faces, the health check stops a run one radius past the wall layer):", ""]
    return markdown(title, meta, rows, note) + "\n".join(lines + table_lines(runs)) + "\n"


def fmt(v):
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 100 else f"{v:.1f}" if abs(v) < 1e6 else f"{v:.4g}"
    return str(v)


def header(meta):
    if "scene" not in meta:
        unused = f" Not used (another model than the name's): {'; '.join(meta['not used'])}." if meta.get("not used") else ""
        return (f"Benchmarks in {meta['folder']}; device {meta['device']}, Warp {meta['warp']}, "
                f"commit {meta['commit']}.{unused}")
    return (f"Scene {meta['scene']} at scale {meta['scale']}, {meta['time']} s simulated; device {meta['device']}, "
            f"Warp {meta['warp']}, commit {meta.get('commit')}"
            + (" (this checkout's: the cells do not record the code that ran them)."
               if meta.get("commit_from") == "table" else ".")
            + (f" Every cell: {', '.join(f'{k} = {v}' for k, v in meta['fixed'].items())}." if meta["fixed"] else ""))


def table_lines(rows):
    """A markdown table of ``rows`` (the first row's columns, less the series, status and instability note),
    then a line for each row that did not finish."""
    cols = [k for k in rows[0] if not k.endswith("_every_0.2s") and k not in ("status", "unstable")]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(fmt(r.get(k)) for k in cols) + " |" for r in rows]
    return lines + [f"\n{r['method']}: {r['status']}" + (f" ({r['unstable']})" if r.get("unstable") else "")
                    for r in rows if r.get("status", "done") != "done"]


def markdown(title, meta, rows, note):
    return "\n".join([f"# {title}", "", note, "", header(meta), ""] + table_lines(rows)) + "\n"


NOTES = {
    "vr-fig7": (f"E: the fluid's kinetic energy, averaged over +-{WINDOW} s around each time (the last: "
                f"[{10 - 2 * WINDOW:g}, 10] s); mean [2,8]: the per-frame ratio's mean; settled: E over "
                f"[9, 10] s at most {SETTLE_FACTOR}x DFSPH's over the same second."),
    "blocks": ("E: the fluid's kinetic energy (linear); E_rot: the model's rotational energy (micropolar: "
               "1/2 m I omega^2; Rankine: the spin zeta/2 of a sphere of the particle radius; 0 without a model); "
               f"E_end: the mean over the last 0.4 s; E/E_base: window means of +-{WINDOW} s."),
    "vr-fig10": (f"E: the fluid's kinetic energy, averaged over +-{WINDOW} s around each time (the last before the "
                 f"run's end: [t - {2 * WINDOW:g}, t]; past the end: —); mean [0,15] (flowing) and [15,end] (after): "
                 f"the per-frame ratio's mean; settled: E over the last second at most {SETTLE_FACTOR}x DFSPH's."),
    "table1": ("ms/step: `warpsph bench steps` (ms_per_step, the production stepper) per model at the scene's paper "
               "particle count; overhead: over DFSPH's ms/step. The paper's columns: its total minutes and the "
               "overheads they give."),
    "calm": (f"t_s: the stop (the last keyframe time of the scene's moving bodies, or --stop); E_s: the fluid's "
             f"kinetic energy at the frame nearest t_s; calm 10 % / 1 %: the time after t_s of the first frame "
             f"whose energy is below 10 % / 1 % of E_s (—: not within the run, whose end less t_s bounds it from "
             f"below); / DFSPH: over the first cell's; calm {CALM_LEVELS[0]:.0%} of DFSPH's E_s: the same against one "
             f"threshold for every cell, the first cell's; E_end: the mean over the last {END_WINDOW:g} s; E stirring: "
             f"the mean over [t_s - 1, t_s]; E_rot,s: the model's rotational energy at the frame nearest t_s "
             f"(micropolar: its spin field's; Rankine: zeta/2 as a sphere's spin; 0 for DFSPH), not in E."),
    "vr-fig4": ("zeta: the SPH curl of v (eq 6, fluid neighbours, fresh lists) at each time, the same for every "
                "method (not a model's own field); |zeta| mean, p90, p99, max over the region's particles; enstrophy: "
                "1/2 sum V |zeta|^2, V = m / rho, over the region (as the stats CSV's, there over all the fluid); "
                "/ DFSPH: over the first cell's in the same region at the same time."),
    "river": ("enstrophy: 1/2 sum V |zeta|^2 over every fluid particle in the tunnel, averaged over the last "
              "simulated second; per particle: over the fluid count at the end; wake enstrophy (when the sweep has a "
              "region): the same over the particles inside the sweep's region (the wake box)."),
}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", choices=["vr-fig7", "vr-fig10", "blocks", "river", "calm", "table1", "vr-fig4"])
    p.add_argument("sweep", help="the sweep file (table1: the folder of table1_<scene>_<model>.json)")
    p.add_argument("out", nargs="?", help="the sweep's --out folder (not for table1)")
    p.add_argument("--json", required=True, help="result JSON (the .md goes beside it)")
    p.add_argument("--title", default=None)
    p.add_argument("--note", default="", help="a sentence appended to the table's note (what the run changed, why)")
    p.add_argument("--stop", type=float, default=None,
                   help="calm: the stop time t_s (s); default the last keyframe time of the scene's moving bodies")
    p.add_argument("--times", default=None,
                   help="vr-fig4: comma-separated times (s) to measure at; default the sweep's time")
    p.add_argument("--slab", action="append", default=None, metavar="AXIS=CENTRE[:HALF]",
                   help="vr-fig4: a slab |x_AXIS - CENTRE| < HALF (metres; CENTRE mid: the domain's mid-plane; HALF "
                        "default the particle radius), repeatable; default z=mid. All the fluid is always added")
    p.add_argument("--device", default=None, help="vr-fig4: the device (default the sweep's, else cpu)")
    a = p.parse_args(argv)
    if (a.kind == "table1") != (a.out is None):
        p.error("table1 takes the benchmarks' folder alone; the other kinds a sweep file and its --out folder")
    if a.kind == "vr-fig4":
        try:
            slabs = [parse_slab(x) for x in (a.slab or ["z=mid"])]
        except ValueError as exc:
            p.error(str(exc))
        times = [float(t) for t in a.times.split(",")] if a.times else [float(load_sweep(a.sweep)["time"])]
        meta, results, first = fig4_records(a.sweep, a.out, times, a.device)
        regions = slab_regions(slabs, scene_of(first))
        meta["regions"] = [r[0] for r in regions]
        table, runs = vr_fig4(results, regions, times), fig4_runs(results, times)
        command = (f"python -m warpsph.validation.paper_tables vr-fig4 {a.sweep} OUT --times {','.join(f'{t:g}' for t in times)}"
                   + "".join(f" --slab {x}" for x in (a.slab or [])) + f" --json {a.json}")
    elif a.kind == "table1":
        meta, table = table1(a.sweep)
        command = (f"for sn in {' '.join(f'{t[0]}:{t[3]}' for t in TABLE1)}; do s=${{sn%:*}}; "
                   f"for m in none micropolar vorticity_refinement; do warpsph bench steps --device cuda --scene "
                   f"scenes/$s.json --particles ${{sn#*:}} --model $m --out {a.sweep}/table1_${{s}}_$m.json; done; "
                   f"done && python -m warpsph.validation.paper_tables table1 {a.sweep} --json {a.json}")
    else:
        meta, rows = load(a.sweep, a.out)
        done = [r for r in rows if r["status"] != "missing"]
        meta.update(device=done[0]["device"] if done else None, warp=done[0]["warp"] if done else None)
        if a.kind == "calm":
            meta["stop_time"] = a.stop if a.stop is not None else stop_time(a.sweep)
            if meta["stop_time"] is None:
                p.error("the scene's moving bodies do not stop (no keyframes, or a spin or drift without end): "
                        "give --stop T")
            meta["stop_from"] = "--stop" if a.stop is not None else "the scene's last keyframe"
        table = {"vr-fig7": vr_fig7, "vr-fig10": vr_fig10, "blocks": blocks, "river": river,
                 "calm": calm}[a.kind](meta, rows)
        command = (f"warpsph sweep {a.sweep} --out OUT --workers 2 && python -m warpsph.validation.paper_tables {a.kind} "
                   f"{a.sweep} OUT --json {a.json}" + (f" --stop {a.stop:g}" if a.stop is not None else ""))
    title = a.title or {"vr-fig7": "VR paper Fig 7: kinetic energy against DFSPH",
                        "vr-fig10": "VR paper Fig 10: hemisphere, kinetic energy against DFSPH",
                        "blocks": "Rankine paper Figs 11-12: falling blocks",
                        "river": "Rankine paper Fig 7: river tunnel, beta against nu_t",
                        "calm": "Rankine paper Figs 3 and 13: calm-down time after the stirring body stops",
                        "table1": "VR paper Table 1: cost per scene",
                        "vr-fig4": "VR paper Fig 4: vorticity magnitude in a slice of the board scene"}[a.kind]
    note = NOTES[a.kind] + (f" Here t_s = {meta['stop_time']:g} s ({meta['stop_from']})." if a.kind == "calm" else "") \
        + (f" {a.note}" if a.note else "")
    result = {"title": title, "note": note, **meta, "command": command, "rows": table}
    if a.kind == "vr-fig4":
        result["runs"] = runs
    path = Path(a.json)
    path.write_text(json.dumps(result, indent=1) + "\n")
    path.with_suffix(".md").write_text(fig4_markdown(title, meta, runs, table, note) if a.kind == "vr-fig4"
                                       else markdown(title, meta, table, note))
    print(path.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
