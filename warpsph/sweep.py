"""Sweeps: many independent runs (cells), spread over processes, GPUs or a Ray cluster; resumable.

    warpsph sweep SWEEP.json --out OUT [--executor local|ray] [--workers N] [--devices cpu|cuda:0,cuda:1] [--plot]
    warpsph.sweep.run_sweep("SWEEP.json", "OUT", executor="local", workers=2)

A sweep file (JSON, or YAML with pyyaml installed) has a base, axes (their product gives the cells) and/or an
explicit list of ``cells``, values held for every cell (``fixed``) and the measures to tabulate. Three kinds of
base:

A validation case (a ``warpsph validate`` row per cell)::

    {"base": "taylor-green",                      # a case of warpsph.validation.cases
     "axes": {"method": ["dfsph", "vr"],          # warpsph validate --methods
              "resolution": [16, 24, 32],         # warpsph validate --resolutions
              "solver.density_max_error": [0.01, 0.1],   # any scene key path under "solver" or "time"
              "cfl": [0.3, 0.5]},                 # aliases: cfl, fixed_dt, tolerance (solver.density_max_error)
     "fixed": {"method": "dfsph"},                # optional: values held for every cell (same keys as axes)
     "measures": ["error_pct", "wall_s", "steps", "particles"],   # row keys of the case (default these)
     "warm_up": true}                             # optional: a tiny run first, kernel loading kept out of wall_s

A scene file (the scene run per cell, with its measures)::

    {"scene": "scenes/dam_break.json",            # relative to the sweep file's folder, else to the current one
     "scale": 0.05,                               # load_scene's particle-count scale (default 1)
     "time": 1.0,                                 # simulated seconds; or "frames": N (default the scene's frames)
     "axes": {"models": [[], [{"type": "rankine", "beta": 0.5}]],   # the scene's whole "models" list
              "fluid.viscosity": [0.01, 0.05],    # any scene key path, list items by index: models[0].beta
              "scale": [0.02, 0.05],              # also: method (dfsph, vr, rankine, micropolar), cfl, fixed_dt,
              "tolerance": [0.01, 0.1]},          # tolerance; a key's value is as written in the scene file
     "measures": ["ke_ratio", "enstrophy_end", "blow_up_step", "wall_s", "steps", "density_iterations"]}

A function ``fn(device, **params)`` returning the row (a dict; ``unstable`` set: a blow-up), for studies whose
runs are not a scene file (the Pareto study: ``warpsph.validation.pareto:point``)::

    {"base": {"function": "warpsph.validation.pareto:point"},
     "cells": [{"method": "dfsph", "resolution": 24, "tolerance": 0.05}, ...],   # keys: fn's parameters
     "fixed": {"case": "lamb-oseen"}, "measures": ["error_percent", "wall_per_sim_s"]}

``cells``: a list of objects of key -> value (same keys as axes), one cell each; with axes too, every product
point runs each of them. A cell's keys are applied models first, so ``models`` and ``models[0].beta`` combine.
Every key and value is checked before anything runs: a bad one raises :class:`warpsph.errors.SceneError` naming
it (``axes.models[1]``, ``cells[2].time.cfl``).

Scene-file measures (``SCENE_MEASURES``, every frame measured by :class:`warpsph.diagnostics.Diagnostics`):
``particles`` (fluid particles at the start) and ``particles_end`` (at the end: emitters add, sinks remove),
``ke_ratio`` kinetic energy at the end / at the start (null when it starts at rest), ``enstrophy_end``,
``blow_up_step`` and ``unstable`` (the health check's message) of a blow-up, ``wall_s`` (the run alone, device
synchronised, measurements subtracted), ``steps``, ``density_iterations`` / ``divergence_iterations`` (mean per
solve, ``sim.statistics()``), ``dt_min`` (the smallest step: read back every step, asked for only); per frame
(lists, 5 significant digits): ``kinetic_energy``, ``rotational_energy`` (as the stats CSV: micropolar's
spin, VR/Rankine's ζ/2; 0 for plain DFSPH/IISPH), ``enstrophy``, ``frame_times``, and ``region_enstrophy`` (the
enstrophy of the particles inside the sweep's ``"region": {"min": [x, y, z], "max": [x, y, z]}``, e.g. a wake).

Output folder: ``cells/CELL.json`` per cell (written atomically by the driver when the cell ends; ``status``
"done", "unstable" (a blow-up: the health check's diagnostic in ``unstable``, a result) or "failed" (an
exception: its traceback; rerun by the next invocation)), then ``table.json`` and ``table.md`` assembled from
the cell files (and with ``--plot``, :func:`warpsph.plots.sweep_figures`). Running a sweep again skips the cells
whose file holds a result for the same parameters and runs the failed and missing ones: a killed sweep loses at
most the cells in flight.

Executors: ``local`` (concurrent.futures, a fresh process per cell, ``workers`` at once, the devices given to the
worker slots in turn: ``devices=["cuda:0", "cuda:0", "cuda:1", "cuda:1"]`` packs two cells on each GPU) and
``ray`` (``pip install 'warpsph[ray]'``: one task per cell with ``num_gpus`` (a fraction packs several small
cells on one GPU; 1 by default when the sweep's device is cuda, see :func:`ray_placement`), ``max_retries`` for
cells lost with a worker; ``address`` joins a running cluster, otherwise a local Ray instance starts).
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import hashlib
import importlib
import inspect
import itertools
import json
import logging
import math
import os
import time
import traceback
from pathlib import Path

from .errors import SceneError
from .tables import value_text
from .device import init_warp, pick_device
from .diagnostics import Diagnostics
from .io.splishsplash import convert, is_splishsplash
from .scene import (Scene, key_path, load_scene, parse_dataclass, parse_json, read_text, rescale, scene_from_dict,
    with_overrides)
from .simulation import InstabilityError, Simulation
from .validation.cases import (CASES, ERRORS, MIN_RESOLUTION, ROWS, _finite, commit_info, device_info, timed_run,
    warm_up, write_json)
from .validation.taylor_green import METHODS

SWEEP_KEYS = ("name", "base", "scene", "scale", "frames", "time", "axes", "cells", "fixed", "measures", "warm_up",
              "device", "region")
SCENE_ONLY = ("scale", "frames", "time")
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
# row keys of a scene-file cell
SCENE_MEASURES = ("particles", "particles_end", "ke_ratio", "ke_start", "ke_end", "ke_max", "ke_tail_mean", "enstrophy_start",
                  "enstrophy_end", "blow_up_step", "blow_up_time", "unstable", "instability", "steps", "frames",
                  "time_reached", "density_iterations", "divergence_iterations", "solver_density_error_pct",
                  "max_density_error_pct", "mean_density_error_pct", "dt_mean", "dt_min", "wall_s", "setup_s",
                  "measure_s", "ms_per_step", "kinetic_energy", "rotational_energy", "enstrophy", "frame_times",
                  "region_enstrophy")
SCENE_DEFAULT_MEASURES = ("particles", "ke_ratio", "enstrophy_end", "blow_up_step", "steps", "density_iterations",
                          "wall_s")
# differ from run to run: not compared between executors
TIMING_MEASURES = ("wall_s", "setup_s", "elapsed_s", "measure_s", "ms_per_step", "wall_per_sim_s", "warmup_s",
                   "load_average", "pareto")


# --- the sweep file ------------------------------------------------------------------------------------

def _tiny_scene(overrides):
    """A minimal scene dict with ``overrides`` ({"solver.x": v, "time.y": w}) set, for checking them."""
    data = {"name": "sweep-check", "particle_radius": 0.1, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [0.5, 0.5, 0.5]}]}
    return with_overrides(data, overrides)


MAX_SWEEP_BYTES = 2**20  # the most bytes of a sweep file; 10,000 cells written out take about 1 MB


def _read(source):
    """(file name, data) of a sweep given as a path (JSON or YAML) or a dict."""
    if isinstance(source, dict):
        return "<sweep>", source
    file = str(source)
    path = Path(source)
    if not path.is_file():
        raise SceneError(file, "", "no such sweep file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise SceneError(file, "", f"cannot read the sweep file ({exc.strerror})") from None
    if size > MAX_SWEEP_BYTES:  # checked before reading: a 50 MB file took 42 s to parse and refuse
        raise SceneError(file, "", f"{size:,} bytes; a sweep file is at most {MAX_SWEEP_BYTES:,} bytes (1 MiB): give "
                                   f"an axis the values to try, not every value, or split the sweep")
    text = read_text(path, "sweep")
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise SceneError(file, "", "YAML sweep files need pyyaml (pip install pyyaml); or write it as JSON") from None
        try:
            return file, yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise SceneError(file, "", f"not valid YAML: {exc}") from None
        except RecursionError:
            raise SceneError(file, "", "not a sweep: its YAML is nested too deeply") from None
    return file, parse_json(text, file, "sweep")


def _number(value, low=0.0):
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) and value > low


def _function(name):
    """The function of a function base ("module:name")."""
    module, _, attr = str(name).partition(":")
    if not module or not attr:
        raise ValueError(f"expected \"module:function\", got {name!r}")
    try:
        fn = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"cannot import {name}: {exc}") from None
    if not callable(fn) or "device" not in inspect.signature(fn).parameters:
        raise ValueError(f"{name} is not a function taking device and the cell's keys")
    return fn


class _Base:
    """What a sweep's cells run: checks keys and values, builds the cell dicts."""

    kind = ""
    fixed_defaults = {}

    def __init__(self, file):
        self.file = file

    def error(self, where, reason):
        return SceneError(self.file, where, reason)


