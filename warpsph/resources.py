"""Memory estimate of a scene before anything is allocated (refuse what will not fit)."""

from __future__ import annotations

import os

import numpy as np

from warpsph.errors import SceneError
from warpsph.models import plugin_of
from warpsph.neighbours import grid_geometry
from warpsph.solvers import solver_class

# bytes per fluid particle, from the arrays Simulation allocates (measured 301 B/particle in all
# on the 1M dam break, tools/results/bench_dam_break_1M_model_none_h100.json on the `results` branch)
# (the pressure solvers' own: warpsph/solvers/base.py)
SORT = 2 * 8 + 12 + 8  # keys and order (2N each) and a gather copy: held only while sorting (the peak)
NEIGHBOUR_ROWS = 4 * 4  # counts and offsets of both lists
NEIGHBOUR_LISTS = 4 * (32 + 8)  # initial capacity: 32 fluid, 8 boundary neighbours a particle
BOUNDARY = 12 + 12 + 4 + 4  # x, v, volume and cell-sorted id per boundary sample
SHARED_VORTICITY = 12  # the vorticity field of v~, once for all models that read it


def estimate_bytes(scene, num_fluid, num_boundary):
    """Device bytes a simulation of ``scene`` allocates (an estimate, slightly high)."""
    plugins = [plugin_of(m) for m in scene.models]
    solver = solver_class(scene.solver.method)
    scratch = [p.scratch_columns for p in plugins] + [0, solver.pool_columns(scene)]
    per_fluid = solver.bytes_per_particle(scene) + SORT + NEIGHBOUR_ROWS + NEIGHBOUR_LISTS  # the solver's fluid state
    per_fluid += sum(p.bytes_per_particle for p in plugins)  # each model's own arrays
    per_fluid += SHARED_VORTICITY if any(p.needs_vorticity for p in plugins) else 0
    per_fluid += 4 * max(scratch)  # the scratch pool (DFSPH: if wider than its own, counted in SOLVER)
    _, dims = grid_geometry(scene.domain, scene.support_radius, num_fluid + num_boundary)
    cell_tables = 2 * 4 * int(np.prod(dims))  # the fluid's and the boundary's
    return num_fluid * per_fluid + num_boundary * BOUNDARY + cell_tables


def free_bytes(device):
    """Free memory of a Warp device: the GPU's, or the host's available RAM for ``cpu``."""
    if device.is_cuda:
        return int(device.free_memory)
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError):
        return None


def check_fits(scene, num_fluid, num_boundary, device):
    """Raises :class:`SceneError` (key particle_radius) when the scene will not fit on ``device``."""
    need = estimate_bytes(scene, num_fluid, num_boundary)
    free = free_bytes(device)
    if free is not None and need > free:
        raise SceneError(scene.source, "particle_radius",
                         f"{num_fluid} fluid + {num_boundary} boundary particles need about {need / 2**30:.2f} GiB "
                         f"but {device} has {free / 2**30:.2f} GiB free: use a larger radius or a smaller --scale")
    return need
