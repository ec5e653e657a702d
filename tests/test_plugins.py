"""A model plug-in defined in this file alone: its parameters, registration, memory, fields, state and
kernel. Nothing else in warpsph names it, and a scene, the CLI, the USD cache, checkpoints, the memory
check and the schema all take it."""

import json
import typing

import numpy as np
import pytest
import warp as wp
from pxr import Usd, UsdGeom

from warpsph import SceneError, load_scene
from warpsph.cli import main
from warpsph.io.checkpoint import load_checkpoint, save_checkpoint
from warpsph.models import REGISTRY, Model, register
from warpsph.resources import estimate_bytes
from warpsph.scene import key, scene_json_schema, schema
from warpsph.simulation import Simulation
from conftest import tank_scene


@wp.kernel
def damp_velocity(v: wp.array(dtype=wp.vec3), rate: float, dt: wp.array(dtype=float), work: wp.array(dtype=float)):
    """v *= 1 - rate dt; work accumulates the specific kinetic energy taken out."""
    i = wp.tid()
    before = wp.dot(v[i], v[i])
    v[i] = v[i] * (1.0 - rate * dt[0])
    work[i] = work[i] + 0.5 * (before - wp.dot(v[i], v[i]))


@schema
class Damping:
    """A linear drag, for the plug-in test."""

    rate: float = key(2.0, doc="drag rate", unit="1/s", ge=0.0, le=50.0)
    label: typing.Optional[str] = key(None, doc="unused; a string parameter")


class DampingModel(Model):
    """v *= 1 - rate dt once per step; publishes the work done per particle."""

    Parameters = Damping
    bytes_per_particle = 4
    output_fields = {"damping_work": 4}
    flag_names = ("has_run",)

    def __init__(self, ctx, params):
        super().__init__(ctx, params)
        self.work = ctx.per_particle(self.name, float)
        self.has_run = 0

    def step(self, ctx):
        assert not hasattr(ctx, "pressure_solver") and not hasattr(ctx, "moving_bodies")  # the narrow context
        ctx.launch(damp_velocity, ctx.num_fluid, [ctx.fluid.v, self.params.rate, ctx.dt, self.work])
        self.has_run = 1

    def reorder(self, ctx, order):
        ctx.permute(self.work, order)

    def fields(self):
        return {"damping_work": self.work}

    def state(self):
        return {"damping_work": self.work}


@pytest.fixture
def damping():
    register("test_damping")(DampingModel)
    yield DampingModel
    del REGISTRY["test_damping"]


def write(tmp_path, models, name="scene.json", frames=4):
    data = tank_scene(radius=0.04, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), models=models,
                      output={"fps": 40, "frames": frames})
    data["solver"] = {"sort_interval": 2}
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_a_plugin_defined_in_a_test_file_runs_in_a_scene(tmp_path, damping, device):
    plain = Simulation(load_scene(write(tmp_path, [])), device=device).run(frames=4)
    scene = load_scene(write(tmp_path, [{"type": "test_damping", "rate": 8.0}], "damped.json"))
    assert type(scene.models[0]) is Damping and scene.models[0].rate == 8.0
    damped = Simulation(scene, device=device).run(frames=4)
    assert damped.launches["damp_velocity"] == damped.step_count
    assert damped.kinetic_energy() < 0.8 * plain.kinetic_energy()
    work = damped.active(damped.fields()["damping_work"]).numpy()
    assert work.min() >= 0.0 and work.sum() > 0.0
    # its memory: allocated as declared, and counted by the check before a run
    assert damped.allocations["test_damping"] == 4 * damped.capacity
    assert estimate_bytes(scene, 1000, 0) - estimate_bytes(load_scene(write(tmp_path, [])), 1000, 0) == 1000 * 4


def test_a_plugin_is_validated_and_in_the_schema(tmp_path, damping):
    with pytest.raises(SceneError, match=r"models\[0\]\.rate.*a number in \[0, 50\]"):
        load_scene(write(tmp_path, [{"type": "test_damping", "rate": 99}]))
    with pytest.raises(SceneError, match=r"models\[0\]\.rat.*did you mean 'rate'"):
        load_scene(write(tmp_path, [{"type": "test_damping", "rat": 1}]))
    with pytest.raises(SceneError, match=r"models\[0\]\.type.*did you mean 'test_damping'"):
        load_scene(write(tmp_path, [{"type": "test_dampin"}]))
    entries = {e["properties"]["type"]["const"]: e for e in scene_json_schema()["properties"]["models"]["items"]["oneOf"]}
    assert entries["test_damping"]["properties"]["rate"]["maximum"] == 50.0
    assert entries["test_damping"]["properties"]["rate"]["unit"] == "1/s"


def test_a_plugin_reaches_the_usd_cache_and_checkpoints(tmp_path, damping):
    path = write(tmp_path, [{"type": "test_damping", "rate": 4.0}])
    out = tmp_path / "damped.usdc"
    assert main(["run", str(path), "--device", "cpu", "--out", str(out), "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    api = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Fluid"))
    work = api.GetPrimvar("damping_work")
    assert str(work.GetTypeName()) == "float[]" and np.array(work.Get(4)).sum() > 0.0
    # a resumed run equals an uninterrupted one, the plug-in's array and flag included
    straight = Simulation(load_scene(path), device="cpu").run(frames=4)
    first = Simulation(load_scene(path), device="cpu").run(frames=2)
    save_checkpoint(first, tmp_path / "ckpt.h5")
    resumed = load_checkpoint(tmp_path / "ckpt.h5", device="cpu")
    assert resumed.turbulence_models[0].has_run == 1
    resumed.run(frames=4)
    assert np.array_equal(resumed.fluid.x.numpy(), straight.fluid.x.numpy())
    assert np.array_equal(resumed.turbulence_models[0].work.numpy(), straight.turbulence_models[0].work.numpy())
