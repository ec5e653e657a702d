"""Developer script (#37): the tanks at rest of `warpsph validate tank-at-rest` under one solver variant, one JSON line
per tank on stdout. The variant is whatever the environment sets (a prototype's WARPSPH_* switches, e.g. from a
patch in docs/notes/patches/) plus scene overrides in OVR (JSON), so that variants run as separate processes:

    OVR='{"solver": {"shifting": 8.0}}' python tools/tanks_variants.py shift8 10 2.5 1e-6 1.0 0.88

Arguments: label, particles across the 0.4 m tank, end time T [s], viscosity [m^2/s], fills (default 1.0 0.88).
Each line: the case's measurements (largest speed over the last second / sqrt(gH), ...), the rms speed at T over
sqrt(gH), the mean density error of all fluid particles at T, the wall time and the WARPSPH_* environment."""

import json
import os
import sys
import time

import numpy as np

from warpsph.device import init_warp
from warpsph.validation.rest import G, tank_at_rest


def main(argv):
    label, resolution, end, nu = argv[0], int(argv[1]), float(argv[2]), float(argv[3])
    fills = [float(f) for f in argv[4:]] or [1.0, 0.88]
    overrides = {"fluid": {"viscosity": nu}, **json.loads(os.environ.get("OVR", "{}"))}
    init_warp()
    for fill in fills:
        start = time.time()
        try:
            row = tank_at_rest(resolution, fill, device=os.environ.get("DEV", "cpu"), T=end, overrides=overrides)
            sim = row.pop("sim")
            row["mean_density_error"] = float(sim.fluid.density.numpy().mean() / sim.scene.fluid.density - 1.0)
            speed = np.linalg.norm(sim.velocities(), axis=1)
            row["rms_over_sqrt_gH"] = float(np.sqrt((speed ** 2).mean()) / np.sqrt(G * row["water_height_m"]))
        except Exception as exc:  # a blown-up variant is a result too
            row = {"fill": fill, "error": repr(exc)[:200]}
        row.update(label=label, resolution=resolution, T=end, nu=nu, wall_s=round(time.time() - start, 1),
                   env={k: v for k, v in os.environ.items() if k.startswith("WARPSPH_")}, overrides=overrides)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
