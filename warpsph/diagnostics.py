"""Per-frame diagnostics: energies, enstrophy, density error, solver iterations.

Computed at output frames only (host reads), never inside a step. Written as CSV beside
the USD cache by the CLI, and plotted by ``tools/plot_energy.py`` (like Fig 7 of the VR paper).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import warp as wp

from warpsph.models.vorticity import curl_of

COLUMNS = ["frame", "time", "steps", "particles", "dt", "kinetic_energy", "potential_energy", "rotational_energy", "enstrophy",
           "density_error_mean", "density_error_max", "divergence_iterations", "density_iterations"]


class Diagnostics:
    """Measures a simulation at output frames; ``measure(sim, frame)`` returns one row (dict)."""

    def __init__(self):
        self._vorticity = None
        self._totals = (0, 0, 0, 0)

    def _vorticity_of(self, sim):
        if sim.vorticity_field is not None:
            return sim.host(sim.vorticity_field.vorticity)
        if self._vorticity is None:  # plain DFSPH: a scratch array owned by the diagnostics
            self._vorticity = sim.zeros("diagnostics", sim.capacity, dtype=wp.vec3)
        f = sim.fluid
        sim.neighbours.update(f.x)  # the lists of the current positions
        return sim.host(curl_of(sim, f.v, self._vorticity))

    def measure(self, sim, frame):
        m = sim.particle_mass
        x = sim.host(sim.fluid.x).astype(np.float64)
        v = sim.host(sim.fluid.v).astype(np.float64)
        rho = sim.host(sim.fluid.density).astype(np.float64)
        g = np.asarray(sim.scene.gravity, np.float64)
        zeta = self._vorticity_of(sim).astype(np.float64)
        volume = m / np.maximum(rho, 1e-9)
        rotational = 0.0
        for model in sim.turbulence_models:
            if hasattr(model, "rotational_energy"):
                rotational = model.rotational_energy(sim)
                break
        else:
            if sim.turbulence_models:  # VR / Rankine: particle spin zeta/2, inertia of a sphere 2/5 m r^2
                inertia = 0.4 * m * sim.scene.particle_radius ** 2
                rotational = 0.5 * inertia * float((0.25 * zeta**2).sum())
        totals = sim.pressure_solver.iteration_totals()
        d = [a - b for a, b in zip(totals, self._totals)]
        self._totals = totals
        error = rho / sim.rest_density - 1.0
        return {
            "frame": frame,
            "time": sim.time,
            "steps": sim.step_count,
            "particles": sim.num_fluid,
            "dt": float(sim.dt.numpy()[0]),
            "kinetic_energy": 0.5 * m * float((v**2).sum()),
            "potential_energy": -m * float(((x - np.asarray(sim.scene.domain.min)) @ g).sum()),
            "rotational_energy": rotational,
            "enstrophy": 0.5 * float((volume[:, None] * zeta**2).sum()),
            "density_error_mean": float(np.maximum(error, 0.0).mean()),
            "density_error_max": float(error.max()),
            "divergence_iterations": d[0] / d[1] if d[1] else 0.0,
            "density_iterations": d[2] / d[3] if d[3] else 0.0,
        }


class DiagnosticsWriter:
    """An ``on_frame`` callback that appends one CSV row per frame (flushed, so a stopped run keeps its rows).
    ``append``: continue the file after frame ``append`` (rows of later frames, from a run resumed
    before, are dropped: each frame once)."""

    def __init__(self, path, append=None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.diagnostics = Diagnostics()
        append = append is not None and self.path.exists() and _keep_rows(self.path, append)
        self._file = open(self.path, "a" if append else "w", newline="")
        self._csv = csv.DictWriter(self._file, fieldnames=COLUMNS)
        if not append:
            self._csv.writeheader()
        self.rows = []

    def __call__(self, sim, frame):
        row = self.diagnostics.measure(sim, frame)
        self._csv.writerow(row)
        self._file.flush()
        self.rows.append(row)

    def close(self):
        self._file.close()


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
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
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


def read_csv(path):
    """Columns of a diagnostics CSV as float arrays."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]} if rows else {}
