"""Sweeps: many independent validation runs (cells), spread over processes, GPUs or a Ray cluster; resumable.

    warpsph sweep SWEEP.json --out OUT [--executor local|ray] [--workers N] [--devices cpu|cuda:0,cuda:1]
    warpsph.sweep.run_sweep("SWEEP.json", "OUT", executor="local", workers=2)

A sweep file (JSON, or YAML with pyyaml installed)::

    {"base": "taylor-green",                      # a case of warpsph.validation.cases (warpsph validate CASE)
     "axes": {"method": ["dfsph", "vr"],          # warpsph validate --methods
              "resolution": [16, 24, 32],         # warpsph validate --resolutions
              "solver.density_max_error": [0.01, 0.1],   # any scene key path under "solver" or "time"
              "cfl": [0.3, 0.5]},                 # aliases: cfl, fixed_dt, tolerance (solver.density_max_error)
     "fixed": {"method": "dfsph"},                # optional: values held for every cell (same keys as axes)
     "measures": ["error_pct", "wall_s", "steps", "particles"],   # row keys of the case (default these)
     "warm_up": true}                             # optional: validate's warm-up before the timed run (default true)

Every cell is one ``warpsph validate`` row for (case, method, resolution, device), with the "solver" and "time"
keys of the axes set in the case's scene (they are absent, i.e. the defaults, unless an axis or ``fixed`` names
them). The cells are the product of the axes in the file's order.

Output folder: ``cells/CELL.json`` per cell (written atomically by the driver when the cell ends; ``status``
"done", "unstable" (a blow-up: the health check's diagnostic in ``unstable``, a result) or "failed" (an
exception: its traceback; rerun by the next invocation)), then ``table.json`` and ``table.md`` assembled from
the cell files. Running a sweep again skips the cells whose file holds a result for the same parameters and
runs the failed and missing ones: a killed sweep loses at most the cells in flight.

Executors: ``local`` (concurrent.futures, a fresh process per cell, ``workers`` at once, the devices given to the
worker slots in turn: ``devices=["cuda:0", "cuda:0", "cuda:1", "cuda:1"]`` packs two cells on each GPU) and
``ray`` (``pip install 'warpsph[ray]'``: one task per cell with ``num_gpus`` (a fraction packs several small
cells on one GPU), ``max_retries`` for cells lost with a worker; ``address`` joins a running cluster, otherwise a
local Ray instance starts).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
import os
import time
import traceback
from pathlib import Path

from .errors import SceneError

SWEEP_KEYS = ("name", "base", "axes", "fixed", "measures", "warm_up", "device")
ALIASES = {"cfl": "time.cfl", "fixed_dt": "time.fixed_dt", "tolerance": "solver.density_max_error",
           "density_max_error": "solver.density_max_error", "divergence_max_error": "solver.divergence_max_error",
           "methods": "method", "resolutions": "resolution"}
SCENE_SECTIONS = ("solver", "time")
DEFAULT_MEASURES = ("particles", "error_pct", "steps", "wall_s")
# row keys of warpsph.validation.cases per case (besides case, method, resolution, error_units)
COMMON_MEASURES = ("particles", "error_pct", "wall_s", "steps", "setup_s", "unstable", "unstable_time")
CASE_MEASURES = {
    "taylor-green": ("time", "l1_speed_error", "peak_speed_exact", "ke_ratio", "ke_ratio_exact", "ke_error_pct",
                     "mean_density_ratio", "pack_steps", "error_pct_frames"),
    "lamb-oseen": ("time", "core_radius_m", "core_spacings", "l1_error_m_per_s", "omega_ratio", "omega_curl_ratio",
                   "omega_decay", "omega_decay_exact", "nu_effective", "r_peak", "r_peak_exact", "ke_ratio",
                   "centre_offset", "error_pct_frames"),
    "hydrostatic": ("radius", "T", "density_error_mean_pct", "density_error_mean_abs_pct", "density_error_max_pct",
                    "max_speed", "mid_depth_pressure_ratio", "probe_pressure_rms_error_pct"),
    "dam-front": ("front_rms_shifted", "front_rms_raw", "time_shift_T", "points", "depth", "T_end"),
}
TIMING_MEASURES = ("wall_s", "setup_s", "elapsed_s")  # differ from run to run: not compared between executors


# --- the sweep file ------------------------------------------------------------------------------------

def _tiny_scene(overrides):
    """A minimal scene dict with ``overrides`` ({"solver.x": v, "time.y": w}) set, for checking them."""
    from .scene import with_overrides

    data = {"name": "sweep-check", "particle_radius": 0.1, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [0.5, 0.5, 0.5]}]}
    return with_overrides(data, overrides)


def load_sweep(source):
    """The sweep file (a path, JSON or YAML) or dict, checked; returns the normalised spec (a dict with base,
    case, axes (an ordered list of [key, values]), fixed, measures, warm_up, name). Raises
    :class:`warpsph.errors.SceneError` naming the file and the key."""
    from .validation.cases import CASES, MIN_RESOLUTION
    from .validation.taylor_green import METHODS

    file = "<sweep>"
    if not isinstance(source, dict):
        file = str(source)
        path = Path(source)
        if not path.is_file():
            raise SceneError(file, "", "no such sweep file")
        text = path.read_text()
        if path.suffix.lower() in (".yaml", ".yml"):
            try:
                import yaml
            except ImportError:
                raise SceneError(file, "", "YAML sweep files need pyyaml (pip install pyyaml); or write it as JSON") from None
            try:
                data = yaml.safe_load(text)
            except yaml.YAMLError as exc:
                raise SceneError(file, "", f"not valid YAML: {exc}") from None
        else:
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise SceneError(file, "", f"not valid JSON: {exc}") from None
    else:
        data = source
    if not isinstance(data, dict):
        raise SceneError(file, "", "expected an object with keys base, axes, measures")
    for key in data:
        if key not in SWEEP_KEYS:
            raise SceneError(file, key, f"unknown key; known keys: {', '.join(SWEEP_KEYS)}")
    if "base" not in data:
        raise SceneError(file, "base", f"missing: a validation case ({', '.join(CASES)})")
    base = data["base"]
    if isinstance(base, dict):
        if set(base) != {"case"}:
            raise SceneError(file, "base", "expected a case name or {\"case\": NAME}")
        base = base["case"]
    if not isinstance(base, str) or not base:
        raise SceneError(file, "base", f"expected a validation case name ({', '.join(CASES)}), got {base!r}")
    if base not in CASES:
        if base.endswith((".json", ".yaml", ".yml")) or Path(base).exists():
            raise SceneError(file, "base", f"scene-file sweeps ('{base}') are not supported yet; use a validation "
                                           f"case: {', '.join(CASES)}")
        raise SceneError(file, "base", f"unknown case '{base}'; expected one of {', '.join(CASES)}")
    case = base

    def check_value(where, key, value):
        if key == "method":
            if not isinstance(value, str) or value not in METHODS:
                raise SceneError(file, where, f"unknown method {value!r}; expected one of {', '.join(METHODS)}")
        elif key == "resolution":
            if isinstance(value, bool) or not isinstance(value, int) or value < MIN_RESOLUTION:
                raise SceneError(file, where, f"expected an integer >= {MIN_RESOLUTION}, got {value!r}")
        else:
            try:
                from .scene import scene_from_dict

                scene_from_dict(_tiny_scene({key: value}))
            except SceneError as exc:
                raise SceneError(file, where, exc.reason) from None
            except (TypeError, ValueError) as exc:
                raise SceneError(file, where, str(exc)) from None

    def check_key(where, key):
        key = ALIASES.get(key, key)
        if key in ("method", "resolution"):
            return key
        parts = key.split(".")
        if len(parts) != 2 or parts[0] not in SCENE_SECTIONS or not parts[1]:
            raise SceneError(file, where, "unknown axis; expected method, resolution, a scene key solver.NAME or "
                                          f"time.NAME, or one of {', '.join(a for a in ALIASES if a not in ('methods', 'resolutions'))}")
        return key

    axes_in = data.get("axes")
    if not isinstance(axes_in, dict) or not axes_in:
        raise SceneError(file, "axes", "expected an object of axis name -> list of values, e.g. "
                                       "{\"method\": [\"dfsph\", \"vr\"], \"resolution\": [16, 32]}")
    axes = []
    for name, values in axes_in.items():
        key = check_key(f"axes.{name}", name)
        if any(key == k for k, _ in axes):
            raise SceneError(file, f"axes.{name}", f"axis {key} given twice")
        if not isinstance(values, list) or not values:
            raise SceneError(file, f"axes.{name}", f"expected a non-empty list of values, got {values!r}")
        for k, value in enumerate(values):
            check_value(f"axes.{name}[{k}]", key, value)
        if len({json.dumps(v, sort_keys=True) for v in values}) != len(values):
            raise SceneError(file, f"axes.{name}", "repeated value")
        axes.append([key, list(values)])
    fixed_in = data.get("fixed", {})
    if not isinstance(fixed_in, dict):
        raise SceneError(file, "fixed", "expected an object of key -> value")
    fixed = {}
    for name, value in fixed_in.items():
        key = check_key(f"fixed.{name}", name)
        if any(key == k for k, _ in axes):
            raise SceneError(file, f"fixed.{name}", f"{key} is also an axis")
        check_value(f"fixed.{name}", key, value)
        fixed[key] = value
    keys = [k for k, _ in axes] + list(fixed)
    if "resolution" not in keys:
        raise SceneError(file, "axes", "needs a resolution (an axis or in fixed)")
    if "method" not in keys:
        fixed["method"] = "dfsph"
    for values in itertools.product(*[v for _, v in axes]):  # keys checked together (min <= max iterations, ...)
        overrides = {k: v for k, v in [*zip([k for k, _ in axes], values), *fixed.items()] if "." in k}
        try:
            from .scene import scene_from_dict

            scene_from_dict(_tiny_scene(overrides))
        except SceneError as exc:
            raise SceneError(file, "axes", f"the cell {overrides}: {exc.key}: {exc.reason}") from None
    measures = data.get("measures", list(DEFAULT_MEASURES))
    known = COMMON_MEASURES + CASE_MEASURES[case]
    if not isinstance(measures, list) or not measures:
        raise SceneError(file, "measures", f"expected a non-empty list of row keys, e.g. {list(DEFAULT_MEASURES)}")
    for k, m in enumerate(measures):
        if m not in known:
            raise SceneError(file, f"measures[{k}]", f"unknown measure {m!r} for {case}; known: {', '.join(known)}")
    warm = data.get("warm_up", True)
    if not isinstance(warm, bool):
        raise SceneError(file, "warm_up", f"expected true or false, got {warm!r}")
    device = data.get("device")
    if device is not None and not isinstance(device, str):
        raise SceneError(file, "device", f"expected a device name (cpu, cuda:0, ...), got {device!r}")
    name = data.get("name", Path(file).stem if file != "<sweep>" else "sweep")
    if not isinstance(name, str):
        raise SceneError(file, "name", f"expected a string, got {name!r}")
    return {"name": name, "base": data["base"], "case": case, "axes": axes, "fixed": fixed,
            "measures": list(measures), "warm_up": warm, "device": device}


def cells(spec):
    """The cells of ``spec`` in order: dicts {"case", "params", "warm_up", "id"}."""
    out = []
    names = [k for k, _ in spec["axes"]]
    for values in itertools.product(*[v for _, v in spec["axes"]]):
        params = dict(zip(names, values))
        params.update(spec["fixed"])
        out.append({"case": spec["case"], "params": params, "warm_up": spec["warm_up"],
                    "id": cell_id(spec["case"], params, [k for k, _ in spec["axes"]])})
    return out


def cell_id(case, params, axis_names):
    """A file name for the cell: the axis values, then a hash of everything that defines it."""
    label = "_".join(f"{k.split('.')[-1]}-{params[k]}" for k in axis_names)
    label = "".join(c if c.isalnum() or c in "-._" else "-" for c in label)[:80]
    digest = hashlib.sha1(json.dumps([case, params], sort_keys=True).encode()).hexdigest()[:8]
    return f"{label}_{digest}"


# --- one cell ------------------------------------------------------------------------------------------

def run_cell(cell, device="cpu"):
    """Runs one cell (in this process) on ``device``; returns its record: status "done" with the row,
    "unstable" with the health check's diagnostic (a result), or "failed" with the traceback."""
    started = time.time()
    record = {"id": cell["id"], "case": cell["case"], "params": cell["params"], "device": device,
              "host": os.uname().nodename, "pid": os.getpid(), "started": started}
    try:
        from .cli import _init_warp  # wp.init() without the no-CUDA-driver warning on a CPU machine

        wp = _init_warp()
        from .simulation import InstabilityError
        from .validation.cases import ERRORS, ROWS, _finite, device_info, warm_up
        from .validation.taylor_green import METHODS

        params = cell["params"]
        models = METHODS[params["method"]]
        overrides = {k: v for k, v in params.items() if "." in k}
        record.update(device_info(device))  # "device": the device's name, "device_alias": cpu, cuda:0, ...
        row = {"case": cell["case"], "method": params["method"], "resolution": params["resolution"],
               "error_units": ERRORS[cell["case"]][0]}
        if cell.get("warm_up", True):
            t0 = time.perf_counter()
            warm_up(models, device, overrides)
            record["warmup_s"] = time.perf_counter() - t0
        try:
            row.update(ROWS[cell["case"]](models, params["resolution"], device, overrides))
            record["status"] = "done"
        except InstabilityError as exc:  # as warpsph validate records it
            row.update(particles=None, error_pct=None, wall_s=None, steps=exc.step, unstable=str(exc),
                       unstable_time=exc.time)
            record["status"] = "unstable"
        wp.synchronize_device(device)
        row["error_pct"] = _finite(row.get("error_pct"))
        record["row"] = row
    except Exception as exc:  # noqa: BLE001 - recorded; the next run of the sweep retries the cell
        record.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    record["elapsed_s"] = time.time() - started
    return record


