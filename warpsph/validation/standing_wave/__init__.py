"""A standing gravity wave in a closed tank: its frequency against linear theory and its amplitude decay
against the viscous rate 2 nu k^2.

    warpsph validate standing-wave --resolutions 16 24 32 --device cpu --json standing_wave.json

Set-up: a tank L long (x) and 2 h tall (y), walled in x and y (free-slip: Akinci walls without wall viscosity),
periodic in z and ``DEPTH`` spacings deep (quasi-2D), filled to depth h under gravity g along -y. The first
sloshing mode, k = pi / L, starts from a flat surface with the velocity of linear theory (Lamb 1932, section
228) at its zero crossing,

    u_x = -a w cosh(k y) / sinh(k h) sin(k x),   u_y = a w sinh(k y) / sinh(k h) cos(k x),
    w^2 = g k tanh(k h),

where a is the surface amplitude and y the height above the floor. The potential flow's dissipation, 2 mu e:e
over the volume, takes the mode's energy at 4 nu k^2 whatever the depth (the free-slip walls add no boundary
layer), so its amplitude decays as exp(-2 nu k^2 t) (Lamb 1932, section 348).

Measured: the mode's amplitude A(t) = sum_i v_i . m(x_i) / sum_i |m(x_i)|^2, m the velocity above at a w = 1, at
``SAMPLES_PER_PERIOD`` times a period; then the least-squares fit A = exp(-gamma t) (c1 cos w t + c2 sin w t)
over w and gamma. ``error_pct`` is the frequency error |w / w_theory - 1| in %; the decay rate's error
gamma / (2 nu k^2) - 1 is reported beside it (``decay_error_pct``).
"""

from __future__ import annotations

import numpy as np
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.simulation import Simulation

L = 1.0  # tank length [m]
H = 0.5  # water depth [m]
G = 9.81
NU = 0.01  # [m^2/s]: amplitude decay 2 nu k^2 = 0.197 / s, 0.40 over the run
AMPLITUDE = 0.01  # surface amplitude a [m]: k a = 0.031, linear
PERIODS = 4.0  # the run's length in periods of the linear theory
DEPTH = 6  # z depth in particle spacings (a periodic axis takes at least 3 support radii)
SAMPLES_PER_PERIOD = 24


def theory(nu=NU):
    """(k, w, gamma) of the first mode: wavenumber [1/m], angular frequency [1/s], amplitude decay rate [1/s]."""
    k = np.pi / L
    return k, float(np.sqrt(G * k * np.tanh(k * H))), 2.0 * nu * k * k


def mode(x):
    """The mode's velocity at a w = 1 at positions x (N x 3; y above the floor)."""
    k = np.pi / L
    s = np.sinh(k * H)
    return np.stack([-np.cosh(k * x[:, 1]) / s * np.sin(k * x[:, 0]), np.sinh(k * x[:, 1]) / s * np.cos(k * x[:, 0]),
                     np.zeros(len(x))], axis=1)


def build(resolution, device="cpu", nu=NU, models=(), overrides=None):
    """The tank at t = 0 with the mode's velocity (resolution: particles across L)."""
    d = L / resolution
    k, w, _ = theory(nu)
    data = {"name": "standing_wave", "particle_radius": d / 2, "gravity": [0, -G, 0],
            "domain": {"min": [0, 0, 0], "max": [L, 2 * H, DEPTH * d], "periodic": ["z"]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [L, H, DEPTH * d]}],
            "fluid": {"viscosity": nu}, "models": list(models),
            "output": {"fps": SAMPLES_PER_PERIOD * w / (2 * np.pi)}}
    sim = Simulation(scene_from_dict(with_overrides(data, overrides)), device=device)
    x = sim.fluid.x.numpy().astype(np.float64)
    sim.fluid.v.assign((AMPLITUDE * w * mode(x)).astype(np.float32))
    return sim


def amplitude(sim):
    """The mode's amplitude of the current velocities, in units of a w."""
    x = sim.fluid.x.numpy().astype(np.float64)
    v = sim.fluid.v.numpy().astype(np.float64)
    m = mode(x)
    return float((v * m).sum() / (m * m).sum()) / (AMPLITUDE * theory()[1])


def fit(t, A, w_guess):
    """(w, gamma) of A = exp(-gamma t) (c1 cos w t + c2 sin w t), least squares: a grid over w and gamma
    with c1, c2 solved for at each node, refined twice about the best node."""
    t, A = np.asarray(t), np.asarray(A)

    def residual(w, g):
        basis = np.exp(-g * t)[:, None] * np.stack([np.cos(w * t), np.sin(w * t)], axis=1)
        c, *_ = np.linalg.lstsq(basis, A, rcond=None)
        return float(((basis @ c - A) ** 2).sum())

    w_range, g_range = (0.7 * w_guess, 1.3 * w_guess), (-0.5, 2.0)
    for _ in range(3):
        ws, gs = np.linspace(*w_range, 61), np.linspace(*g_range, 61)
        r = np.array([[residual(w, g) for g in gs] for w in ws])
        i, j = np.unravel_index(np.argmin(r), r.shape)
        dw, dg = ws[1] - ws[0], gs[1] - gs[0]
        w_range, g_range = (ws[i] - 2 * dw, ws[i] + 2 * dw), (gs[j] - 2 * dg, gs[j] + 2 * dg)
    return float(ws[i]), float(gs[j])


def standing_wave(resolution, device="cpu", nu=NU, models=(), overrides=None, on_run=None):
    """Runs the wave; returns (times, amplitudes, the simulation, the fit's summary). ``on_run(sim, run)``
    wraps the run (``run(callback)``), e.g. to time it."""
    sim = build(resolution, device, nu, models, overrides)
    k, w, gamma = theory(nu)
    times, amps = [0.0], [amplitude(sim)]

    def record(s, frame):
        times.append(s.time)
        amps.append(amplitude(s))

    end = PERIODS * 2 * np.pi / w
    run = lambda callback: sim.run(until_time=end, on_frame=callback)  # noqa: E731
    if on_run is None:
        run(record)
    else:
        on_run(sim, run, record)
    w_fit, gamma_fit = fit(times, amps, w)
    summary = {"omega": w_fit, "omega_theory": w, "frequency_error_pct": 100.0 * (w_fit / w - 1.0),
               "decay_rate": gamma_fit, "decay_rate_theory": gamma, "decay_error_pct": 100.0 * (gamma_fit / gamma - 1.0),
               "amplitude_start": amps[0], "k": k, "nu": nu, "T": end}
    return np.array(times), np.array(amps), sim, summary
