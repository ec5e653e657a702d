"""Dam-break front against Martin & Moyce (1952), column height / width = 2 (n^2 = 2).

    warpsph validate dam-front --resolutions 8 10 --device cpu --json dam_front.json
    python -m warpsph.validation.dam_front --resolution 10 --device cpu --out tools/results/dam_front_cpu.json

A column of width a and height 2a (a = 2.25 in = 0.05715 m) collapses along a long, quasi-2D tank
(``--depth`` particles deep, 4 by default). The front Z (the 99.5th percentile of x among the particles within a of the floor,
so a lone splash does not lead it) is recorded against T = t sqrt(2 g / a).

Start-time offset: the experiment's clock starts at the gate release, which takes time; its first
reading is Z/a = 1.217 at T = 0.832. We report the error per reference point both raw and after the
constant time shift dT in [-1, 1] that minimises the RMS error (the shift is reported).
Writes JSON and, with matplotlib, a PNG of Z/a against T.
"""

import argparse
import json
import time
from importlib import resources

import numpy as np
from warpsph.plots import write_report
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation

# the experiment's points beside this module (reference.json, shipped with the package): (T, Z/a) for a = 2.25 in
REFERENCE = json.loads(resources.files(__name__).joinpath("reference.json").read_text(encoding="utf-8"))
MARTIN_MOYCE = np.array(REFERENCE["series"]["a = 2.25 in"]["points"])
A = REFERENCE["series"]["a = 2.25 in"]["a_m"]  # m: 2.25 in
G = 9.81
T_END = 6.0  # the run's end in T = t sqrt(2 g / a)
DEPTH = 4  # tank depth in particles


def dam_front(resolution=10, device="cpu", T_end=T_END, samples_per_T=8, models=(), depth=DEPTH, timing=None,
              overrides=None):
    """Runs the dam break; returns arrays T and Z/a, and the simulation. ``timing`` (a dict) receives
    ``wall_s``: the run alone, device synchronised, the per-frame front measurement subtracted.
    ``overrides``: dotted scene keys to set (:func:`warpsph.scene.with_overrides`)."""
    d = A / resolution
    r = d / 2
    scale_T = np.sqrt(2 * G / A)
    fps = samples_per_T * scale_T
    data = {
        "name": "martin_moyce", "particle_radius": r,
        "domain": {"min": [0, 0, 0], "max": [12 * A, 2.5 * A, depth * d]},
        "fluid_blocks": [{"start": [0, 0, 0], "end": [A, 2 * A, depth * d]}],
        "fluid": {"viscosity": 1.0e-6},  # water: the experiment's fluid
        "output": {"fps": fps}, "models": list(models),
    }
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    import warp as wp

    T, Z = [], []
    measuring = [0.0]

    def on_frame(sim, frame):
        wp.synchronize_device(sim.device)  # the run's own work ends here
        start = time.perf_counter()
        x = sim.fluid.x.numpy()
        low = x[:, 1] < A
        T.append(sim.time * scale_T)
        Z.append(np.percentile(x[low, 0], 99.5) / A if low.any() else 0.0)
        measuring[0] += time.perf_counter() - start

    wp.synchronize_device(sim.device)
    start = time.perf_counter()
    sim.run(until_time=T_end / scale_T, on_frame=on_frame)
    wp.synchronize_device(sim.device)
    if timing is not None:
        timing["wall_s"] = time.perf_counter() - start - measuring[0]
    return np.array(T), np.array(Z), sim


def compare(T, Z, reference=MARTIN_MOYCE):
    """Errors of Z/a at the reference T, raw and with the best constant time shift."""
    def errors(shift):
        inside = (reference[:, 0] + shift >= T[0]) & (reference[:, 0] + shift <= T[-1])
        model = np.interp(reference[inside, 0] + shift, T, Z)
        return inside, model - reference[inside, 1]

    shifts = np.linspace(-1.0, 1.0, 401)
    rms = [np.sqrt(np.mean(errors(s)[1] ** 2)) if errors(s)[0].sum() >= 5 else np.inf for s in shifts]
    best = float(shifts[int(np.argmin(rms))])
    inside0, raw = errors(0.0)
    inside1, shifted = errors(best)
    return {
        "reference_T": reference[:, 0].tolist(), "reference_Z_over_a": reference[:, 1].tolist(),
        "raw_errors": raw.tolist(), "raw_rms": float(np.sqrt(np.mean(raw**2))), "raw_points": int(inside0.sum()),
        "time_shift_T": best, "shifted_errors": shifted.tolist(), "shifted_rms": float(np.min(rms)),
        "shifted_points": int(inside1.sum()),
    }


def figures(report):
    """The report's figure, from the report alone: the front Z/a against T, raw and time-shifted, and the
    experiment."""
    T, Z, shift = np.asarray(report["T"]), np.asarray(report["Z_over_a"]), report["time_shift_T"]
    return [("", [(T, Z, "-", f"warpsph ({report['particles']} particles)"), (T - shift, Z, "--", f"shifted by {shift:+.2f}"),
                  (MARTIN_MOYCE[:, 0], MARTIN_MOYCE[:, 1], "ko", "Martin & Moyce 1952")], "T = t sqrt(2g/a)", "Z / a", (6, 4))]


def main(argv=None):
    parser = argparse.ArgumentParser(prog=f"python -m {__name__}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=10, help="particles across the column width a")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--T-end", type=float, default=T_END)
    parser.add_argument("--depth", type=int, default=DEPTH, help="tank depth in particles (quasi-2D)")
    parser.add_argument("--out", help="JSON file (a PNG is written beside it when matplotlib is present)")
    args = parser.parse_args(argv)
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    T, Z, sim = dam_front(args.resolution, args.device, args.T_end, depth=args.depth)
    result = {"case": "Martin & Moyce 1952, a = 2.25 in, n^2 = 2", "resolution": args.resolution, "depth": args.depth,
              "particles": sim.num_fluid, "device": str(sim.device), "warp": wp.__version__,
              "T": T.tolist(), "Z_over_a": Z.tolist(), **compare(T, Z)}
    print(f"{sim.num_fluid} particles: RMS error of Z/a {result['raw_rms']:.3f} raw, {result['shifted_rms']:.3f} "
          f"with time shift {result['time_shift_T']:+.3f}")
    if args.out:
        write_report(result, args.out, figures(result))
