"""Stacked dynamic bodies (issue #39, "Bodies that move right"): boxes stacked in air rest on each other and on the
floor, and no two interpenetrate by more than a particle radius (CPU, r = 0.02 m, 0.2 m boxes of density 800,
a few fluid particles in a far corner: a scene needs fluid)."""

import numpy as np
import pytest

from conftest import SCENES_DIR, make_sim, tank_scene

pytestmark = pytest.mark.slow  # boxes settle on each other over seconds of simulated time

R = 0.02
SIDE = 0.2


def _surface_points(n=9):
    """An n x n grid on each face of the box (body space, about its centre)."""
    g = np.linspace(-SIDE / 2, SIDE / 2, n)
    a, b = (c.ravel() for c in np.meshgrid(g, g))
    faces = []
    for k in range(3):
        for s in (-SIDE / 2, SIDE / 2):
            p = np.zeros((a.size, 3))
            p[:, k], p[:, (k + 1) % 3], p[:, (k + 2) % 3] = s, a, b
            faces.append(p)
    return np.unique(np.concatenate(faces), axis=0)


POINTS = _surface_points()


def _depth(a, b):
    """How deep the deepest of box a's surface points lies inside box b [m]; 0: none inside."""
    local = (a.to_world(POINTS) - b.position) @ b.rotation
    return max(0.0, float((SIDE / 2 - np.abs(local)).min(axis=1).max()))


def _tilt(body):
    """Degrees between the box's y axis and the vertical."""
    return float(np.degrees(np.arccos(np.clip(body.rotation[1, 1], -1.0, 1.0))))


def _stack(count, gap, dynamics, offsets=None, until=1.5, device="cpu"):
    """``count`` boxes one above the other at x = 0.35 m (+ ``offsets``), the lowest on the floor, each next one
    ``gap`` above the last; run to ``until``. Returns the boxes (lowest first) and the deepest interpenetration of
    neighbours over the run [particle radii]."""
    offsets = offsets or [0.0] * count
    boxes = [{"mesh": "meshes/unit_box.obj", "scale": [SIDE] * 3, "name": f"box{i}",
              "translation": [0.35 + offsets[i], SIDE / 2 + i * (SIDE + gap), 0.2],
              "dynamics": {"density": 800.0, **dynamics}} for i in range(count)]
    data = tank_scene(radius=R, domain=(0.7, 1.0, 0.4), block=(0.08, 0.04, 0.08), obstacles=boxes, output={"fps": 10})
    sim = make_sim(data, device=device, base_dir=SCENES_DIR)
    named = {b.name: b for b in sim.moving_bodies.dynamic}
    stack = [named[f"box{i}"] for i in range(count)]
    deepest = 0.0
    while sim.time < until:
        sim.step()
        for low, high in zip(stack, stack[1:]):
            deepest = max(deepest, _depth(low, high), _depth(high, low))
    return stack, deepest / R


def _assert_at_rest(stack, offsets, height, speed, spin, tilt, drift):
    """Every box on the one under it (``height``: its centre within that many radii of SIDE / 2 + i SIDE), slower
    than ``speed`` [m/s] and ``spin`` [rad/s], tilted less than ``tilt`` [degrees], within ``drift`` [m] of where it
    was placed across."""
    for i, box in enumerate(stack):
        assert abs(box.position[1] - (SIDE / 2 + i * SIDE)) < height * R
        assert np.linalg.norm(box.velocity) < speed and np.linalg.norm(box.angular_velocity) < spin
        assert _tilt(box) < tilt
        assert np.hypot(box.position[0] - 0.35 - offsets[i], box.position[2] - 0.2) < drift