class _Case(_Base):
    kind = "case"

    def __init__(self, file, case):
        super().__init__(file)
        self.case = self.label = case
        self.fixed_defaults = {"method": "dfsph"}

    def key(self, where, name):
        key = ALIASES.get(name, name)
        if key in ("method", "resolution"):
            return key
        parts = key.split(".")
        if len(parts) != 2 or parts[0] not in SCENE_SECTIONS or not parts[1]:
            raise self.error(where, "unknown axis; expected method, resolution, a scene key solver.NAME or time.NAME, "
                                    f"or one of {', '.join(a for a in ALIASES if a not in ('methods', 'resolutions'))}")
        return key

    def value(self, where, key, value):
        if key == "method":
            if not isinstance(value, str) or value not in METHODS:
                raise self.error(where, f"unknown method {value!r}; expected one of {', '.join(METHODS)}")
        elif key == "resolution":
            if isinstance(value, bool) or not isinstance(value, int) or value < MIN_RESOLUTION:
                raise self.error(where, f"expected an integer >= {MIN_RESOLUTION}, got {value!r}")
        else:
            try:
                scene_from_dict(_tiny_scene({key: value}))
            except SceneError as exc:
                raise self.error(where, exc.reason) from None
            except (TypeError, ValueError) as exc:
                raise self.error(where, str(exc)) from None

    def cell(self, where, params):
        if "resolution" not in params:
            raise self.error(where, "needs a resolution (an axis, in fixed or in every cell)")
        overrides = {k: v for k, v in params.items() if "." in k}
        try:  # keys checked together (min <= max iterations, ...)
            scene_from_dict(_tiny_scene(overrides))
        except SceneError as exc:
            raise self.error(where, f"the cell {overrides}: {exc.key}: {exc.reason}") from None

    def measures(self):
        return COMMON_MEASURES + CASE_MEASURES[self.case], DEFAULT_MEASURES

    def make(self, params, warm_up):
        return {"kind": "case", "case": self.case, "params": params, "warm_up": warm_up}

    def digest(self, params):
        return [self.case, params]


class _Function(_Base):
    kind = "function"

    def __init__(self, file, name):
        super().__init__(file)
        try:
            fn = _function(name)
        except ValueError as exc:
            raise self.error("base.function", str(exc)) from None
        self.function = self.label = name
        self.parameters = [p for p in inspect.signature(fn).parameters if p not in ("device", "warm_up")]
        self.takes_warm_up = "warm_up" in inspect.signature(fn).parameters

    def key(self, where, name):
        if name not in self.parameters:
            close = difflib.get_close_matches(name, self.parameters, n=1)
            hint = f"did you mean '{close[0]}'?" if close else f"expected one of {', '.join(self.parameters)}"
            raise self.error(where, f"not a parameter of {self.function}; {hint}")
        return name

    def value(self, where, key, value):
        pass

    def cell(self, where, params):
        pass

    def measures(self):
        return None, ("wall_s",)

    def make(self, params, warm_up):
        return {"kind": "function", "case": self.function, "function": self.function, "params": params,
                "warm_up": warm_up if self.takes_warm_up else None}

    def digest(self, params):
        return [self.function, params]