def _run_cell_in_child(cell, device):
    return run_cell(cell, device)


# --- output --------------------------------------------------------------------------------------------

def _cell_path(out, cell):
    return Path(out) / "cells" / f"{cell['id']}.json"


def finished(out, cell):
    """The cell's record when its file holds a result (done or unstable) for the same case and parameters."""
    path = _cell_path(out, cell)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if record.get("status") in ("done", "unstable") and record.get("case") == cell["case"] \
            and record.get("params") == cell["params"]:
        return record
    return None


def assemble(spec, out):
    """``table.json`` and ``table.md`` in ``out`` from the cell files; returns the table (a dict)."""
    from .validation.cases import commit_info, write_json

    axis_names = [k for k, _ in spec["axes"]]
    rows, counts = [], {"done": 0, "unstable": 0, "failed": 0, "missing": 0}
    for cell in cells(spec):
        path = _cell_path(out, cell)
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError):
            record = {"status": "missing"}
        if record.get("params") not in (None, cell["params"]):
            record = {"status": "missing"}
        status = record.get("status", "missing")
        counts[status] = counts.get(status, 0) + 1
        row = {k: cell["params"][k] for k in axis_names}
        r = record.get("row", {})
        row.update({m: r.get(m) for m in spec["measures"]})
        row["status"] = status
        if status == "unstable":
            row["unstable"] = r.get("unstable")
        if status == "failed":
            row["error"] = record.get("error")
        row["device"] = record.get("device_alias", record.get("device"))
        rows.append(row)
    table = {"sweep": spec["name"], "case": spec["case"], "axes": axis_names, "fixed": spec["fixed"],
             "measures": spec["measures"], "counts": counts, "complete": counts["done"] + counts["unstable"] == len(rows),
             **commit_info(), "rows": rows}
    write_json(table, Path(out) / "table.json")
    _write_text(Path(out) / "table.md", markdown(table))
    return table


