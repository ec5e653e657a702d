"""Inflow emitters and outflow sinks: the particle count changes, ids stay unique, USD follows."""

import json

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from conftest import make_sim
from warpsph.cli import main
from warpsph.errors import SceneError


def channel(sinks=True, fps=20, frames=10, **emitter):
    e = {"min": [0, 0, 0], "max": [0.04, 0.2, 0.2], "velocity": [1.0, 0, 0]}
    e.update(emitter)
    data = {"name": "channel", "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [1.0, 0.4, 0.2]},
            "emitters": [e], "output": {"fps": fps, "frames": frames}}
    if sinks:
        data["sinks"] = [{"min": [0.85, 0, 0], "max": [1.0, 0.4, 0.2]}]
    return data


def test_emitter_adds_a_layer_each_time_the_last_moved_a_spacing():
    sim = make_sim(channel(sinks=False))
    layer = 5 * 5  # the 0.2 x 0.2 m cross-section at a 0.04 m spacing
    assert sim.num_fluid == layer  # the layer due at t = 0
    counts = []
    sim.run(frames=10, on_frame=lambda s, f: counts.append((s.time, s.num_fluid)))
    for t, n in counts:  # 625 particles a second at 1 m/s; a layer due during the last step comes with the next
        due = int(np.floor(t * 1.0 / 0.04 + 1e-6)) + 1
        assert n in (layer * due, layer * (due - 1))
    assert counts[-1][1] >= 25 * 13
    ids = sim.host(sim.fluid.ids)
    assert np.array_equal(np.sort(ids), np.arange(sim.num_fluid))  # new ids, none reused
    x = sim.host(sim.fluid.x)
    assert x[:, 0].max() > 0.3 and np.isfinite(x).all()  # the jet advanced into the channel


@pytest.mark.slow
def test_sink_removes_what_enters_it_and_ids_are_never_reused():
    sim = make_sim(channel(frames=20))
    seen = set()
    history = []

    def on_frame(s, frame):
        ids = s.host(s.fluid.ids)
        assert len(np.unique(ids)) == len(ids)
        history.append((s.num_fluid, s.inflow.next_id))
        seen.update(ids.tolist())

    sim.run(frames=20, on_frame=on_frame)
    n, emitted = history[-1]
    assert emitted in (25 * 25, 25 * 26) and n < emitted - 200  # the sink took hundreds out
    x = sim.host(sim.fluid.x)
    # after the step's drain only particles that moved in during the step can be past the sink's face
    assert (x[:, 0] > 0.85 + 0.1).sum() == 0
    assert max(seen) == emitted - 1
    # state follows the compaction: each particle keeps its own velocity (no stale rows in the active part)
    assert np.isfinite(sim.host(sim.fluid.v)).all() and np.abs(sim.host(sim.fluid.v)).max() < 10.0


def test_count_changes_survive_a_snapshot():
    sim = make_sim(channel())
    sim.run(frames=8)
    snapshot = sim._snapshot()
    n, next_id = sim.num_fluid, sim.inflow.next_id
    sim.run(frames=12)
    assert (sim.num_fluid, sim.inflow.next_id) != (n, next_id)
    sim._restore(snapshot)
    assert (sim.num_fluid, sim.inflow.next_id) == (n, next_id)


def test_usd_cache_holds_a_changing_particle_count(tmp_path):
    scene = tmp_path / "channel.json"
    scene.write_text(json.dumps(channel(frames=12)))
    out = tmp_path / "channel.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out)]) == 0
    stage = Usd.Stage.Open(str(out))
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid"))
    counts = [len(points.GetPointsAttr().Get(f)) for f in range(13)]
    assert counts[0] == 25 and counts[6] > counts[1]
    for f in (3, 12):
        ids = np.array(points.GetIdsAttr().Get(f))
        assert len(ids) == counts[f] == len(points.GetVelocitiesAttr().Get(f)) and len(np.unique(ids)) == len(ids)


