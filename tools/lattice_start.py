"""Developer script (#37): a sealed 0.4 m box filled from a perfect lattice under full gravity (no ramp) on the CPU.
Prints one JSON line: the rms speed at 0.04 / 0.1 / 0.2 / 0.3 s and the layer-mean pressure of both solves [Pa] at
0.04 s (the odd-even layer pattern of the density solve shows there). A prototype's WARPSPH_* switches and scene
overrides in OVR (JSON) select the variant:

    OVR='{"solver": {"shifting": 8.0}}' python tools/lattice_start.py shift8 12
"""

import json
import os
import sys
import time

import numpy as np

from warpsph.device import init_warp
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation

SIDE = 0.4  # m
MARKS = (0.04, 0.1, 0.2, 0.3)  # s


def main(label, across=12):
    r = SIDE / (2 * across)
    data = {"name": "lattice", "particle_radius": r, "gravity": [0, -9.81, 0],
            "domain": {"min": [0, 0, 0], "max": [SIDE] * 3}, "fluid_blocks": [{"start": [0, 0, 0], "end": [SIDE] * 3}],
            "fluid": {"viscosity": 1e-6}}
    init_warp()
    sim = Simulation(scene_from_dict(with_overrides(data, json.loads(os.environ.get("OVR", "{}")))), device="cpu")
    out, start, marks = {"label": label, "across": across}, time.time(), list(MARKS)
    while marks:
        sim.step()
        if sim.time < marks[0] - 1e-9:
            continue
        v = sim.velocities()
        out[f"rms_{marks[0]}"] = float(np.sqrt((v ** 2).sum(1).mean()))
        if marks[0] == MARKS[0]:
            sums = sim.pressure_solver.pressure_sum
            p = (sums[0].numpy() + sums[1].numpy())[: sim.num_fluid] * sim.scene.fluid.density
            layer = np.floor(sim.positions()[:, 1] / (2 * r)).astype(int)
            out["p_layers_Pa"] = [round(float(p[layer == n].mean())) for n in range(min(across, 12))]
        marks.pop(0)
    out.update(steps=sim.step_count, wall_s=round(time.time() - start, 1))
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], *map(int, sys.argv[2:3]))
