"""Where Taylor-Green's kinetic energy goes, by solver stage: the change of sum |v|^2 (as a fraction of its
value at t = 0) inside the divergence solve, inside the density solve, and in the rest of the step (the
viscosity's acceleration; shifting moves positions only), against the analytic exp(-16 pi^2 nu t) - 1.
Default solver and validation scene (warpsph.validation.taylor_green, packed start). The step runs without
a captured graph so each solve can be measured. Developer diagnostic for issue #16 (docs/notes/solver.md).

    python tools/taylor_green_energy_budget.py --device cuda --resolution 256 [--solver '{"shifting": 0}']
"""
import argparse
import json

import numpy as np
import warp as wp

wp.config.log_level = wp.LOG_WARNING
from warpsph.validation import taylor_green as tg  # noqa: E402

TIMES = (0.05, 0.1, 0.2, 0.3)


def budget(device, resolution, solver=None, times=TIMES):
    """Rows at each time in ``times``: the energy changes by stage, as fractions of KE(0)."""
    overrides = {f"solver.{k}": v for k, v in (solver or {}).items()} or None
    sim, _ = tg.build([], resolution, tg.NU, max(times), device, pack_steps=tg.PACK_STEPS, overrides=overrides)
    sim.use_graph = False
    energy = sim.kinetic_energy
    ke0 = energy()

    spent = {"divergence_solve": 0.0, "density_solve": 0.0}

    def measured(solve, label):
        def run(*args, **kwargs):
            before = energy()
            result = solve(*args, **kwargs)
            spent[label] += (energy() - before) / ke0
            return result
        return run

    ps = sim.pressure_solver
    ps.correct_divergence = measured(ps.correct_divergence, "divergence_solve")
    ps.correct_density = measured(ps.correct_density, "density_solve")
    rows, pending = [], list(times)
    while pending:
        sim.step()
        if sim.time >= pending[0]:
            pending.pop(0)
            total = (energy() - ke0) / ke0
            rows.append({"across": resolution, "solver_keys": solver or {}, "t": sim.time, "steps": sim.step_count,
                         "dKE_over_KE0": total, "analytic": float(np.exp(-16 * np.pi**2 * tg.NU * sim.time) - 1),
                         **spent, "rest_viscosity": total - sum(spent.values())})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--resolution", type=int, default=32, help="particles across L = 1 m")
    ap.add_argument("--solver", type=json.loads, default=None, help='scene "solver" keys as JSON')
    ap.add_argument("--out", help="write the rows here (JSON)")
    args = ap.parse_args(argv)
    rows = budget(args.device, args.resolution, args.solver)
    for r in rows:
        print(f"t {r['t']:.3f} ({r['steps']} steps): dKE/KE0 {r['dKE_over_KE0']:+.4f} (analytic {r['analytic']:+.4f}) = "
              f"divergence {r['divergence_solve']:+.4f} + density {r['density_solve']:+.4f} + rest {r['rest_viscosity']:+.4f}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