@pytest.mark.parametrize("count, friction, measured", [(2, None, 0.0002), (3, None, 0.085), (3, 0.5, 0.085)])
def test_stacked_boxes_rest_without_sinking_into_each_other(count, friction, measured, device):
    """The top box is dropped 3 cm onto the one under it (on the floor; three boxes: the middle one too). The contacts'
    impulses are solved together, walls and bodies, in Gauss-Seidel sweeps: solved once each, in turn, the box on top
    pushed the one under it back into the floor and nothing stopped it again, so a resting stack kept g dt (two boxes)
    and 3 g dt (three) of downward velocity, 0.039 and 0.118 m/s, in place only because the projections held it.
    Measured (CPU, Warp 1.19): deepest 0.0002 / 0.085 / 0.085 r over the run; at 1.5 s every centre within 0.038 r of
    its resting height, speeds below 2e-5 / 6e-5 / 4e-7 m/s, spins below 3e-6 rad/s, tilts below 0.014 degrees,
    moved across by at most 1.3e-4 m."""
    stack, deepest = _stack(count, 0.03, {"friction": friction}, device=device)
    assert deepest < max(1.5 * measured, 0.01) < 1.0  # never a particle radius into each other
    _assert_at_rest(stack, [0.0] * count, height=0.06, speed=1e-4, spin=1e-4, tilt=0.02, drift=2e-4)


def test_a_box_resting_off_centre_on_another_stays():
    """A box 5 cm off the centre of the one under it (its centre of mass 5 cm inside the edge), friction 0.5: a contact
    between bodies acts at the touching samples' corners, not at their depth-weighted centre (about which the top box
    turned: it fell off, 117 degrees over and still rolling at 1.5 s). Measured: 0.0009 r deep; at 1.5 s 0.04
    degrees, 8e-7 m/s, 4e-6 rad/s, moved across by 5.5e-4 m."""
    offsets = [0.0, 0.05]
    stack, deepest = _stack(2, 0.03, {"friction": 0.5}, offsets)
    assert deepest < 0.01
    _assert_at_rest(stack, offsets, height=0.06, speed=1e-4, spin=1e-4, tilt=0.06, drift=1e-3)


def test_a_box_off_the_edge_of_another_falls_off():
    """Its centre of mass 3 cm beyond the lower box's edge, the top box turns over the edge and falls to the floor.
    Measured: on its side on the floor (centre 0.1000 m up, 90.0 degrees over); the lower box pushed 2.0 mm along x."""
    low, high = _stack(2, 0.03, {"friction": 0.5}, [-0.1, 0.03])[0]
    assert abs(high.position[1] - SIDE / 2) < 0.06 * R and abs(_tilt(high) - 90.0) < 1.0
    assert abs(low.position[1] - SIDE / 2) < 0.06 * R and _tilt(low) < 0.1 and abs(low.position[0] - 0.25) < 0.003


@pytest.mark.parametrize("friction", [None, 0.5])
def test_a_box_dropped_on_its_edge_lies_flat_on_the_floor(friction):
    """A box at 30 degrees about z dropped 0.2 m onto the floor lands on an edge and turns flat: the wall's contact
    points are the vertices within a radius of the floor, each above it free to come down by its height in the step
    (with friction the upper edge, 1.6 cm up at 4.7 degrees, was held as if touching and the box stopped there;
    without, the contact acted at the centre of mass and the box stayed on its edge at 30 degrees). Measured: flat
    (to 1e-5 degrees) from 0.73 s (no friction coefficient: the spin halved every step) and 0.32 s (friction 0.5),
    lowest vertex 7e-9 m into the floor, at rest (3e-8 m/s)."""
    box = {"mesh": "meshes/unit_box.obj", "scale": [SIDE] * 3, "translation": [0.35, 0.3, 0.2], "name": "box",
           "rotation_axis": [0, 0, 1], "rotation_angle": np.pi / 6,
           "dynamics": {"density": 800.0, "friction": friction}}
    data = tank_scene(radius=R, domain=(0.7, 1.0, 0.4), block=(0.08, 0.04, 0.08), obstacles=[box], output={"fps": 10})
    sim = make_sim(data, base_dir=SCENES_DIR)
    body = sim.moving_bodies.dynamic[0]
    while sim.time < 1.5:
        sim.step()
    turned = np.degrees(np.arccos(np.clip(body.rotation[0, 0], -1.0, 1.0)))
    assert abs(turned - 30.0) < 0.01  # turned back by the placement's 30 degrees: flat
    assert abs(body.to_world(body.vertices)[:, 1].min()) < 0.001 * R
    assert np.linalg.norm(body.velocity) < 1e-4 and np.linalg.norm(body.angular_velocity) < 1e-3