@pytest.mark.parametrize("change, key, words", [
    ({"velocity": [1.0, 0.5, 0]}, "emitters[0].velocity", "along one axis"),
    ({"max": [0.04, 0.01, 0.2]}, "emitters[0]", "cross-section holds no particle"),
    ({"start": 1.0, "end": 0.5}, "emitters[0].end", "after start"),
])
def test_bad_emitters_name_the_key(change, key, words):
    with pytest.raises(SceneError) as err:
        make_sim(channel(**change))
    assert key in str(err.value) and words in str(err.value)


def _jet(models):
    """A 1 m/s jet emitted between two still slabs, no gravity: the particles at the jet's sides are born
    into a shear layer, with vorticity of about 1 / spacing. The step is fixed at the viscous limit (4 ms): the adaptive
    step dips by ~17 % on an emission step (the new layer's close pairs raise the viscous rate), and Rankine's core,
    sqrt(4 1.25643 nu dt), shrinks with it, which by itself doubles its correction on that step (0.0034 against
    0.0014 m/s): not what these tests measure."""
    return {"name": "jet", "particle_radius": 0.02, "gravity": [0, 0, 0], "time": {"fixed_dt": 0.004},
            "domain": {"min": [0, 0, 0], "max": [1.0, 0.4, 0.2]},
            "fluid_blocks": [{"start": [0, 0, 0], "end": [1.0, 0.12, 0.2]}, {"start": [0, 0.28, 0], "end": [1.0, 0.4, 0.2]}],
            "emitters": [{"min": [0, 0.12, 0], "max": [0.04, 0.28, 0.2], "velocity": [1.0, 0, 0]}],
            "output": {"fps": 20, "frames": 4}, "models": models}


def _first_step_corrections(spec, steps=60, history_for_new=True):
    """Mean |dv| of the model's own correction over the steps in which a layer was emitted, for the new
    layer and for the layer emitted before it, and that older layer's mean |dv| on the steps before."""
    sim = make_sim(_jet([spec]))
    model = sim.models[-1]
    if not history_for_new:  # what emitted particles got before: zeroed state taken for history
        model.emitted = lambda *args: None
    step, seen = model.step, {}

    def recording(s):
        v0 = s.host(s.fluid.v).astype(np.float64)
        step(s)
        seen["dv"] = np.linalg.norm(s.host(s.fluid.v) - v0, axis=1)
        seen["ids"] = s.host(s.fluid.ids)

    model.step = recording
    new, older, calm, last = [], [], [], None
    for n in range(steps):
        before = sim.inflow.next_id
        sim.step()
        ids, dv = seen["ids"], seen["dv"]
        k = sim.inflow.next_id - before
        if k and n > 20 and last is not None:
            new.append(dv[ids >= before].mean())
            older.append(dv[(ids >= before - k) & (ids < before)].mean())
            calm.append(last)
        last = dv[(ids >= sim.inflow.next_id - 20) & (ids < sim.inflow.next_id)].mean()
    return np.mean(new), np.mean(older), np.mean(calm)


@pytest.mark.parametrize("spec", [{"type": "rankine", "beta": 1.0}, {"type": "vorticity_refinement", "alpha": 1.0}])
def test_emitted_particles_first_model_correction_is_no_outlier(spec):
    """An emitted particle has no model history (VR's target, Rankine's omega^{n-1}); its zeroed state was
    taken for one, so its first step fed back its whole vorticity (Rankine) or removed it (VR). Now its
    first correction is skipped (``Model.emitted``): on an emission step the new layer and the layer
    before it are corrected about as much as that layer was on the steps before. Measured (emissions in
    steps 21-60): Rankine new / older / calm 0.0016 / 0.0017 / 0.0024 m/s (0.0051 / 0.0071 / 0.0024 with
    zeroed history); VR 0.0026 / 0.0044 / 0.0033 (0.0043 / 0.0061 / 0.0032)."""
    new, older, calm = _first_step_corrections(spec)
    assert new < 1.2 * calm and older < 1.6 * calm, (new, older, calm)