class _SceneFile(_Base):
    kind = "scene"

    def __init__(self, file, data):
        super().__init__(file)
        self.fields = [f.name for f in dataclasses.fields(Scene) if f.name != "source"]
        scene = data["scene"]
        if not isinstance(scene, str) or not scene:
            raise self.error("scene", f"expected a scene file path, got {scene!r}")
        here = [Path(file).parent / scene] if file != "<sweep>" and not Path(scene).is_absolute() else []
        found = [p for p in here + [Path(scene)] if p.is_file()]
        if not found:
            raise self.error("scene", f"no such scene file: {' or '.join(str(p) for p in here + [Path(scene)])}")
        self.path, self.label = found[0].resolve(), scene
        for key in SCENE_ONLY:
            if key in data and not (_number(data[key]) if key != "frames" else
                                    isinstance(data[key], int) and not isinstance(data[key], bool) and data[key] >= 1):
                raise self.error(key, f"expected {'an integer >= 1' if key == 'frames' else 'a number > 0'}, "
                                      f"got {data[key]!r}")
        if "frames" in data and "time" in data:
            raise self.error("time", "give frames or time (simulated seconds), not both")
        self.scale, self.frames, self.seconds = data.get("scale", 1.0), data.get("frames"), data.get("time")
        try:
            load_scene(self.path, self.scale)
        except SceneError as exc:
            raise self.error("scene", f"{self.path}: {exc.key}: {exc.reason}") from None
        self.data = json.loads(self.path.read_text(encoding="utf-8-sig"))
        if is_splishsplash(self.data):
            self.data = convert(self.data, self.path)

    def key(self, where, name):
        key = ALIASES.get(name, name)
        if key in ("method", "models", "scale"):
            return key
        try:
            first = key_path(key)[0]
        except ValueError as exc:
            raise self.error(where, str(exc)) from None
        if first not in self.fields:
            known = ["scale", "method", "models", "models[K].NAME", *ALIASES]
            close = difflib.get_close_matches(name, ["scale", "method", "models", *ALIASES, *self.fields], n=1)
            raise self.error(where, f"unknown axis; expected a scene key path ({', '.join(self.fields)}; e.g. "
                                    f"fluid.viscosity) or {', '.join(a for a in known if a not in ('methods', 'resolutions'))}"
                                    + (f"; did you mean '{close[0]}'?" if close else ""))
        return key

    def value(self, where, key, value):
        if key == "method" and (not isinstance(value, str) or value not in METHODS):
            raise self.error(where, f"unknown method {value!r}; expected one of {', '.join(METHODS)}")
        if key == "scale" and not _number(value):
            raise self.error(where, f"expected a number > 0, got {value!r}")
        if key == "models" and not isinstance(value, list):
            raise self.error(where, f"expected a list of models, e.g. [] or [{{\"type\": \"rankine\", \"beta\": 0.5}}], "
                                    f"got {value!r}")

    def cell(self, where, params, sources):
        """Builds the cell's scene; an error names the sweep key that set the failing scene key."""
        if "method" in params and "models" in params:
            raise self.error(sources["models"], "method and models both set the scene's models: give one")
        try:
            scene_of({"scene": self.data, "scene_file": str(self.path), "scale": self.scale, "params": params})
        except (SceneError, ValueError) as exc:
            if isinstance(exc, SceneError):
                scene_key, reason = exc.key, exc.reason
            else:  # with_overrides: "'models[1]': no such item ..."
                text = str(exc)
                scene_key, reason = text[1:].split("': ", 1) if text.startswith("'") and "': " in text else ("", text)
            owner = [k for k in params if k == scene_key or scene_key.startswith((k + ".", k + "["))
                     or k.startswith((scene_key + ".", scene_key + "["))
                     or (k == "method" and scene_key.startswith("models"))]
            if owner:
                key = max(owner, key=len)
                raise self.error(sources[key], reason if key == scene_key else f"{scene_key}: {reason}") from None
            raise self.error(where, f"the cell {params}: {scene_key}: {reason}") from None

    def measures(self):
        return SCENE_MEASURES, SCENE_DEFAULT_MEASURES

    def make(self, params, warm_up):
        return {"kind": "scene", "case": self.label, "scene": self.data, "scene_file": str(self.path),
                "scale": self.scale, "frames": self.frames, "seconds": self.seconds, "params": params,
                "warm_up": warm_up}

    def digest(self, params):
        return [self.data, self.scale, self.frames, self.seconds, params]


def _base(file, data):
    if "scene" in data:
        if "base" in data:
            raise SceneError(file, "scene", "give base (a validation case or a function) or scene (a scene file), "
                                            "not both")
        return _SceneFile(file, data)
    for key in SCENE_ONLY:
        if key in data:
            raise SceneError(file, key, "only for a scene-file sweep (\"scene\": FILE)")
    if "base" not in data:
        raise SceneError(file, "base", f"missing: a validation case ({', '.join(CASES)}), {{\"function\": "
                                       f"\"module:name\"}}, or \"scene\": a scene file")
    base = data["base"]
    if isinstance(base, dict):
        if set(base) == {"function"}:
            return _Function(file, base["function"])
        if set(base) != {"case"}:
            raise SceneError(file, "base", "expected a case name, {\"case\": NAME} or {\"function\": \"module:name\"}")
        base = base["case"]
    if not isinstance(base, str) or not base:
        raise SceneError(file, "base", f"expected a validation case name ({', '.join(CASES)}), got {base!r}")
    if base not in CASES:
        if base.endswith((".json", ".yaml", ".yml")) or Path(base).exists():
            raise SceneError(file, "base", f"'{base}' is a scene file: give it as \"scene\": \"{base}\" (base names "
                                           f"a validation case: {', '.join(CASES)})")
        raise SceneError(file, "base", f"unknown case '{base}'; expected one of {', '.join(CASES)}")
    return _Case(file, base)


