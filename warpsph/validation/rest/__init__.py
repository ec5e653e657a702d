"""Tanks at rest under gravity: a sealed box filled to the lid and pools filled to 88, 93 and 95 %.

    warpsph validate tank-at-rest --resolutions 8 16 --device cpu --json rest.json

A cube of side 0.4 m (walls on every face) holds water filled to ``fill`` of its height (in whole particle
layers, at least one empty above a pool: ``fill_layers`` is the fill run); gravity is ramped in
over the first 0.2 s (a smooth step, as in the hydrostatic tank), then the tank rests until ``T`` (5 s).
Water at rest stays at rest: reported per fill are the largest speed over the last second against sqrt(g H)
(H the water height; the goal of #37 is 1e-3), the unremoved mean density error away from the free surface, and
how many particles the solver took for the free surface at the end (none in the sealed box).
"""

import numpy as np

from warpsph.validation.hydrostatic import ramp_gravity
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation

SIDE = 0.4  # m
T_END = 5.0  # s
RAMP = 0.2  # s: gravity ramped in
FILLS = (1.0, 0.95, 0.93, 0.88)
G = 9.81


def tank_at_rest(resolution, fill, device="cpu", T=T_END, models=(), overrides=None, on_run=None):
    """Runs one tank (``resolution`` particles across the side) to ``T``; returns its measurements.
    ``on_run(sim, run)``: called with the simulation and a function that runs it (for timing)."""
    radius = SIDE / (2 * resolution)
    # whole particle layers; a pool keeps at least one empty layer above it
    layers = resolution if fill >= 1.0 else max(1, min(resolution - 1, round(fill * resolution)))
    height = layers * SIDE / resolution
    data = {"name": f"rest_{int(round(100 * fill))}", "particle_radius": radius, "gravity": [0, 0, 0],
            "domain": {"min": [0, 0, 0], "max": [SIDE, SIDE, SIDE]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [SIDE, height, SIDE]}], "models": list(models)}
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    speeds = []

    def run():
        while sim.time < T:
            ramp_gravity(sim, RAMP, G)
            sim.step()
            if sim.time > T - 1.0 and sim.step_count % 10 == 0:
                speeds.append(float(np.sqrt(sim.max_speed_sq.numpy()[0])))

    if on_run is not None:
        on_run(sim, run)
    else:
        run()
    scale = np.sqrt(G * height)
    speed_end = float(np.linalg.norm(sim.velocities(), axis=1).max())
    return {"fill": fill, "fill_layers": height / SIDE, "particles": sim.num_fluid, "water_height_m": height, "steps": sim.step_count,
            "max_speed_last_second": max(speeds + [speed_end]), "speed_end": speed_end,
            "max_speed_over_sqrt_gH": max(speeds + [speed_end]) / scale,
            "surface_particles_end": int(sim.pressure_solver.free_surface_count()), "sim": sim}
