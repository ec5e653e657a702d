"""SPlisHSPlasH's motor joints (pysplishsplash 2.19.0 data/Scenes MotorScene.json and MotorScene2.json), imported
(#39): a TargetVelocityMotorHingeJoint between a dynamic body and a static one holds the body on the hinge and sets
its spin to the target every step (PositionBasedDynamics), so warpsph makes the body kinematic, spinning about the
hinge axis through the hinge position. The scenes are written here (CI has no SPlisHSPlasH) at r = 0.05 m; the
measured values below are pysplishsplash 2.19.0's own."""

import copy
import json

import numpy as np
import pytest

from warpsph import SceneError, load_scene
from warpsph.bodies import kinematic_pose
from warpsph.io.splishsplash import SplishSplashWarning, conversion_of
from warpsph.simulation import Simulation
from test_splishsplash import scenes, write  # noqa: F401 (scenes: the fixture)

MOTOR_SCENE = {
    "Configuration": {
        "particleRadius": 0.05, "numberOfStepsPerRenderUpdate": 4, "simulationMethod": 4, "gravitation": [0, -9.81, 0],
        "cflMethod": 1, "cflFactor": 1, "cflMaxTimeStepSize": 0.005, "boundaryHandlingMethod": 2,
        "DFSPH": {"minIterations": 2, "maxIterations": 100, "maxError": 0.05, "maxIterationsV": 100, "maxErrorV": 0.1,
                  "enableDivergenceSolver": True},
    },
    "Materials": [{"id": "Fluid", "density0": 1000, "colorMapType": 1, "viscosityMethod": 1,
                   "Standard viscosity": {"viscosity": 0.01}}],
    "RigidBodies": [
        {"id": 0, "geometryFile": "../models/UnitBox.obj", "translation": [0, 1, 0], "rotationAxis": [1, 0, 0],
         "rotationAngle": 0, "scale": [2, 2, 2], "color": [0.1, 0.4, 0.6, 1.0], "isDynamic": False, "isWall": True,
         "mapInvert": True, "mapThickness": 0.0, "mapResolution": [25, 25, 25]},
        {"id": 1, "geometryFile": "../models/UnitBox.obj", "translation": [0, 0.1, 0], "rotationAxis": [1, 0, 0],
         "rotationAngle": 0, "scale": [1, 0.1, 0.2], "color": [0.1, 0.4, 0.6, 1.0], "density": 10000,
         "isDynamic": True, "isWall": False, "mapInvert": False, "mapThickness": 0.0, "mapResolution": [20, 20, 20]},
    ],
    "TargetVelocityMotorHingeJoints": [{"bodyID1": 1, "bodyID2": 0, "position": [0, 0, 0], "axis": [0, 1, 0],
                                        "target": -6}],
    "FluidBlocks": [{"denseMode": 0, "start": [-0.5, -0.5, -0.5], "end": [0.5, 0.5, 0.5], "translation": [0.0, 0.6, 0.0],
                     "scale": [1, 0.75, 1]}],
}


def motor_scene_2():
    """MotorScene2.json: a longer paddle, its target a sequence of (time, target) pairs, repeated."""
    data = copy.deepcopy(MOTOR_SCENE)
    data["RigidBodies"][1]["scale"] = [1.5, 0.1, 0.2]
    joint = data["TargetVelocityMotorHingeJoints"][0]
    del joint["target"]
    joint.update({"repeatSequence": 1, "targetSequence": [0, -5, 1, 5, 2, -5]})
    return data


# pysplishsplash 2.19.0, MotorScene2.json at r = 0.05 m (CPU): the paddle's angular velocity (y) at the end of the
# step ending at t (dt 5 ms): the sequence's target at the end of the step before, negated (the target is bodyID2's
# spin less bodyID1's), linear between the pairs and repeated every 2 s. To 0.6 s from the file; past 2 s from a copy
# with bodyID1 and bodyID2 swapped (and little fluid), which spins at +target: its -3.04 and -1.04 rad/s negated.
SPLISHSPLASH_SPIN = ((0.101, 4.04), (0.301, 2.04), (0.501, 0.04), (0.601, -0.96), (2.201, 3.04), (2.401, 1.04))


