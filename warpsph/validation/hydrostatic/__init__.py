"""Hydrostatic tank (after Adami et al. 2012): density error and pressure against rho g h.

    warpsph validate hydrostatic --resolutions 10 20 --device cpu --json hydrostatic.json
    python -m warpsph.validation.hydrostatic --radius 0.02 --device cpu --out tools/results/hydrostatic_cpu.json

A 0.4 m cube of water rests in a tank; gravity is ramped in over the first 0.2 s (smoothly, to avoid
sloshing), then the tank settles for ``--T`` seconds. Reported: mean and max density error of the
particles deeper than one support radius, the largest speed, and the pressure along a vertical probe
line through the centre (particles within 2r of it, averaged over the last 20 steps) against
p = rho0 g (H - y), with H the water height from the fluid volume. JSON, and a PNG with matplotlib.
``warpsph validate hydrostatic`` counts the resolution in particles across the cube (radius = SIDE / 2N:
10 across is r = 0.02 m).
"""

import argparse
import time

import numpy as np
from warpsph.plots import write_report
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation

SIDE = 0.4  # m: the water cube
T_END = 1.5  # s: settled time (gravity ramped in over the first 0.2 s)


def ramp_gravity(sim, ramp, g=9.81):
    """Sets ``sim.gravity`` (along -y) to g ramped in with a smooth step over the first ``ramp`` seconds (a tank
    started at rest does not slosh)."""
    import warp as wp

    s = min(sim.time / ramp, 1.0)
    sim.gravity = wp.vec3(0.0, -g * (3 * s * s - 2 * s * s * s), 0.0)


def hydrostatic(radius=0.02, T=T_END, device="cpu", ramp=0.2, models=(), overrides=None):
    """Runs the tank; returns the measurements (with ``wall_s``: the stepping alone, device synchronised, and
    ``steps``). ``overrides``: dotted scene keys to set (:func:`warpsph.scene.with_overrides`)."""
    side = SIDE
    data = {"name": "hydrostatic", "particle_radius": radius, "gravity": [0, 0, 0],
            "domain": {"min": [0, 0, 0], "max": [side, 1.5 * side, side]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [side, side, side]}], "models": list(models)}
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    import warp as wp

    wp.synchronize_device(sim.device)
    start = time.perf_counter()
    while sim.time < T:
        ramp_gravity(sim, ramp)
        sim.step()
    x = sim.fluid.x.numpy()
    height = sim.num_fluid * sim.fluid_volume / side**2
    probe = np.all(np.abs(x[:, [0, 2]] - side / 2) < 2 * radius, axis=1)
    pressures = []
    for _ in range(20):
        sim.step()
        pressures.append(sim.pressure_solver.pressure_field())
    p = np.mean(pressures, axis=0)
    wp.synchronize_device(sim.device)
    wall = time.perf_counter() - start
    x = sim.fluid.x.numpy()
    rho = sim.fluid.density.numpy() / sim.rest_density
    deep = x[:, 1] < x[:, 1].max() - sim.support_radius
    ids_probe = probe  # particles barely move at rest
    y = x[ids_probe, 1]
    exact = sim.rest_density * 9.81 * (height - y)
    mid = np.abs(y - height / 2) < 1.5 * radius
    return {
        "particles": sim.num_fluid, "radius": radius, "T": T, "water_height": height,
        "density_error_mean": float(np.mean(rho[deep] - 1.0)), "density_error_max": float(np.max(np.abs(rho[deep] - 1.0))),
        "density_error_mean_abs": float(np.mean(np.abs(rho[deep] - 1.0))),
        "max_speed": float(np.linalg.norm(sim.fluid.v.numpy(), axis=1).max()),
        "probe_y": y.tolist(), "probe_pressure": p[ids_probe].tolist(), "probe_pressure_exact": exact.tolist(),
        "mid_depth_pressure_ratio": float(p[ids_probe][mid].mean() / exact[mid].mean()),
        "probe_pressure_rms_error_relative": float(np.sqrt(np.mean((p[ids_probe] - exact) ** 2)) / (sim.rest_density * 9.81 * height)),
        "wall_s": wall, "steps": sim.step_count, "device": str(sim.device),
    }


def figures(report):
    """The report's figure, from the report alone: the probe's pressure against rho g (H - y)."""
    return [("", [(report["probe_pressure"], report["probe_y"], "o", "warpsph"),
                  (report["probe_pressure_exact"], report["probe_y"], "k-", "rho g (H - y)")],
             "pressure [Pa]", "y [m]", (4, 5))]


def main(argv=None):
    parser = argparse.ArgumentParser(prog=f"python -m {__name__}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--radius", type=float, default=0.02)
    parser.add_argument("--T", type=float, default=T_END)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--out")
    args = parser.parse_args(argv)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    result = hydrostatic(args.radius, args.T, args.device)
    result["warp"] = wp.__version__
    print(f"{result['particles']} particles: density error mean {100 * result['density_error_mean']:+.3f} %, "
          f"max {100 * result['density_error_max']:.3f} %; mid-depth p / rho g h = {result['mid_depth_pressure_ratio']:.3f}; "
          f"probe RMS error {100 * result['probe_pressure_rms_error_relative']:.1f} % of rho g H; max |v| {result['max_speed']:.4f} m/s")
    if args.out:
        write_report(result, args.out, figures(result))