def load_sweep(source):
    """The sweep file (a path, JSON or YAML) or dict, checked; returns the normalised spec (a dict: name, kind,
    case (the base's label), axes (an ordered list of [key, values]), cells (a list of key -> value objects, or
    None), columns (the keys that vary), fixed, measures, warm_up, device, and the base's own keys). Raises
    :class:`warpsph.errors.SceneError` naming the file and the key."""
    file, data = _read(source)
    if not isinstance(data, dict):
        raise SceneError(file, "", "expected an object with keys base (or scene), axes, measures")
    for key in data:
        if key not in SWEEP_KEYS:
            raise SceneError(file, key, f"unknown key; known keys: {', '.join(SWEEP_KEYS)}")
    base = _base(file, data)

    axes_in, entries_in = data.get("axes"), data.get("cells")
    if entries_in is None and (not isinstance(axes_in, dict) or not axes_in):
        raise SceneError(file, "axes", "expected an object of axis name -> list of values, e.g. "
                                       "{\"method\": [\"dfsph\", \"vr\"], \"resolution\": [16, 32]} (or a cells list)")
    if axes_in is not None and not isinstance(axes_in, dict):
        raise SceneError(file, "axes", "expected an object of axis name -> list of values")
    axes, sources = [], {}  # sources: key -> where each value comes from (for errors naming the sweep key)
    for name, values in (axes_in or {}).items():
        key = base.key(f"axes.{name}", name)
        if any(key == k for k, _ in axes):
            raise SceneError(file, f"axes.{name}", f"axis {key} given twice")
        if not isinstance(values, list) or not values:
            raise SceneError(file, f"axes.{name}", f"expected a non-empty list of values, got {values!r}")
        for k, value in enumerate(values):
            base.value(f"axes.{name}[{k}]", key, value)
        if len({json.dumps(v, sort_keys=True) for v in values}) != len(values):
            raise SceneError(file, f"axes.{name}", "repeated value")
        axes.append([key, list(values)])
        sources[key] = [f"axes.{name}[{k}]" for k in range(len(values))]
    entries = None
    if entries_in is not None:
        if not isinstance(entries_in, list) or not entries_in:
            raise SceneError(file, "cells", f"expected a non-empty list of objects (key -> value), got {entries_in!r}")
        entries, entry_names = [], []
        for n, entry in enumerate(entries_in):
            if not isinstance(entry, dict):
                raise SceneError(file, f"cells[{n}]", f"expected an object of key -> value, got {entry!r}")
            cell, entry_names_n = {}, {}
            for name, value in entry.items():
                key = base.key(f"cells[{n}].{name}", name)
                if any(key == k for k, _ in axes):
                    raise SceneError(file, f"cells[{n}].{name}", f"{key} is also an axis")
                base.value(f"cells[{n}].{name}", key, value)
                cell[key] = value
                entry_names_n[key] = name
            entries.append(cell)
            entry_names.append(entry_names_n)
        if len({json.dumps(e, sort_keys=True) for e in entries}) != len(entries):
            raise SceneError(file, "cells", "repeated cell")
    fixed_in = data.get("fixed", {})
    if not isinstance(fixed_in, dict):
        raise SceneError(file, "fixed", "expected an object of key -> value")
    fixed = {}
    for name, value in fixed_in.items():
        key = base.key(f"fixed.{name}", name)
        if any(key == k for k, _ in axes) or any(key in e for e in entries or ()):
            raise SceneError(file, f"fixed.{name}", f"{key} is also an axis or a cell's key")
        base.value(f"fixed.{name}", key, value)
        fixed[key] = value
        sources[key] = f"fixed.{name}"
    varied = [k for k, _ in axes] + list(dict.fromkeys(k for e in entries or () for k in e))
    for key, value in base.fixed_defaults.items():
        if key not in varied and key not in fixed:
            fixed[key] = value
    names = [k for k, _ in axes]
    for index in itertools.product(*[range(len(v)) for _, v in axes]):
        for n, entry in enumerate(entries if entries is not None else [{}]):
            where = "axes" if entries is None else f"cells[{n}]"
            params = {**{k: dict(axes)[k][i] for k, i in zip(names, index)}, **entry, **fixed}
            if isinstance(base, _SceneFile):  # the sweep key behind each scene key, for errors
                here = {k: sources[k][i] for k, i in zip(names, index)}
                here.update({k: f"{where}.{entry_names[n][k]}" for k in entry})
                here.update({k: sources[k] for k in fixed})
                base.cell(where, params, here)
            else:
                base.cell(where, params)

    known, default = base.measures()
    measures = data.get("measures", list(default))
    if not isinstance(measures, list) or not measures:
        raise SceneError(file, "measures", f"expected a non-empty list of row keys, e.g. {list(default)}")
    for k, m in enumerate(measures):
        if not isinstance(m, str) or (known is not None and m not in known):
            raise SceneError(file, f"measures[{k}]", f"unknown measure {m!r} for {base.label}; known: "
                                                     f"{', '.join(known or ())}")
    warm = data.get("warm_up", True)
    if not isinstance(warm, bool):
        raise SceneError(file, "warm_up", f"expected true or false, got {warm!r}")
    device = data.get("device")
    if device is not None and not isinstance(device, str):
        raise SceneError(file, "device", f"expected a device name (cpu, cuda:0, ...), got {device!r}")
    region = data.get("region")
    if region is not None:
        corners = [region.get(k) if isinstance(region, dict) else None for k in ("min", "max")]
        if not isinstance(base, _SceneFile) or set(region) - {"min", "max"} or not all(
                isinstance(c, list) and len(c) == 3 and all(_number(x, low=-math.inf) for x in c) for c in corners):
            raise SceneError(file, "region", "expected {\"min\": [x, y, z], \"max\": [x, y, z]} (metres; a scene "
                                             "sweep's box whose enstrophy the cells also measure)")
        region = [[float(x) for x in c] for c in corners]
    name = data.get("name", Path(file).stem if file != "<sweep>" else "sweep")
    if not isinstance(name, str):
        raise SceneError(file, "name", f"expected a string, got {name!r}")
    spec = {"name": name, "kind": base.kind, "base": data.get("base"), "case": base.label, "axes": axes,
            "cells": entries, "columns": varied, "fixed": fixed, "measures": list(measures), "warm_up": warm,
            "device": device}
    if isinstance(base, _SceneFile):
        spec.update(scene=base.label, scene_file=str(base.path), scene_data=base.data, scale=base.scale,
                    frames=base.frames, time=base.seconds, region=region)
    if isinstance(base, _Function):
        spec.update(function=base.function, takes_warm_up=base.takes_warm_up)
    return spec


def _combinations(axes, entries):
    """(axis values, cell entry, where) per cell: the product of the axes, each with every entry."""
    names = [k for k, _ in axes]
    for values in itertools.product(*[v for _, v in axes]):
        for n, entry in enumerate(entries if entries is not None else [{}]):
            yield dict(zip(names, values)), entry, ("axes" if entries is None else f"cells[{n}]")


def cells(spec):
    """The cells of ``spec`` in order: dicts {"kind", "case", "params", "warm_up", "id", ...}."""
    out = []
    for point, entry, _ in _combinations(spec["axes"], spec.get("cells")):
        params = {**point, **entry, **spec["fixed"]}
        if spec.get("kind") == "scene":
            cell = {"kind": "scene", "case": spec["case"], "scene": spec["scene_data"], "scene_file": spec["scene_file"],
                    "scale": spec["scale"], "frames": spec["frames"], "seconds": spec["time"], "params": params,
                    "warm_up": spec["warm_up"], "track_dt": "dt_min" in spec["measures"], "region": spec.get("region")}
            digest = [spec["scene_data"], spec["scale"], spec["frames"], spec["time"], params]
            if spec.get("region") is not None:  # (sweeps without one keep their cells' ids)
                digest.append(spec["region"])
        elif spec.get("kind") == "function":
            cell = {"kind": "function", "case": spec["case"], "function": spec["function"], "params": params,
                    "warm_up": spec["warm_up"] if spec["takes_warm_up"] else None}
            digest = [spec["function"], params]
        else:
            cell = {"kind": "case", "case": spec["case"], "params": params, "warm_up": spec["warm_up"]}
            digest = [spec["case"], params]
        cell["id"] = cell_id(digest, params, [k for k in spec.get("columns", [k for k, _ in spec["axes"]])
                                              if k in params])
        out.append(cell)
    return out


