"""A sphere sinking in a viscous fluid: its terminal speed against Stokes drag with the walls' correction.

    warpsph validate sinking-sphere --resolutions 5 10 --device cuda --json sinking.json

A dynamic sphere of diameter D = 0.1 m and density ``SPHERE_DENSITY`` starts at rest on the axis of a square tank
(side ``SIDE`` = 6 D, water to ``FILL`` = 9 D) and sinks. The fluid is the default one (eq 4, nu = 0.05 m^2/s,
so the Reynolds number stays below 1) with twice that viscosity against the samples of the sphere and the
tank (``fluid.boundary_viscosity`` 2 nu: no slip, as the reference assumes; the ``poiseuille`` case holds a channel's
flow at its walls with it, where the same nu slips by about half a spacing). Stokes drag 6 pi mu R v (1 + 3 Re / 16, Oseen) balances
the sphere's weight less its buoyancy in an unbounded fluid; on the axis of a tube of diameter W the walls slow
it by Haberman & Sayre's factor K(D / W) (1958). The tank is square, so W lies between its side (the inscribed
tube, the lower bound) and 1.128 times it (the tube of the same area). The case reports the measured terminal
speed (the mean sinking speed while the sphere's centre is between ``WINDOW`` of the water depth, well away
from the surface and the floor) against that band; ``error_pct`` is its distance from the band's middle in %.
"""

import json
import math
from importlib import resources
from pathlib import Path

import numpy as np
from warpsph.scene import scene_from_dict, with_overrides
from warpsph.validation.poiseuille import NO_SLIP
from warpsph.simulation import Simulation

D = 0.1  # m, the sphere's diameter
SIDE = 6 * D  # m
FILL = 9 * D  # m, water depth
TANK_HEIGHT = 10 * D  # m
START = 6 * D  # m, the sphere's centre at rest (3 D below the surface)
WINDOW = (0.55, 0.35)  # of the water depth: the centre's span over which the speed is averaged
SPHERE_DENSITY = 3000.0  # kg/m^3
T_END = 2.5  # s
G = 9.81
EQUAL_AREA = 2.0 / math.sqrt(math.pi)  # the diameter of the tube with the square's area, in sides
SCENES = Path(__file__).resolve().parents[3] / "scenes"  # meshes/unit_sphere.obj
# Haberman & Sayre's wall factor, a rational function of D / W: its coefficients beside this module (reference.json)
REFERENCE = json.loads(resources.files(__name__).joinpath("reference.json").read_text(encoding="utf-8"))
WALL_FACTOR = REFERENCE["wall_factor"]


def wall_factor(ratio):
    """Haberman & Sayre (1958): the terminal speed of a sphere on the axis of a tube, over the unbounded one, for
    sphere diameter / tube diameter ``ratio`` (< 0.6)."""
    def series(coefficients):  # {power: coefficient} in rising powers
        return sum(c * ratio ** int(n) for n, c in sorted(coefficients.items(), key=lambda item: int(item[0])))

    return series(WALL_FACTOR["numerator"]) / series(WALL_FACTOR["denominator"])


def stokes_speed(volume, density, rho0, nu):
    """The unbounded terminal speed of a sphere of ``volume`` with Oseen's correction, F = 6 pi mu R v (1 + 3 Re / 16),
    Re = v 2R / nu, solved for v; and Re."""
    radius = (3 * volume / (4 * math.pi)) ** (1 / 3)
    weight = (density - rho0) * volume * G
    mu = rho0 * nu
    stokes = weight / (6 * math.pi * mu * radius)
    # v (1 + 3 v R / (8 nu)) = stokes: the positive root
    a = 3 * radius / (8 * nu)
    v = (-1 + math.sqrt(1 + 4 * a * stokes)) / (2 * a)
    return v, v * 2 * radius / nu


def sinking_sphere(resolution, device="cpu", T=T_END, density=SPHERE_DENSITY, models=(), overrides=None,
                   on_run=None):
    """Runs one sphere (``resolution`` particles across its diameter) to ``T`` or until it has crossed the
    window; returns the measurements. ``on_run(sim, run)``: called with the simulation and a function that
    runs it (for timing)."""
    radius = D / (2 * resolution)
    centre = SIDE / 2
    sphere = {"mesh": "meshes/unit_sphere.obj", "scale": [D, D, D], "translation": [centre, START, centre],
              "name": "sphere", "dynamics": {"density": density}}
    data = {"name": "sinking_sphere", "particle_radius": radius,
            "domain": {"min": [0, 0, 0], "max": [SIDE, TANK_HEIGHT, SIDE]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [SIDE, FILL, SIDE]}], "obstacles": [sphere],
            "models": list(models)}
    data = with_overrides(data, overrides)
    fluid = data.setdefault("fluid", {})
    fluid.setdefault("boundary_viscosity", NO_SLIP * fluid.get("viscosity", 0.05))
    sim = Simulation(scene_from_dict(data, base_dir=SCENES), device=device)
    body = sim.moving_bodies.dynamic[0]
    top, bottom = WINDOW[0] * FILL, WINDOW[1] * FILL
    track = []  # (time, centre height) inside the window

    def run():
        while sim.time < T and body.position[1] > bottom:
            sim.step()
            if bottom <= body.position[1] <= top:
                track.append((sim.time, float(body.position[1])))

    if on_run is not None:
        on_run(sim, run)
    else:
        run()
    scene = sim.scene
    nu, rho0 = scene.fluid.viscosity, scene.fluid.density
    volume = body.mass / density
    unbounded, reynolds = stokes_speed(volume, density, rho0, nu)
    ratio = 2 * (3 * volume / (4 * math.pi)) ** (1 / 3) / SIDE
    band = (unbounded * wall_factor(ratio), unbounded * wall_factor(ratio / EQUAL_AREA))
    t = np.array([p[0] for p in track])
    y = np.array([p[1] for p in track])
    crossed = len(t) > 2 and y[-1] <= bottom + 0.1 * (top - bottom)
    speed = float(-np.polyfit(t, y, 1)[0]) if len(t) > 2 else float("nan")
    middle = 0.5 * (band[0] + band[1])
    return {"particles": sim.num_fluid, "steps": sim.step_count, "sphere_radius_m": 0.5 * D,
            "terminal_speed": speed, "crossed_window": bool(crossed),
            "reference_band": list(band), "reference_unbounded": unbounded, "reynolds": reynolds,
            "speed_over_reference": speed / middle, "in_band": bool(band[0] <= speed <= band[1]),
            "error_pct": 100.0 * abs(speed / middle - 1.0), "sim": sim}