def load(folder, data, name="MotorScene"):
    with pytest.warns(SplishSplashWarning):
        return load_scene(write(folder, data, name))


def test_motor_scene_gives_a_kinematic_paddle(scenes):
    scene = load(scenes, MOTOR_SCENE)
    (paddle,) = scene.obstacles
    assert paddle.dynamics is None and paddle.motion is not None
    m = paddle.motion
    assert m.axis == (0, 1, 0) and m.center == (0, 0, 0)
    assert m.angular_velocity == 6.0  # -target: PositionBasedDynamics drives omega(bodyID2) - omega(bodyID1)
    c = conversion_of(scene)
    assert c.refused == [] and any(line.startswith("TargetVelocityMotorHingeJoints[0]") and "obstacles[0].motion" in line
                                   for line in c.mapped)
    # the static body named second or first: the sign follows
    data = copy.deepcopy(MOTOR_SCENE)
    data["TargetVelocityMotorHingeJoints"][0].update({"bodyID1": 0, "bodyID2": 1})
    assert load(scenes, data).obstacles[0].motion.angular_velocity == -6.0


def test_the_paddle_corner_moves_on_the_circle_at_the_target_rate(scenes, device):
    scene = load(scenes, MOTOR_SCENE)
    sim = Simulation(scene, device=device)
    (paddle,) = [b for b in sim.bodies if b.kind == "kinematic"]
    corner = paddle.vertices[np.argmax(paddle.vertices @ [1.0, 1e-3, 1e-6])]  # body space: about the hinge
    assert corner + paddle.reference == pytest.approx([0.5, 0.15, 0.1])
    placed = []
    for _ in range(4):
        placed.append(sim.time)  # the samples stand at the pose of the step's start
        sim.step()
    assert sim.check_health() is None
    t = placed[-1]
    world = paddle.to_world(corner)
    angle = 6.0 * t
    expected = [0.5 * np.cos(angle) + 0.1 * np.sin(angle), 0.15, -0.5 * np.sin(angle) + 0.1 * np.cos(angle)]
    assert world == pytest.approx(expected, abs=1e-9) and t > 0.0
    # on the device: every sample of the paddle on its circle about the y axis, moving at omega x r
    first = sim.moving_bodies.first_sample
    x = sim.boundary.x.numpy()[first:first + len(paddle.samples)].astype(np.float64)
    v = sim.boundary.v.numpy()[:len(paddle.samples)].astype(np.float64)  # (the moving samples' velocities only)
    R = kinematic_pose(paddle.obstacle.motion, paddle.reference, t)[1]
    np.testing.assert_allclose(x, paddle.samples @ R.T + paddle.reference, atol=1e-5)
    np.testing.assert_allclose(v, np.cross([0.0, 6.0, 0.0], x - paddle.reference), atol=1e-4)


def test_motor_scene_2s_sequence_is_read_as_splishsplash_reads_it(scenes):
    """PositionBasedDynamics' TimeStepController interpolates the target linearly between the (time, target) pairs
    and, with repeatSequence, takes the time less the sequence's duration (2 s) while it exceeds it."""
    scene = load(scenes, motor_scene_2(), "MotorScene2")
    m = scene.obstacles[0].motion
    assert [(s.time, s.rate) for s in m.spin_rates] == [(0, 5), (1, -5), (2, 5)] and m.spin_repeat
    for t, rate in SPLISHSPLASH_SPIN:  # the rate at the step's start (a step late)
        assert kinematic_pose(m, np.zeros(3), t - 0.005)[3][1] == pytest.approx(rate, abs=1e-9)
    for t, angle, rate in ((0.5, 1.25, 0.0), (1.0, 0.0, -5.0), (1.5, -1.25, 0.0), (2.25, 0.9375, 2.5), (4.5, 1.25, 0.0)):
        _, R, _, w = kinematic_pose(m, np.zeros(3), t)
        assert w[1] == pytest.approx(rate) and np.arctan2(R[0, 2], R[0, 0]) == pytest.approx(angle)
    # an odd last value is dropped, and target wins over targetSequence, as SPlisHSPlasH reads them
    data = motor_scene_2()
    data["TargetVelocityMotorHingeJoints"][0]["targetSequence"] = [0, -5, 1, 5, 2]
    assert [s.time for s in load(scenes, data, "Odd").obstacles[0].motion.spin_rates] == [0, 1]
    data["TargetVelocityMotorHingeJoints"][0]["target"] = 3
    m = load(scenes, data, "Both").obstacles[0].motion
    assert m.spin_rates == () and m.angular_velocity == -3.0