def _write_text(path, text):
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _fmt(v):
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def markdown(table):
    cols = table["axes"] + table["measures"] + ["status"]
    lines = [f"# Sweep {table['sweep']}: {table['case']}", ""]
    if table["fixed"]:
        lines += ["Fixed: " + ", ".join(f"{k} = {v}" for k, v in table["fixed"].items()), ""]
    c = table["counts"]
    lines += [f"{c['done']} done, {c['unstable']} unstable, {c['failed']} failed, {c['missing']} missing", ""]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "|".join("---" for _ in cols) + "|")
    for r in table["rows"]:
        cells_ = []
        for k in cols:
            v = r.get(k)
            if k == "status" and r.get("unstable"):
                v = f"unstable: {r['unstable']}"
            elif k == "status" and r.get("error"):
                v = f"failed: {r['error']}"
            cells_.append(_fmt(v).replace("|", "\\|").replace("\n", " "))
        lines.append("| " + " | ".join(cells_) + " |")
    return "\n".join(lines) + "\n"


def comparable(table):
    """The table's rows without the timing measures: what two executors must agree on."""
    return [{k: v for k, v in r.items() if k not in TIMING_MEASURES and k != "device"} for r in table["rows"]]


# --- progress ------------------------------------------------------------------------------------------

class _Progress:
    def __init__(self, total, skipped, log):
        self.total, self.skipped, self.log = total, skipped, log
        self.done = self.failed = self.unstable = self.running = 0
        self.start = time.time()

    def line(self, note=""):
        finished_now = self.done + self.unstable + self.failed
        left = self.total - self.skipped - finished_now
        elapsed = time.time() - self.start
        eta = "—" if finished_now == 0 else f"{elapsed / finished_now * left:.0f} s"
        self.log(f"sweep: {self.skipped + self.done + self.unstable}/{self.total} done ({self.skipped} earlier, "
                 f"{self.unstable} unstable), {self.running} running, {self.failed} failed, elapsed {elapsed:.0f} s, "
                 f"ETA {eta}" + (f"  {note}" if note else ""))

    def record(self, record):
        self.running -= 1
        status = record["status"]
        if status == "done":
            self.done += 1
        elif status == "unstable":
            self.unstable += 1
        else:
            self.failed += 1
        detail = {"done": "", "unstable": f": {record.get('row', {}).get('unstable')}",
                  "failed": f": {record.get('error')}"}[status]
        self.line(f"[{record['id']} {status}{detail}]")


