"""The papers' energy figures as tables (#21), from a finished scene-file sweep's cell files.

    python tools/paper_tables.py vr-fig7 sweeps/vr_fig7_cpu.json OUT_DIR --json tools/results/vr_fig7_cpu.json
    python tools/paper_tables.py blocks sweeps/rankine_fig11_cpu.json OUT_DIR --json tools/results/rankine_fig11_cpu.json

Reads each cell's per-frame series (``kinetic_energy``, ``rotational_energy``, ``frame_times``; see
warpsph/sweep.py) and writes a small JSON (no per-particle data; the energy series thinned to 0.2 s) and the
markdown table beside it (same name, .md).

vr-fig7 (VR paper Fig 7, the Fig 8 dam break): the first cell is the baseline (DFSPH). Columns: E/E_DFSPH at
t = 2, 4, 6, 8, 10 s, E the fluid's kinetic energy averaged over a window of +-WINDOW s around t (the last one
[10 - 2 WINDOW, 10]); the mean over [2, 8] s of the per-frame ratio; "settled": the kinetic energy averaged over
[9, 10] s is at most SETTLE_FACTOR times DFSPH's over the same second (the paper's criterion: "the energy values
after 10 s ... are very close to the DFSPH values", the methods that "have higher energy than DFSPH" do not
settle); and that window's energy over the run's peak (how calm the fluid is in absolute terms).

blocks (Rankine paper Figs 11-12, falling blocks): per cell the kinetic energy's peak and its time, the energy
at the end over the baseline's (the cell without a model on the same pressure solver), the rotational energy
(Fig 12's second curve) at the peak and at the end, and the rotational/linear ratio.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

TIMES = (2.0, 4.0, 6.0, 8.0, 10.0)
WINDOW = 0.2          # s either side of each time
SETTLE_WINDOW = (9.0, 10.0)
SETTLE_FACTOR = 1.5   # "very close to DFSPH": within 1.5x of its kinetic energy over [9, 10] s


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
    from warpsph.validation.taylor_green import METHODS

    text = label(METHODS[params["method"]] if "method" in params else params.get("models", []))
    if params.get("solver.method") == "iisph":
        text = "IISPH" if text == "DFSPH" else f"{text} (IISPH)"
    other = {k: v for k, v in params.items() if k not in ("method", "models", "solver.method", *fixed)}
    return text + "".join(f", {k} = {v}" for k, v in other.items())


def load(sweep, out):
    from warpsph.sweep import load_sweep, records
    from warpsph.validation.cases import commit_info

    spec = load_sweep(sweep)
    rows = []
    for cell, record in records(spec, out):
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
                     "particles_end": r.get("particles_end", r["particles"]),
                     "device": record.get("device"), "warp": record.get("warp")})
    meta = {"sweep": str(sweep), "scene": spec["scene"], "scale": spec["scale"], "time": spec["time"],
            "fixed": spec["fixed"], **commit_info()}
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


def vr_fig7(meta, rows):
    base = rows[0]  # DFSPH as the scene file has it
    t_end = meta["time"]
    out = []
    for r in rows:
        if r["status"] == "missing":
            out.append({"method": r["label"], "status": "missing"})
            continue
        row = {"method": r["label"], "status": r["status"], "particles": r["particles"], "steps": r["steps"],
               "wall_s": r["wall_s"]}
        for T in TIMES:
            lo, hi = (T - WINDOW, T + WINDOW) if T < t_end - 1e-9 else (T - 2 * WINDOW, T)
            row[f"E/E_DFSPH t={T:g}"] = ratio(window_mean(r["t"], r["ke"], lo, hi),
                                             window_mean(base["t"], base["ke"], lo, hi))
        n = min(len(r["t"]), len(base["t"]))
        t = r["t"][:n]
        sel = (t >= 2.0 - 1e-9) & (t <= 8.0 + 1e-9) & (base["ke"][:n] > 0)
        row["mean E/E_DFSPH [2,8]"] = float(np.mean(r["ke"][:n][sel] / base["ke"][:n][sel])) if sel.any() else None
        tail = window_mean(r["t"], r["ke"], *SETTLE_WINDOW)
        row["E[9,10] / E_DFSPH[9,10]"] = ratio(tail, window_mean(base["t"], base["ke"], *SETTLE_WINDOW))
        row["E[9,10] / E_max"] = ratio(tail, float(r["ke"].max()))
        row["E_max (J)"] = float(r["ke"].max())
        row["settled"] = None if row["E[9,10] / E_DFSPH[9,10]"] is None else \
            bool(row["E[9,10] / E_DFSPH[9,10]"] <= SETTLE_FACTOR)
        if r["status"] == "unstable":
            row["settled"], row["unstable"] = False, r["unstable"]
        row["kinetic_energy_every_0.2s"] = thin(r["t"], r["ke"])
        out.append(row)
    return out


def _solver(r):
    return (r.get("params") or {}).get("solver.method", "dfsph")


def blocks(meta, rows):
    """Each cell against the baseline (no model) of its own pressure solver."""
    bases = {_solver(r): r for r in rows if r["status"] != "missing" and not r["params"].get("models")}
    out = []
    for r in rows:
        if r["status"] == "missing" or _solver(r) not in bases:
            out.append({"method": r["label"], "status": "missing"})
            continue
        base = bases[_solver(r)]
        k = int(np.argmax(r["ke"]))
        end = window_mean(r["t"], r["ke"], r["t"][-1] - 0.4, r["t"][-1])
        end_rot = window_mean(r["t"], r["rot"], r["t"][-1] - 0.4, r["t"][-1])
        row = {"method": r["label"], "status": r["status"], "particles": r["particles"], "steps": r["steps"],
               "wall_s": r["wall_s"], "peak E (J)": float(r["ke"][k]), "peak time (s)": float(r["t"][k]),
               "peak / baseline peak": ratio(float(r["ke"][k]), float(base["ke"].max())),
               "E_end (J)": end,
               "E_end / baseline E_end": ratio(end, window_mean(base["t"], base["ke"], base["t"][-1] - 0.4,
                                                                 base["t"][-1])),
               "E_end / peak E": ratio(end, float(r["ke"][k])),
               "E_rot at peak (J)": float(r["rot"][k]), "E_rot peak (J)": float(r["rot"].max()),
               "E_rot end (J)": end_rot, "E_rot/E end": ratio(end_rot, end)}
        for T in (1.0, 2.0, 4.0, 6.0, 8.0, 10.0):
            if T <= r["t"][-1] + 1e-9:
                row[f"E/E_base t={T:g}"] = ratio(window_mean(r["t"], r["ke"], T - WINDOW, min(T + WINDOW, r["t"][-1])),
                                                window_mean(base["t"], base["ke"], T - WINDOW, min(T + WINDOW, base["t"][-1])))
        if r["status"] == "unstable":
            row["unstable"] = r["unstable"]
        row["kinetic_energy_every_0.2s"] = thin(r["t"], r["ke"])
        row["rotational_energy_every_0.2s"] = thin(r["t"], r["rot"])
        out.append(row)
    return out


def river(meta, rows):
    """Rankine Fig 7 (river tunnel): enstrophy and kinetic energy over the last second, per particle too."""
    out = []
    for r in rows:
        if r["status"] == "missing":
            out.append({"method": r["label"], "status": "missing"})
            continue
        t_end = r["t"][-1]
        row = {"method": r["label"], "status": r["status"], "particles (end)": r["particles_end"],
               "steps": r["steps"], "wall_s": r["wall_s"],
               "enstrophy, last 1 s": window_mean(r["t"], r["ens"], t_end - 1.0, t_end),
               "KE (J), last 1 s": window_mean(r["t"], r["ke"], t_end - 1.0, t_end)}
        row["enstrophy per particle"] = ratio(row["enstrophy, last 1 s"], float(r["particles_end"] or 0))
        if r["status"] == "unstable":
            row["unstable"] = r["unstable"]
        row["enstrophy_every_0.2s"] = thin(r["t"], r["ens"])
        out.append(row)
    base = next((x for x in out if x["method"] in ("DFSPH", "IISPH")), None)
    for x in out:
        if base and x.get("enstrophy, last 1 s") is not None:
            x["enstrophy / baseline"] = ratio(x["enstrophy, last 1 s"], base["enstrophy, last 1 s"])
    return out


def fmt(v):
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.4g}"
    return str(v)


def markdown(title, meta, rows, note):
    cols = [k for k in rows[0] if not k.endswith("_every_0.2s") and k not in ("status", "unstable")]
    lines = [f"# {title}", "", note, "",
             f"Scene {meta['scene']} at scale {meta['scale']}, {meta['time']} s simulated; device {meta['device']}, "
             f"Warp {meta['warp']}, commit {meta.get('commit')}."
             + (f" Every cell: {', '.join(f'{k} = {v}' for k, v in meta['fixed'].items())}." if meta["fixed"] else ""), "",
             "| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(fmt(r.get(k)) for k in cols) + " |")
    bad = [r for r in rows if r.get("status") != "done"]
    for r in bad:
        lines.append(f"\n{r['method']}: {r['status']}" + (f" ({r['unstable']})" if r.get("unstable") else ""))
    return "\n".join(lines) + "\n"


NOTES = {
    "vr-fig7": (f"E: the fluid's kinetic energy, averaged over +-{WINDOW} s around each time (the last: "
                f"[{10 - 2 * WINDOW:g}, 10] s); mean [2,8]: the per-frame ratio's mean; settled: E over "
                f"[9, 10] s at most {SETTLE_FACTOR}x DFSPH's over the same second."),
    "blocks": ("E: the fluid's kinetic energy (linear); E_rot: the model's rotational energy (micropolar: "
               "1/2 m I omega^2; Rankine: the spin zeta/2 of a sphere of the particle radius; 0 without a model); "
               f"E_end: the mean over the last 0.4 s; E/E_base: window means of +-{WINDOW} s."),
    "river": ("enstrophy: 1/2 sum V |zeta|^2 over every fluid particle in the tunnel (not the wake alone), "
              "averaged over the last simulated second; per particle: over the fluid count at the end."),
}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", choices=["vr-fig7", "blocks", "river"])
    p.add_argument("sweep")
    p.add_argument("out", help="the sweep's --out folder")
    p.add_argument("--json", required=True, help="result JSON (the .md goes beside it)")
    p.add_argument("--title", default=None)
    a = p.parse_args(argv)
    meta, rows = load(a.sweep, a.out)
    done = [r for r in rows if r["status"] != "missing"]
    meta.update(device=done[0]["device"] if done else None, warp=done[0]["warp"] if done else None)
    table = {"vr-fig7": vr_fig7, "blocks": blocks, "river": river}[a.kind](meta, rows)
    title = a.title or {"vr-fig7": "VR paper Fig 7: kinetic energy against DFSPH",
                        "blocks": "Rankine paper Figs 11-12: falling blocks",
                        "river": "Rankine paper Fig 7: river tunnel, beta against nu_t"}[a.kind]
    result = {"title": title, "note": NOTES[a.kind], **meta,
              "command": f"warpsph sweep {a.sweep} --out OUT --workers 2 && python tools/paper_tables.py {a.kind} "
                         f"{a.sweep} OUT --json {a.json}", "rows": table}
    path = Path(a.json)
    path.write_text(json.dumps(result, indent=1) + "\n")
    path.with_suffix(".md").write_text(markdown(title, meta, table, NOTES[a.kind]))
    print(path.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