def _label(value):
    """A short text for a value: a models list as rankine-beta-0.5 (none for [])."""
    if isinstance(value, list) and all(isinstance(m, dict) and "type" in m for m in value):
        return "+".join("-".join([str(m["type"])] + [f"{k}-{v}" for k, v in m.items() if k != "type"])
                        for m in value) or "none"
    return str(value)


def cell_id(digest, params, names):
    """A file name for the cell: its varied values, then a hash of everything that defines it."""
    label = "_".join(f"{k.split('.')[-1]}-{_label(params[k])}" for k in names)
    label = "".join(c if c.isalnum() or c in "-._" else "-" for c in label)[:80]
    return f"{label}_{hashlib.sha1(json.dumps(digest, sort_keys=True).encode()).hexdigest()[:8]}"


# --- one cell ------------------------------------------------------------------------------------------

def scene_overrides(params):
    """A scene cell's keys as scene key paths in the order they apply: the models (``method`` or ``models``)
    before their items; ``scale`` is not a scene key."""
    overrides = {k: v for k, v in params.items() if k not in ("method", "scale")}
    if "method" in params:
        overrides["models"] = METHODS[params["method"]]
    return dict(sorted(overrides.items(), key=lambda kv: len(key_path(kv[0]))))


def scene_data(cell):
    """A scene-file cell's scene dict: the base scene with the cell's keys set."""
    return with_overrides(cell["scene"], scene_overrides(cell["params"]))


def scene_of(cell):
    """The :class:`warpsph.scene.Scene` of a scene-file cell: its base scene with the cell's keys set, at its
    scale (a key's value is as written in the scene file: the scale then applies, as for ``load_scene``)."""
    params = cell["params"]
    scene = parse_dataclass(Scene, scene_data(cell), cell["scene_file"])
    return rescale(dataclasses.replace(scene, source=cell["scene_file"]), params.get("scale", cell["scale"]))


