"""Plane Poiseuille flow between two walls: the walls' friction (``fluid.boundary_viscosity``) against no slip.

    warpsph validate poiseuille --resolutions 10 20 --device cpu --json poiseuille.json

A channel W = 0.2 m wide between walls at y = 0 and y = W (the domain's faces, Akinci samples), periodic along x
and z, full of fluid (nu = 0.05 m^2/s) and driven by a uniform body force f along x (the scene's gravity). With no
slip at the walls the steady profile is u(y) = f / (2 nu) y (W - y), its mean f W^2 / (12 nu) (Poiseuille). After
T = 0.5 s (six diffusion times W^2 / (pi^2 nu)) the velocities of the last 0.1 s are fitted with a parabola of the
theory's curvature: where it meets zero are the fluid's no-slip planes, whose distance beyond the walls in particle
spacings is the slip (``slip_spacings``: 0 on the walls, > 0 outside them). A free fit's curvature over f / nu
(``curvature_ratio``) is nu over the viscosity the bulk flow feels. ``error_pct`` is |the slip| in spacings (not a
percentage: the row's ``error_units`` is "spacings"); ``mean_over_no_slip`` the mean speed over the no-slip mean.

The case runs with ``fluid.boundary_viscosity`` 2 nu: eq 4 against a wall sample reads the pair's velocity
difference, and a no-slip wall's ghost velocity is 2 v_w - v_f (Adami, Hu & Adams 2012), which doubles that
difference. With the same nu as the fluid's the flow slips by about half a spacing.
"""

from __future__ import annotations

import numpy as np

from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation

W = 0.2  # m, the channel's width (y)
NU = 0.05  # m^2/s
FORCE = 1.0  # m/s^2, the body force along x
T_END = 0.5  # s
AVERAGE = 0.1  # s: the last part of the run whose velocities are fitted
MIN_PERIOD = 0.12  # m: the periodic x and z lengths (at least 3 support radii at 10 across)
NO_SLIP = 2.0  # fluid.boundary_viscosity over fluid.viscosity that holds the fluid at the samples (this case)


def no_slip_mean(nu=NU, force=FORCE):
    """The mean speed of the no-slip profile f W^2 / (12 nu) [m/s]."""
    return force * W * W / (12.0 * nu)


def fit_profile(y, u, nu=NU, force=FORCE):
    """(y0, y1, curvature ratio) of speeds ``u`` at heights ``y``: the zeros of the parabola u = f / (2 nu) (y - y0)
    (y1 - y) fitted by least squares with its curvature fixed, and a free quadratic's curvature over f / nu."""
    a = force / (2.0 * nu)
    (b, c), *_ = np.linalg.lstsq(np.stack([y, np.ones_like(y)], 1), u + a * y * y, rcond=None)
    root = np.sqrt(b * b + 4.0 * a * c)
    free = np.linalg.lstsq(np.stack([y * y, y, np.ones_like(y)], 1), u, rcond=None)[0]
    return (b - root) / (2.0 * a), (b + root) / (2.0 * a), float(-free[0] / a)


def poiseuille(resolution, device="cpu", T=T_END, models=(), overrides=None, on_run=None):
    """Runs the channel (``resolution`` particles across W) to ``T``; returns its measurements.
    ``on_run(sim, run)``: called with the simulation and a function that runs it (for timing)."""
    radius = W / (2 * resolution)
    period = max(MIN_PERIOD, 12 * radius)
    data = {"name": "poiseuille", "particle_radius": radius, "gravity": [FORCE, 0.0, 0.0],
            "domain": {"min": [0, 0, 0], "max": [period, W, period], "periodic": ["x", "z"]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [period, W, period]}],
            "fluid": {"viscosity": NU, "boundary_viscosity": NO_SLIP * NU}, "models": list(models)}
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    heights, speeds = [], []

    def run():
        while sim.time < T:
            sim.step()
            if sim.time > T - AVERAGE:
                heights.append(sim.positions()[:, 1].astype(np.float64))
                speeds.append(sim.velocities()[:, 0].astype(np.float64))

    if on_run is not None:
        on_run(sim, run)
    else:
        run()
    nu, force = sim.scene.fluid.viscosity, sim.scene.gravity[0]
    y, u = np.concatenate(heights), np.concatenate(speeds)
    y0, y1, curvature = fit_profile(y, u, nu, force)
    slip = float((y1 - W) - y0) / (2 * 2 * radius)  # the two walls' mean, in spacings 2r
    mean = float(u.mean()) / no_slip_mean(nu, force)
    return {"particles": sim.num_fluid, "steps": sim.step_count, "mean_over_no_slip": mean,
            "error_pct": abs(slip), "slip_spacings": slip,
            "no_slip_planes_m": [float(y0), float(y1)], "curvature_ratio": curvature,
            "boundary_viscosity": sim.scene.fluid.boundary_viscosity, "sim": sim}