# --- executors -----------------------------------------------------------------------------------------

def _local(todo, devices, workers, on_record, progress):
    import concurrent.futures as cf
    import multiprocessing

    slots = [devices[k % len(devices)] for k in range(workers)]
    free = list(range(workers))
    queue = list(todo)
    # a fresh process per cell (spawned: no Warp/CUDA state is inherited or shared between cells)
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                max_tasks_per_child=1) as pool:
        running = {}
        while queue or running:
            while queue and free:
                slot = free.pop(0)
                cell = queue.pop(0)
                running[pool.submit(_run_cell_in_child, cell, slots[slot])] = (slot, cell)
                progress.running += 1
            done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
            for future in done:
                slot, cell = running.pop(future)
                free.append(slot)
                try:
                    record = future.result()
                except Exception as exc:  # noqa: BLE001 - the worker process died
                    record = {"id": cell["id"], "case": cell["case"], "params": cell["params"], "device": slots[slot],
                              "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
                on_record(cell, record)


def _ray(todo, address, num_gpus, num_cpus, max_retries, on_record, progress, init_kwargs=None):
    try:
        import ray
    except ImportError:
        raise SceneError("", "--executor", "ray is not installed: pip install 'warpsph[ray]' (or use --executor local)") from None
    if not ray.is_initialized():
        kwargs = dict(init_kwargs or {})
        kwargs.setdefault("include_dashboard", False)
        kwargs.setdefault("log_to_driver", False)
        if address:
            kwargs["address"] = address
        ray.init(**kwargs)

    def task(cell):
        device = "cuda:0" if num_gpus and num_gpus > 0 else "cpu"  # Ray sets CUDA_VISIBLE_DEVICES per task
        return run_cell(cell, device)

    remote = ray.remote(num_gpus=num_gpus or 0, num_cpus=num_cpus, max_retries=max_retries)(task)
    pending = {}
    for cell in todo:
        pending[remote.remote(cell)] = cell
        progress.running += 1
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            cell = pending.pop(ref)
            try:
                record = ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - the task failed after its retries (worker lost, ...)
                record = {"id": cell["id"], "case": cell["case"], "params": cell["params"], "status": "failed",
                          "error": f"{type(exc).__name__}: {exc}"}
            on_record(cell, record)


def run_sweep(sweep, out, executor="local", workers=1, devices=None, address=None, num_gpus=None, num_cpus=1,
              max_retries=3, log=None, ray_init=None):
    """Runs the cells of ``sweep`` (a path or dict) not yet finished in ``out``; returns the table (a dict,
    also written to ``out``/table.json and table.md).

    ``executor``: "local" (``workers`` processes, ``devices`` a list given to the worker slots in turn; default
    the sweep file's device or "cpu") or "ray" (``address`` of a cluster, else a local instance (``ray_init``:
    keyword arguments of ray.init); ``num_gpus`` per task (a fraction packs cells on a GPU; 0/None: CPU),
    ``num_cpus`` per task, ``max_retries``). ``log``: a function taking a progress line (default: info on the
    ``warpsph.sweep`` logger)."""
    spec = load_sweep(sweep)
    say = log or logging.getLogger(__name__).info
    if executor not in ("local", "ray"):
        raise SceneError("", "--executor", f"unknown executor '{executor}'; expected local or ray")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise SceneError("", "--workers", f"expected an integer >= 1, got {workers!r}")
    if devices is None:
        devices = [spec["device"] or "cpu"]
    if isinstance(devices, str):
        devices = [d.strip() for d in devices.split(",") if d.strip()]
    if not devices:
        raise SceneError("", "--devices", "expected at least one device")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise SceneError(out, "--out", "is a file; --out names the sweep's output folder")
    (out / "cells").mkdir(parents=True, exist_ok=True)
    from .validation.cases import write_json

    write_json({"sweep": spec, "source": str(sweep) if not isinstance(sweep, dict) else None}, out / "sweep.json")
    all_cells = cells(spec)
    todo = [c for c in all_cells if finished(out, c) is None]
    progress = _Progress(len(all_cells), len(all_cells) - len(todo), say)
    progress.line(f"[{len(todo)} to run, executor {executor}]")

    def on_record(cell, record):
        write_json(record, _cell_path(out, cell))
        progress.record(record)

    if todo:
        if executor == "local":
            _local(todo, devices, min(workers, len(todo)), on_record, progress)
        else:
            _ray(todo, address, num_gpus, num_cpus, max_retries, on_record, progress, ray_init)
    table = assemble(spec, out)
    c = table["counts"]
    say(f"sweep: finished: {c['done']} done, {c['unstable']} unstable, {c['failed']} failed, {c['missing']} missing; "
        f"wrote {out / 'table.json'} and {out / 'table.md'}")
    return table