def scene_row(cell, device):
    """Runs a scene-file cell; returns (status, row): "done", or "unstable" with the health check's diagnostic
    and the measures up to the blow-up."""
    import numpy as np

    start = time.perf_counter()
    sim = Simulation(scene_of(cell), device=device)
    row = {"particles": sim.num_fluid, "setup_s": time.perf_counter() - start}
    diagnostics, frames, dts = Diagnostics(region=cell.get("region")), [], []
    # every step's dt (a read-back per step): after each step that passed its health check, and the failed one's
    tracked = (lambda s: dts.append(float(s.dt.numpy()[0]))) if cell.get("track_dt") else None

    def run(callback):
        if cell.get("seconds") is not None:
            sim.run(until_time=cell["seconds"], on_frame=callback, on_step=tracked)
        else:
            sim.run(frames=cell.get("frames"), on_frame=callback, on_step=tracked)

    status, t0 = "done", time.perf_counter()
    try:
        row["wall_s"], row["measure_s"] = timed_run(sim, run, lambda s, f: frames.append(diagnostics.measure(s, f)))
    except InstabilityError as exc:
        status = "unstable"
        if tracked is not None:  # the step that failed (on_step runs after the steps that passed)
            tracked(sim)
        row.update(wall_s=time.perf_counter() - t0, unstable=str(exc), blow_up_step=exc.step, blow_up_time=exc.time,
                   instability={"step": exc.step, "time": exc.time, "check": exc.check, "particle_id": exc.particle_id,
                                "position": None if exc.position is None else [float(c) for c in exc.position]})
    stats = sim.statistics()
    ke = [f["kinetic_energy"] for f in frames]
    enstrophy = [f["enstrophy"] for f in frames]
    row.update(
        steps=sim.step_count, frames=sim.frame, time_reached=sim.time, particles_end=sim.num_fluid,
        ke_start=ke[0] if ke else None, ke_end=ke[-1] if ke else None,
        ke_ratio=ke[-1] / ke[0] if ke and ke[0] > 0 else None, ke_max=max(ke, default=None),
        ke_tail_mean=float(np.mean(ke[-max(1, len(ke) // 4):])) if ke else None,
        enstrophy_start=enstrophy[0] if ke else None, enstrophy_end=enstrophy[-1] if ke else None,
        density_iterations=stats["density_iterations"], divergence_iterations=stats["divergence_iterations"],
        solver_density_error_pct=100 * stats["density_error"],
        max_density_error_pct=100 * max(f["density_error_max"] for f in frames) if frames else None,
        mean_density_error_pct=100 * float(np.mean([f["density_error_mean"] for f in frames])) if frames else None,
        dt_mean=sim.time / max(sim.step_count, 1), ms_per_step=1e3 * row["wall_s"] / max(sim.step_count, 1),
        kinetic_energy=[float(f"{e:.5g}") for e in ke], frame_times=[round(f["time"], 5) for f in frames],
        rotational_energy=[float(f"{f['rotational_energy']:.5g}") for f in frames],
        enstrophy=[float(f"{e:.5g}") for e in enstrophy])
    if cell.get("region") is not None:
        row["region_enstrophy"] = [float(f"{f['region_enstrophy']:.5g}") for f in frames]
    row.setdefault("blow_up_step", None)
    if dts:
        row["dt_min"] = min(dts)
    return status, row


def run_cell(cell, device="cpu"):
    """Runs one cell (in this process) on ``device``; returns its record: status "done" with the row,
    "unstable" with the health check's diagnostic (a result), or "failed" with the traceback."""
    started = time.time()
    record = {"id": cell["id"], "case": cell["case"], "params": cell["params"], "device": device,
              "host": os.uname().nodename, "pid": os.getpid(), "started": started}
    try:
        wp = init_warp()
        params, kind = cell["params"], cell.get("kind", "case")
        record.update(device_info(device))  # "device": the device's name, "device_alias": cpu, cuda:0, ...
        record.update(commit_info())  # the code that ran this cell (a table may be made later, elsewhere)
        if cell.get("warm_up") and kind != "function":
            t0 = time.perf_counter()
            if kind == "case":
                warm_up(METHODS[params["method"]], device, {k: v for k, v in params.items() if "." in k})
            else:
                warm_up(scene_data(cell).get("models", []), device)
            record["warmup_s"] = time.perf_counter() - t0
        if kind == "scene":
            record["status"], row = scene_row(cell, device)
        elif kind == "function":
            kwargs = dict(params) if cell.get("warm_up") is None else {**params, "warm_up": cell["warm_up"]}
            try:
                row = dict(_function(cell["function"])(device=device, **kwargs))
                record["status"] = "unstable" if row.get("unstable") else "done"
            except InstabilityError as exc:
                row = {"unstable": str(exc), "blow_up_step": exc.step, "unstable_time": exc.time}
                record["status"] = "unstable"
        else:
            row = {"case": cell["case"], "method": params["method"], "resolution": params["resolution"],
                   "error_units": ERRORS[cell["case"]][0]}
            try:
                row.update(ROWS[cell["case"]](METHODS[params["method"]], params["resolution"], device,
                                              {k: v for k, v in params.items() if "." in k}))
                record["status"] = "done"
            except InstabilityError as exc:  # as warpsph validate records it
                row.update(particles=None, error_pct=None, wall_s=None, steps=exc.step, unstable=str(exc),
                           unstable_time=exc.time)
                record["status"] = "unstable"
            row["error_pct"] = _finite(row.get("error_pct"))
        wp.synchronize_device(device)
        record["row"] = row
    except Exception as exc:  # noqa: BLE001 - recorded; the next run of the sweep retries the cell
        record.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    record["elapsed_s"] = time.time() - started
    return record


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


def records(sweep, out):
    """(cell, record) per cell of ``sweep`` (a path, dict or spec) in order; the record is None where ``out``
    holds no file for the cell."""
    spec = sweep if isinstance(sweep, dict) and "columns" in sweep else load_sweep(sweep)
    pairs = []
    for cell in cells(spec):
        try:
            record = json.loads(_cell_path(out, cell).read_text())
        except (OSError, ValueError):
            record = None
        pairs.append((cell, record if record and record.get("params") == cell["params"] else None))
    return pairs


def cells_commit(records):
    """{"commit": ..., "uncommitted": [...]} of the code that ran the cells (their records; several commits
    joined by ", "), or of this checkout when a record predates the key (then "commit_from": "table")."""
    records = [r for r in records if r]
    if not records or any("commit" not in r for r in records):
        return {**commit_info(), "commit_from": "table"}
    commits = sorted({str(r["commit"]) for r in records})
    uncommitted = sorted({f for r in records for f in r.get("uncommitted") or []})
    return {"commit": ", ".join(commits), "uncommitted": uncommitted, "commit_from": "cells"}


def assemble(spec, out):
    """``table.json`` and ``table.md`` in ``out`` from the cell files; returns the table (a dict)."""
    pairs = records(spec, out)
    columns = spec.get("columns", [k for k, _ in spec["axes"]])
    rows, counts = [], {"done": 0, "unstable": 0, "failed": 0, "missing": 0}
    for cell, record in pairs:
        record = record or {"status": "missing"}
        status = record.get("status", "missing")
        counts[status] = counts.get(status, 0) + 1
        row = {k: cell["params"].get(k) for k in columns}
        r = record.get("row", {})
        row.update({m: r.get(m) for m in spec["measures"]})
        row["status"] = status
        if status == "unstable":
            row["unstable"] = r.get("unstable")
        if status == "failed":
            row["error"] = record.get("error")
        row["device"] = record.get("device_alias", record.get("device"))
        rows.append(row)
    table = {"sweep": spec["name"], "kind": spec.get("kind", "case"), "case": spec["case"], "axes": columns,
             "fixed": spec["fixed"], "measures": spec["measures"], "counts": counts,
             "complete": counts["done"] + counts["unstable"] == len(rows),
             **cells_commit([record for _, record in pairs]), "rows": rows}
    write_json(table, Path(out) / "table.json")
    _write_text(Path(out) / "table.md", markdown(table))
    return table


def _json_with_keys(path, keys):
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(data, dict) and keys <= set(data)


def _sweep_markdown(path):
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().startswith("# Sweep ")
    except (OSError, UnicodeDecodeError):
        return False


SPEC_FILE = "sweep.normalised.json"  # the sweep as run (never named like the user's own sweep file)
# the files a sweep writes in --out, and how to tell that a sweep wrote them
OUTPUT_FILES = {SPEC_FILE: lambda p: p.is_file() and _json_with_keys(p, {"sweep", "source"}),
                "table.json": lambda p: p.is_file() and _json_with_keys(p, {"sweep", "counts", "rows"}),
                "table.md": lambda p: p.is_file() and _sweep_markdown(p)}


def _write_text(path, text):
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def markdown(table):
    cols = table["axes"] + table["measures"] + ["status"]
    lines = [f"# Sweep {table['sweep']}: {table['case']}", ""]
    if table["fixed"]:
        lines += ["Fixed: " + ", ".join(f"{k} = {value_text(v)}" for k, v in table["fixed"].items()), ""]
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
            cells_.append(value_text(v).replace("|", "\\|").replace("\n", " "))
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
    """Runs the cells ``workers`` at a time, each in a fresh spawned process (no Warp/CUDA state is inherited or
    shared between cells) that ignores the terminal's SIGINT: a cell that dies (killed, out of memory) is recorded
    as failed with its exit code or signal and the sweep goes on; Ctrl-C (or SIGTERM) stops the cells in flight
    and is raised in the parent (their cells stay missing and run on the next invocation)."""
    import multiprocessing
    from multiprocessing.connection import wait

    context = multiprocessing.get_context("spawn")
    slots = [devices[k % len(devices)] for k in range(workers)]
    free = list(range(workers))
    queue = list(todo)
    running = {}  # process sentinel -> (process, receiving end, slot, cell)
    try:
        while queue or running:
            while queue and free:
                slot, cell = free.pop(0), queue.pop(0)
                receive, send = context.Pipe(duplex=False)
                process = context.Process(target=_cell_process, args=(cell, slots[slot], send), daemon=True)
                # SIGINT blocked while the cell's process starts: it inherits the mask and ignores SIGINT only
                # once it runs _cell_process (Python's start-up and imports, ~1 s, took a group Ctrl-C as a
                # KeyboardInterrupt with a traceback). Here a Ctrl-C meanwhile (another thread may take it) is
                # only noted, and raised once the process is in `running`, where the finally below stops it.
                with _sigint_deferred():
                    process.start()
                    send.close()
                    running[process.sentinel] = (process, receive, slot, cell)
                    progress.running += 1
            for sentinel in wait(list(running)):
                process, receive, slot, cell = running.pop(sentinel)
                try:
                    record = receive.recv() if receive.poll() else None
                except EOFError:  # it died before sending
                    record = None
                process.join()
                receive.close()
                free.append(slot)
                if record is None:
                    code = process.exitcode
                    how = (f"killed by signal {-code} ({_signal_name(-code)})" if code is not None and code < 0
                           else f"exited with code {code}")
                    record = _failed(cell, f"the cell's process {how} before it reported", device=slots[slot],
                                     exit_code=code)
                on_record(cell, record)
    finally:
        for process, receive, _, _ in running.values():  # interrupted: stop the cells in flight
            process.terminate()
        for process, receive, _, _ in running.values():
            process.join(10)
            receive.close()


def _failed(cell, error, **more):
    """The record of a cell whose process or task ended without reporting one."""
    return {"id": cell["id"], "case": cell["case"], "params": cell["params"], **more, "status": "failed", "error": error}


def _signal_name(number):
    import signal

    try:
        return signal.Signals(number).name
    except ValueError:
        return "unknown"


@contextlib.contextmanager
def _sigint_deferred():
    """SIGINT blocked on this thread and noted (not raised) on any other; raised as KeyboardInterrupt on leaving."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        _block_sigint(True)
        try:
            yield
        finally:
            _block_sigint(False)
        return
    noted = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: noted.append(signum))
    _block_sigint(True)
    try:
        yield
    finally:
        _block_sigint(False)  # a SIGINT pending on this thread is handled here: noted
        signal.signal(signal.SIGINT, previous)
    if noted and previous is not signal.SIG_IGN:
        if callable(previous):
            previous(signal.SIGINT, None)  # Python's default handler raises KeyboardInterrupt
        raise KeyboardInterrupt


def _block_sigint(block):
    import signal

    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_BLOCK if block else signal.SIG_UNBLOCK, {signal.SIGINT})


def _cell_process(cell, device, send):
    """A cell's process: the terminal's Ctrl-C goes to the sweep, which stops its cells itself. (It starts with
    SIGINT blocked: a Ctrl-C pending since then is dropped when it is ignored here.)"""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _block_sigint(False)
    try:
        send.send(run_cell(cell, device))
    finally:
        send.close()


def ray_placement(devices, sweep_device, num_gpus, file="<sweep>"):
    """(GPUs per cell, the cells' device) of a Ray sweep. The device asked (``devices``, from --device or
    --devices, else the sweep file's ``sweep_device``) is honoured or refused here, before any cell: cpu takes
    no GPU, cuda (or cuda:0: the GPU Ray assigns) ``num_gpus`` (default 1; a fraction packs cells on a GPU);
    none asked: cuda when ``num_gpus`` > 0, else cpu. Raises :class:`SceneError` naming the option or key."""
    where, asked = ("--devices", devices) if devices else ("device", [sweep_device] if sweep_device else [])
    where_file, what = ("", "--devices") if devices else (file, "the sweep file's device")
    if isinstance(asked, str):
        asked = [d.strip() for d in asked.split(",") if d.strip()]
    if num_gpus is not None and (isinstance(num_gpus, bool) or not isinstance(num_gpus, (int, float))
                                 or not 0 <= num_gpus < math.inf):
        raise SceneError("", "--num-gpus", f"expected a number >= 0, got {num_gpus!r}")
    kinds = {"cpu" if d == "cpu" else "cuda" if d in ("cuda", "cuda:0") else d for d in asked if d != "auto"}
    unknown = kinds - {"cpu", "cuda"}
    if unknown or len(kinds) > 1:
        raise SceneError(where_file, where, f"Ray places each cell itself: expected cpu or cuda (the GPU Ray assigns "
                                            f"a cell), got {', '.join(asked)}")
    kind = kinds.pop() if kinds else None
    if kind == "cpu" and num_gpus:
        raise SceneError("", "--num-gpus", f"{num_gpus:g} GPUs per cell, but {what} is cpu")
    if kind == "cuda" and num_gpus == 0:
        raise SceneError("", "--num-gpus", f"0 gives the cells no GPU, but {what} is cuda (leave --num-gpus out "
                                           f"for 1 GPU per cell, or give a fraction such as 0.25)")
    if kind is None:
        kind = "cuda" if num_gpus else "cpu"
    gpus = (1 if num_gpus is None else num_gpus) if kind == "cuda" else 0
    return gpus, "cuda:0" if kind == "cuda" else "cpu"  # Ray sets CUDA_VISIBLE_DEVICES per task


def _check_ray_gpus(ray, num_gpus, started, asked_by=("", "--num-gpus")):
    """Refuses GPU cells on a Ray instance this program started without GPUs (they would wait forever), naming
    ``asked_by`` ((file, key): the option or sweep file key that asked for the GPU); a cluster joined may still
    add GPU nodes: a warning."""
    have = ray.cluster_resources().get("GPU", 0)
    if num_gpus <= have:
        return
    text = f"the cells ask for {num_gpus:g} GPU each, and the Ray {'instance' if started else 'cluster'} has {have:g}"
    if started:
        raise SceneError(*asked_by, text + "; use a machine with a GPU, --address of a cluster with GPUs, or the "
                                           "device cpu")
    logging.getLogger(__name__).warning("%s: the cells wait until GPU nodes join", text)


def _ray_started_here(ray):
    """Whether the Ray instance this process is connected to was started by it (ray.init without an address, as
    a test or a script calls it before run_sweep): its head node runs here and gains no GPU later. Read from
    Ray's record of its node; False when that is not there (a cluster joined)."""
    node = getattr(getattr(getattr(ray, "_private", None), "worker", None), "_global_node", None)
    return getattr(node, "head", False) is True


def _ray_connect(address, num_gpus, init_kwargs=None, asked_by=("", "--num-gpus")):
    """The ray module, joined to the cluster at ``address`` or a local instance (started unless the program
    started one); GPU cells on a local instance without GPUs are refused here (:func:`_check_ray_gpus`)."""
    try:
        import ray
    except ImportError:
        raise SceneError("", "--executor", "ray is not installed: pip install 'warpsph[ray]' (or use --executor local)") from None
    started = not address and (not ray.is_initialized() or _ray_started_here(ray))
    if not ray.is_initialized():
        kwargs = dict(init_kwargs or {})
        kwargs.setdefault("include_dashboard", False)
        kwargs.setdefault("log_to_driver", False)
        if address:
            kwargs["address"] = address
        ray.init(**kwargs)
    if num_gpus:
        _check_ray_gpus(ray, num_gpus, started, asked_by)
    return ray


def _ray(ray, todo, num_gpus, num_cpus, max_retries, on_record, progress, device="cpu"):
    def task(cell):
        return run_cell(cell, device)

    remote = ray.remote(num_gpus=num_gpus, num_cpus=num_cpus, max_retries=max_retries)(task)
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
                record = _failed(cell, f"{type(exc).__name__}: {exc}")
            on_record(cell, record)


def add_executor_arguments(parser, default_devices="--device"):
    """The executor options of a sweep (``warpsph sweep``) and of a study run as one (``warpsph pareto``,
    ``warpsph stress``); ``default_devices`` says what --devices defaults to."""
    parser.add_argument("--executor", choices=["local", "ray"], default="local",
                        help="local (a process per cell, no extra dependency; default) or ray (pip install 'warpsph[ray]')")
    parser.add_argument("--workers", type=int, default=1, help="local: cells at once (default 1)")
    parser.add_argument("--devices", metavar="D[,D...]",
                        help="local: devices given to the worker slots in turn, e.g. cuda:0,cuda:1, or cuda:0 with "
                             f"--workers 4 to pack four cells on one GPU, or auto (default: {default_devices}); "
                             "ray: cpu or cuda (the GPU Ray assigns each cell)")
    parser.add_argument("--address", help="ray: the cluster to join (e.g. auto or ray://host:10001); default a local instance")
    parser.add_argument("--num-gpus", type=float, default=None,
                        help="ray: GPUs per cell (0.25 packs four cells on a GPU; default 1 when the device is cuda, "
                             "else 0: CPU cells)")
    parser.add_argument("--num-cpus", type=float, default=1.0, help="ray: CPUs per cell (default 1)")
    parser.add_argument("--max-retries", type=int, default=3, help="ray: retries of a cell lost with its worker (default 3)")


def executor_arguments(args):
    """run_sweep's keyword arguments from :func:`add_executor_arguments`' options; a bad one raises
    :class:`warpsph.errors.SceneError` naming it (each of --devices is checked as --device is)."""
    if args.workers < 1:
        raise SceneError("", "--workers", f"expected an integer >= 1, got {args.workers}")
    if args.max_retries < 0:
        raise SceneError("", "--max-retries", f"expected an integer >= 0, got {args.max_retries}")
    if args.num_gpus is not None and not 0 <= args.num_gpus < math.inf:
        raise SceneError("", "--num-gpus", f"expected a number >= 0, got {args.num_gpus:g}")
    devices = [args.device] if getattr(args, "device", None) else None  # None: the sweep file's device
    if args.devices:
        try:
            devices = [pick_device(d.strip()) for d in args.devices.split(",") if d.strip()]
        except SceneError as exc:
            raise SceneError("", "--devices", exc.reason) from None
        if not devices:
            raise SceneError("", "--devices", "expected at least one device")
    if not 0 < args.num_cpus < math.inf:
        raise SceneError("", "--num-cpus", f"expected a number > 0, got {args.num_cpus:g}")
    return {"executor": args.executor, "workers": args.workers, "devices": devices, "address": args.address,
            "num_gpus": args.num_gpus, "num_cpus": args.num_cpus, "max_retries": args.max_retries}


def _local_devices(devices, sweep_device, file):
    """The local executor's worker-slot devices: ``devices`` (a list or "D,D"), else the sweep file's device
    (checked here, before any cell, as --devices is), else cpu."""
    if devices is None:
        devices = [sweep_device or "cpu"]
        if sweep_device:
            try:
                devices = [pick_device(sweep_device)]
            except SceneError as exc:
                raise SceneError(file, "device", exc.reason) from None
    if isinstance(devices, str):
        devices = [d.strip() for d in devices.split(",") if d.strip()]
    if not devices:
        raise SceneError("", "--devices", "expected at least one device")
    return devices


class SweepInterrupted(KeyboardInterrupt):
    """A sweep stopped by SIGINT or SIGTERM (``signum``); the message says what is kept and how to go on."""

    def __init__(self, message, signum):
        super().__init__(message)
        self.signum = signum


def run_sweep(sweep, out, executor="local", workers=1, devices=None, address=None, num_gpus=None, num_cpus=1,
              max_retries=3, log=None, ray_init=None):
    """Runs the cells of ``sweep`` (a path or dict) not yet finished in ``out``; returns the table (a dict,
    also written to ``out``/table.json and table.md).

    ``executor``: "local" (``workers`` processes, ``devices`` a list given to the worker slots in turn; default
    the sweep file's device or "cpu") or "ray" (``address`` of a cluster, else a local instance (``ray_init``:
    keyword arguments of ray.init); ``num_gpus`` per task (a fraction packs cells on a GPU; None: 1 when the
    device (``devices`` or the sweep file's) is cuda, else 0; see :func:`ray_placement`), ``num_cpus`` per task,
    ``max_retries``). ``log``: a function taking a progress line (default: info on the
    ``warpsph.sweep`` logger)."""
    spec = load_sweep(sweep)
    say = log or logging.getLogger(__name__).info
    if executor not in ("local", "ray"):
        raise SceneError("", "--executor", f"unknown executor '{executor}'; expected local or ray")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise SceneError("", "--workers", f"expected an integer >= 1, got {workers!r}")
    file = sweep if not isinstance(sweep, dict) else "<sweep>"
    if executor == "ray":  # the device honoured or refused before anything is written, as for the local executor
        asked_by = ("", "--num-gpus") if num_gpus is not None else ("", "--devices") if devices else (file, "device")
        num_gpus, ray_device = ray_placement(devices, spec["device"], num_gpus, file)
        ray = _ray_connect(address, num_gpus, ray_init, asked_by)
    else:
        devices = _local_devices(devices, spec["device"], file)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise SceneError(out, "--out", "is a file; --out names the sweep's output folder")
    for name, owned in OUTPUT_FILES.items():  # a rerun replaces its own files, never the user's
        path = out / name
        if (path.exists() or path.is_symlink()) and not owned(path):
            raise SceneError(path, "--out", "exists and was not written by warpsph sweep: refusing to replace it; "
                                            "choose another --out")
    (out / "cells").mkdir(parents=True, exist_ok=True)
    write_json({"sweep": spec, "source": str(sweep) if not isinstance(sweep, dict) else None}, out / SPEC_FILE)
    all_cells = cells(spec)
    todo = [c for c in all_cells if finished(out, c) is None]
    progress = _Progress(len(all_cells), len(all_cells) - len(todo), say)
    gpus = f", {num_gpus:g} GPU per cell" if executor == "ray" and num_gpus else ""
    progress.line(f"[{len(todo)} to run, executor {executor}{gpus}]")

    def on_record(cell, record):
        write_json(record, _cell_path(out, cell))
        progress.record(record)

    if todo:
        import signal
        import threading

        def on_sigterm(signum, _frame):
            raise SweepInterrupted("", signum)

        main_thread = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGTERM, on_sigterm) if main_thread else None
        try:
            if executor == "local":
                _local(todo, devices, min(workers, len(todo)), on_record, progress)
            else:
                _ray(ray, todo, num_gpus, num_cpus, max_retries, on_record, progress, ray_device)
        except KeyboardInterrupt as exc:  # Ctrl-C (or SIGTERM): the cells in flight were stopped by the executor
            signum = getattr(exc, "signum", signal.SIGINT)
            kept = sum(finished(out, c) is not None for c in all_cells)
            raise SweepInterrupted(
                f"{signal.Signals(signum).name}: the sweep stopped; {kept} of {len(all_cells)} cells are finished and "
                f"kept in {out / 'cells'}, the cells running were stopped and no table was written; run the same "
                f"command again to run the other {len(all_cells) - kept}", signum) from None
        finally:
            if main_thread:
                signal.signal(signal.SIGTERM, previous)
    table = assemble(spec, out)
    c = table["counts"]
    say(f"sweep: finished: {c['done']} done, {c['unstable']} unstable, {c['failed']} failed, {c['missing']} missing; "
        f"wrote {out / 'table.json'} and {out / 'table.md'}")
    return table