def test_joints_warpsph_cannot_drive_are_refused_in_one_line_with_their_count(scenes):
    data = copy.deepcopy(MOTOR_SCENE)
    for n, x in ((2, -0.6), (3, 0.6)):  # two more free bodies, joined to each other
        data["RigidBodies"].append({"id": n, "geometryFile": "../models/UnitBox.obj", "translation": [x, 1.5, 0],
                                    "scale": [0.2, 0.2, 0.2], "density": 500, "isDynamic": True})
    data["TargetVelocityMotorHingeJoints"].append({"bodyID1": 2, "bodyID2": 3, "position": [0, 1.5, 0],
                                                   "axis": [1, 0, 0], "target": 1})
    data["HingeJoints"] = [{"bodyID1": 2, "bodyID2": 0, "position": [-0.6, 1.5, 0], "axis": [1, 0, 0]}] * 2
    path = scenes / "Joints.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SceneError, match="2 part") as info:
        load_scene(path)
    lines = [line for line in str(info.value).splitlines() if line.startswith("  - ")]  # one line a refused key
    assert lines == ["  - TargetVelocityMotorHingeJoints: 1 of 2 motor joints warpsph cannot drive ([1] joins two dynamic "
                     "bodies (RigidBodies[2] and [3])): warpsph turns a body only about a hinge against a static body, "
                     "the bodies would move freely",
                     "  - HingeJoints: 2 joints between rigid bodies (PositionBasedDynamics): warpsph has no joints, the "
                     "bodies would move freely"]
    # a motor on a body that another joint holds too is not the body's whole motion
    data["HingeJoints"] = [{"bodyID1": 1, "bodyID2": 0, "position": [0, 0, 0], "axis": [0, 1, 0]}]
    path.write_text(json.dumps(data))
    with pytest.raises(SceneError, match=r"2 of 2 motor joints .*\[0\] RigidBodies\[1\] is in 2 joints"):
        load_scene(path)


@pytest.mark.parametrize("change, why", [
    ({"bodyID2": 1}, "[0] joins RigidBodies[1] to itself"),
    ({"bodyID1": 7}, "[0] bodyID1 7 names no body"),
    ({"axis": [0, 0, 0]}, "[0] its axis is zero"),
    ({"target": None, "targetSequence": [0.5, -5, 1, 5]}, "[0] targetSequence starts at 0.5 s, not 0"),
    ({"target": None, "targetSequence": [0, -5, 0, 5]}, "[0] targetSequence times [0.0, 0.0] do not increase"),
    ({"target": None, "targetSequence": [0, -5], "repeatSequence": 1}, "[0] repeatSequence of a single (time, target) pair"),
])
def test_each_motor_warpsph_cannot_drive_says_why(scenes, change, why):
    data = copy.deepcopy(MOTOR_SCENE)
    joint = data["TargetVelocityMotorHingeJoints"][0]
    joint.update(change)
    if joint.get("target", 0) is None:
        del joint["target"]
    path = scenes / "Motor.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert f"TargetVelocityMotorHingeJoints: 1 of 1 motor joints warpsph cannot drive ({why}" in str(info.value)
