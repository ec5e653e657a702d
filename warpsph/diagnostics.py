"""Per-frame diagnostics: energies, enstrophy, density error, solver iterations.

Computed at output frames only, never inside a step: reduced on the device, a few numbers read. Written as CSV beside
the USD cache by the CLI, and plotted by ``warpsph plot energy`` (like Fig 7 of the VR paper). The run's metadata
(``warpsph:import_dropped``: what a SPlisHSPlasH scene run anyway leaves out) goes into a JSON sidecar, OUT.stats.meta.json,
so the CSV stays plain for every reader.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import warp as wp

from warpsph.kernels import diagnostics as dk

COLUMNS = ["frame", "time", "steps", "particles", "dt", "kinetic_energy", "potential_energy", "rotational_energy", "enstrophy",
           "density_error_mean", "density_error_max", "divergence_iterations", "density_iterations", "removed"]


@dataclass
class DiagnosticsContext:
    """What the frame diagnostics see of one simulation (a decomposed one: of each subdomain), and nothing else (no
    solver, no bodies, no neighbour search): the state (the fluid's arrays and count, dt, the allocation call), the
    constants, the device and the launch call, the scene's gravity, and what the solver and the models publish for a
    frame. ``Simulation.diagnostics_context`` is one."""

    state: object  # warpsph.state.State
    constants: object  # warpsph.state.Constants
    device: object  # the simulation's Warp device
    launch: object  # (kernel, dim, inputs): on the simulation's device, counted
    gravity: tuple  # the scene's gravity [m/s^2] (the potential energy's)
    vorticity: object  # the shared vorticity of v~ this step (a device array), or None where no model keeps one
    curl: object  # (v, out) -> the SPH curl of v over the last step's lists, into out (eq 6)
    spin: object  # () -> (angular velocity array, micro-inertia) of the model that carries a spin, or None
    turbulence: bool  # whether a turbulence model runs (its particles spin at zeta / 2)
    iteration_totals: object  # () -> the pressure solver's (divergence iterations, solves, density iterations, solves)
    removed: object  # () -> the particles removed so far (inside sinks and outside an open domain)


class Diagnostics:
    """Measures a simulation at output frames; ``measure(sim, frame)`` returns one row (dict).

    The sums and maxima are reduced on the device (``kernels/diagnostics.py``): seven float64
    numbers cross to the host, not the particle arrays. The enstrophy uses the step's own
    vorticity when a model keeps one; plain DFSPH takes the curl of v over the lists of the last
    step (built at its start: no rebuild at the frame, pairs that came within the support
    radius during the step's advection are left out, as they are for the models)."""

    def __init__(self, region=None):
        """``region``: (lower, upper) corners [m] of a box whose enstrophy the rows also give
        (``region_enstrophy``, e.g. a wake); none: the rows have no such column."""
        self.region = region
        self._arrays = {}  # per part (the simulation, or each subdomain): the reduction's output and scratch
        self._totals = (0, 0, 0, 0)

    def reduce(self, sim):
        """The device reductions of :mod:`warpsph.kernels.diagnostics` as a float64 numpy array, summed over
        the simulation's parts (the maximum of the density error the largest of theirs)."""
        sums = [self._reduce_part(part) for part in sim.parts()]
        out = np.sum(sums, axis=0)
        out[dk.ERROR_MAX] = max(s[dk.ERROR_MAX] for s in sums)
        return out

    def _reduce_part(self, part):
        ctx = part.diagnostics_context
        state, c = ctx.state, ctx.constants
        n = state.num_fluid
        if n == 0:
            return np.zeros(dk.SLOTS, np.float64)
        a = self._arrays.get(id(ctx))
        if a is None:
            a = self._arrays[id(ctx)] = {"out": state.zeros("diagnostics", dk.SLOTS, dtype=wp.float64),
                                         "empty": wp.empty(0, dtype=wp.vec3, device=ctx.device), "vorticity": None}
        init = np.zeros(dk.SLOTS, np.float64)
        init[dk.ERROR_MAX] = -np.inf
        f = state.fluid
        with wp.ScopedDevice(ctx.device):
            if ctx.vorticity is not None:
                zeta = ctx.vorticity
            else:  # plain DFSPH: a scratch array owned by the diagnostics
                if a["vorticity"] is None:
                    a["vorticity"] = state.zeros("diagnostics", state.capacity, dtype=wp.vec3)
                zeta = ctx.curl(f.v, a["vorticity"])
            spinning = ctx.spin()
            spin = spinning[0] if spinning is not None else a["empty"]
            a["out"].assign(init)
            ctx.launch(dk.reduce_frame_diagnostics, min(n, int(dk.REDUCE_THREADS)),
                       [f.x, f.v, f.density, zeta, spin, n, wp.vec3d(*c.domain_min), wp.vec3d(*ctx.gravity),
                        wp.float64(c.particle_mass), wp.float64(c.rest_density),
                        wp.vec3(*(self.region[0] if self.region else (1.0, 1.0, 1.0))),
                        wp.vec3(*(self.region[1] if self.region else (0.0, 0.0, 0.0))), a["out"]])
            return a["out"].numpy()

    def measure(self, sim, frame):
        """One row for ``sim`` (a simulation, or a decomposed one: its parts summed) at ``frame``: the public counts
        and clock of ``sim``, the rest through its first part's :class:`DiagnosticsContext` (the models and the solver
        are the same in every part)."""
        ctx = sim.parts()[0].diagnostics_context
        m = ctx.constants.particle_mass
        sums = self.reduce(sim)
        rotational = 0.0
        spinning = ctx.spin()
        if spinning is not None:  # sum_i 1/2 m I |omega_i|^2 with the model's micro-inertia I (micropolar: 1 / Theta^-1)
            rotational = 0.5 * m * spinning[1] * float(sums[dk.SPIN_SQ])
        elif ctx.turbulence:  # VR / Rankine: particle spin zeta/2, inertia of a sphere 2/5 m r^2
            inertia = 0.4 * m * ctx.constants.particle_radius ** 2
            rotational = 0.5 * inertia * 0.25 * float(sums[dk.VORTICITY_SQ])
        totals = ctx.iteration_totals()
        d = [a - b for a, b in zip(totals, self._totals)]
        self._totals = totals
        n = sim.num_fluid
        row = {
            "frame": frame,
            "time": sim.time,
            "steps": sim.step_count,
            "particles": n,
            "dt": float(ctx.state.dt.numpy()[0]),
            "kinetic_energy": 0.5 * m * float(sums[dk.KINETIC]),
            "potential_energy": -m * float(sums[dk.POTENTIAL]),
            "rotational_energy": rotational,
            "enstrophy": 0.5 * float(sums[dk.ENSTROPHY]),
            "density_error_mean": float(sums[dk.ERROR_SUM]) / n if n else 0.0,
            "density_error_max": float(sums[dk.ERROR_MAX]) if n else 0.0,
            "divergence_iterations": d[0] / d[1] if d[1] else 0.0,
            "density_iterations": d[2] / d[3] if d[3] else 0.0,
            # particles removed since the start: inside sinks and outside an open domain
            "removed": ctx.removed(),
        }
        if self.region is not None:
            row["region_enstrophy"] = 0.5 * float(sums[dk.REGION_ENSTROPHY])
        return row


def vorticity_now(sim):
    """The fluid's vorticity at the current state, for any run (plain DFSPH too): fresh neighbour lists and
    densities for the current positions (``sim.update_densities``), then the SPH curl of v (``curl_of``, eq 6).
    For measurements between frames (VR paper Fig 4's slices, #21): the velocity at the frame, not a model's
    field (the curl of v~ inside the step). The next step rebuilds the lists and densities itself, so the run
    goes on as it would have. Returns host float64 arrays (x, zeta, volume m / max(rho, 1e-9)) of the fluid
    particles, as :class:`Diagnostics` weighs the enstrophy."""
    ctx = sim.diagnostics_context
    f, n = ctx.state.fluid, ctx.state.num_fluid
    with wp.ScopedDevice(ctx.device):
        sim.update_densities()
        zeta = ctx.curl(f.v, wp.zeros(max(n, 1), dtype=wp.vec3, device=ctx.device))
        x = f.x.numpy()[:n].astype(np.float64)
        rho = f.density.numpy()[:n].astype(np.float64)
        zeta = zeta.numpy()[:n].astype(np.float64)
    return x, zeta, ctx.constants.particle_mass / np.maximum(rho, 1e-9)


class DiagnosticsWriter:
    """An ``on_frame`` callback that appends one CSV row per frame (flushed, so a stopped run keeps its rows).
    ``append``: continue the file after frame ``append`` (rows of later frames, from a run resumed
    before, are dropped: each frame once)."""

    def __init__(self, path, append=None, metadata=None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.diagnostics = Diagnostics()
        append = append is not None and self.path.exists() and _keep_rows(self.path, append)
        if not append:
            write_metadata(self.path, metadata)
            _write_header(self.path)
        self._file = open(self.path, "a", newline="")
        self._csv = csv.DictWriter(self._file, fieldnames=COLUMNS)
        self.rows = []

    def __call__(self, sim, frame):
        self.write_row(self.diagnostics.measure(sim, frame))

    def measure(self, sim, frame):
        """One row (on the simulation's thread); :meth:`write_row` may then run on a writer thread."""
        return self.diagnostics.measure(sim, frame)

    def write_row(self, row):
        self._csv.writerow(row)
        self._file.flush()
        self.rows.append(row)

    def close(self):
        self._file.close()


def _write_header(path):
    """A new CSV holding its header, through a rename: a run killed before its first row leaves a file that
    --overwrite knows as warpsph's (it was empty, and refused)."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        csv.DictWriter(f, fieldnames=COLUMNS).writeheader()
    tmp.replace(path)


def _keep_rows(path, last):
    """Rewrites the CSV with the rows of frames up to ``last`` only; False when it is unreadable."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        rows = [r for r in rows if float(r["frame"]) <= last]
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError):
        return False
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore", restval="0")  # older files: no "removed"
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)
    return True


def is_stats_csv(path):
    """Whether ``path`` is a diagnostics CSV that warpsph wrote (its header)."""
    try:
        with open(path, newline="") as f:
            return f.readline().strip().startswith(",".join(COLUMNS[:3]) + ",")
    except (OSError, UnicodeDecodeError):
        return False


def metadata_path(path):
    """The JSON sidecar of a diagnostics CSV (OUT.stats.csv -> OUT.stats.meta.json)."""
    return Path(path).with_suffix(".meta.json")


def write_metadata(path, metadata):
    """Writes the run's ``metadata`` (a dict) beside the CSV ``path``; none: removes an earlier run's sidecar."""
    side = metadata_path(path)
    if metadata:
        side.write_text(json.dumps({"generator": "warpsph", **metadata}, indent=1) + "\n")
    elif is_metadata(side):
        side.unlink()


def is_metadata(path):
    """Whether ``path`` is a metadata sidecar that warpsph wrote."""
    try:
        return Path(path).is_file() and json.loads(Path(path).read_text()).get("generator") == "warpsph"
    except (OSError, ValueError, UnicodeDecodeError, AttributeError):
        return False


def read_metadata(path):
    """The metadata of the run whose diagnostics CSV is ``path`` ({} when it has none)."""
    side = metadata_path(path)
    return {k: v for k, v in json.loads(side.read_text()).items() if k != "generator"} if side.is_file() else {}


def read_csv(path):
    """Columns of a diagnostics CSV as float arrays."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]} if rows else {}
