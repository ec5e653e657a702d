"""Compiling the kernels before the first step (#43): a Simulation compiles exactly the Warp modules its scene
launches in one parallel pass before its set-up launches anything (none of an absent feature's), nothing loads
lazily after it, the results are the same; ``warpsph warmup`` compiles them into Warp's kernel cache and reports."""

import json
import os
import subprocess
import sys
import textwrap
import uuid

import numpy as np
import pytest
import warp as wp

from conftest import SCENES_DIR, make_sim, tank_scene
from warpsph import load_scene, scene_from_dict, warmup
from warpsph.cli import main
from warpsph.models import Model
from warpsph.simulation import Simulation

K = "warpsph.kernels."
CORE = {K + n for n in ("neighbours", "density", "pressure", "integration", "stability", "boundary", "free_surface",
                        "density_solver", "divergence_solver", "shifting", "viscosity")}
FEATURES = {K + n for n in ("bodies", "inflow", "iisph", "micropolar", "rankine", "vorticity_refinement",
                            "vorticity", "decomposition", "diagnostics")}


def channel(**extra):
    """An emitter and a sink in a small channel (tests/test_inflow.py's)."""
    return {"name": "channel", "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [1.0, 0.4, 0.2]},
            "emitters": [{"min": [0, 0, 0], "max": [0.04, 0.2, 0.2], "velocity": [1.0, 0, 0]}],
            "sinks": [{"min": [0.85, 0, 0], "max": [1.0, 0.4, 0.2]}], **extra}


def test_scene_modules_name_each_feature_only_when_the_scene_has_it():
    dam = load_scene(os.path.join(SCENES_DIR, "dam_break.json"), scale=0.1)
    assert set(warmup.scene_modules(dam)) == CORE
    assert set(warmup.scene_modules(dam, frames=True)) == CORE | {K + "diagnostics", K + "vorticity"}
    assert set(warmup.scene_modules(dam, decomposed=True)) == CORE | {K + "decomposition"}
    tank = tank_scene(radius=0.05)
    micropolar = set(warmup.scene_modules(scene_from_dict({**tank, "models": [{"type": "micropolar"}]})))
    assert micropolar == CORE | {K + "micropolar"}  # the viscosity pass fills the shared vorticity
    inviscid = set(warmup.scene_modules(scene_from_dict({**tank, "fluid": {"viscosity": 0.0},
                                                         "models": [{"type": "vorticity_refinement"}]})))
    assert inviscid == CORE - {K + "viscosity"} | {K + "vorticity_refinement", K + "vorticity"}
    iisph = set(warmup.scene_modules(scene_from_dict({**tank, "solver": {"method": "iisph"}})))
    assert iisph == CORE - {K + n for n in ("free_surface", "density_solver", "divergence_solver", "shifting")} | {K + "iisph"}
    assert K + "inflow" in warmup.scene_modules(scene_from_dict(channel()))
    assert K + "bodies" in warmup.scene_modules(load_scene(os.path.join(SCENES_DIR, "propeller.json"), scale=0.01))


def test_plugin_modules_are_named_or_those_of_its_kernels():
    from warpsph.models.micropolar import MicropolarModel

    assert warmup.plugin_modules(MicropolarModel) == [K + "micropolar"]
    named = type("Named", (Model,), {"kernel_modules": ("somewhere.kernels",)})
    assert warmup.plugin_modules(named) == ["somewhere.kernels"]


CASES = {
    "dam break": lambda: load_scene(os.path.join(SCENES_DIR, "dam_break.json"), scale=0.05),
    "kinematic body, VR": lambda: load_scene(os.path.join(SCENES_DIR, "propeller.json"), scale=0.004),
    "emitter and sink": lambda: scene_from_dict(channel()),
    "IISPH with micropolar": lambda: scene_from_dict(tank_scene(radius=0.05, solver={"method": "iisph"},
                                                                models=[{"type": "micropolar"}])),
    "Rankine, no viscosity": lambda: scene_from_dict(tank_scene(radius=0.05, fluid={"viscosity": 0.0},
                                                                models=[{"type": "rankine"}])),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_preload_is_exactly_what_the_set_up_and_the_steps_launch(case, monkeypatch):
    """In this process modules may be loaded already: what counts is the list the preload gets, before any launch,
    against the modules of every kernel launched in the set-up and 20 steps."""
    preloaded, launched = [], set()
    preload, launch = warmup.preload, wp.launch

    def spy_preload(names, device=None, max_workers=None):
        assert not launched, "something was launched before the preload"
        preloaded.append(list(names))
        return preload(names, device, max_workers)

    monkeypatch.setattr(warmup, "preload", spy_preload)
    monkeypatch.setattr(wp, "launch", lambda kernel, *a, **k: (launched.add(kernel.module.name), launch(kernel, *a, **k)))
    sim = Simulation(CASES[case](), device="cpu")
    for _ in range(20):
        sim.step()
    assert len(preloaded) == 1
    assert set(preloaded[0]) == launched
    assert not set(preloaded[0]) & {K + "diagnostics", K + "decomposition"}


def test_warpsph_run_preloads_its_frame_diagnostics_too(tmp_path, monkeypatch):
    preloaded, launched = [], set()
    preload, launch = warmup.preload, wp.launch
    monkeypatch.setattr(warmup, "preload", lambda names, *a, **k: (preloaded.append(list(names)), preload(names, *a, **k))[1])
    monkeypatch.setattr(wp, "launch", lambda kernel, *a, **k: (launched.add(kernel.module.name), launch(kernel, *a, **k)))
    scene = tmp_path / "tank.json"
    scene.write_text(json.dumps(tank_scene(radius=0.05, output={"fps": 25, "frames": 2})))
    assert main(["run", str(scene), "--device", "cpu", "--out", str(tmp_path / "tank.usdc"), "--quiet"]) == 0
    assert len(preloaded) == 1 and set(preloaded[0]) == launched == CORE | {K + "diagnostics", K + "vorticity"}


def test_no_preload_when_turned_off(monkeypatch):
    calls = []
    monkeypatch.setattr(warmup, "preload", lambda *a, **k: calls.append(a))
    make_sim(tank_scene(radius=0.05), preload=False)
    monkeypatch.setenv("WARPSPH_PRELOAD", "0")
    make_sim(tank_scene(radius=0.05))
    assert calls == []
    make_sim(tank_scene(radius=0.05), preload=True)
    assert len(calls) == 1


def test_the_preload_changes_no_result():
    runs = []
    for preload in (True, False):
        sim = make_sim(tank_scene(radius=0.04, models=[{"type": "vorticity_refinement"}]), preload=preload)
        for _ in range(10):
            sim.step()
        runs.append((sim.positions(), sim.velocities(), sim.time))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert runs[0][2] == runs[1][2]


SCRIPT = textwrap.dedent("""
    import json, sys
    import warp as wp
    from warpsph import load_scene, warmup
    from warpsph.simulation import Simulation

    loaded = lambda: sorted(m.name for m in wp._src.context.user_modules.values() if m.execs)
    scene = load_scene(sys.argv[1], scale=0.05)
    before = loaded()
    sim = Simulation(scene, device="cpu")
    after_set_up = loaded()
    for _ in range(5):
        sim.step()
    print(json.dumps({"before": before, "after_set_up": after_set_up, "after_steps": loaded(),
                      "expected": sorted(warmup.scene_modules(scene))}))
""")


@pytest.mark.slow
def test_a_fresh_process_loads_the_scene_modules_before_the_first_step_and_none_after():
    """A fresh process (Warp's kernel cache as the other tests leave it): a dam break's modules are loaded when the
    Simulation is set up (pressure and the solves too, which a lazy load reaches only in the first step),
    nothing loads after, and the modules of the features it lacks never load."""
    out = subprocess.run([sys.executable, "-c", SCRIPT, os.path.join(SCENES_DIR, "dam_break.json")],
                         capture_output=True, text=True, timeout=600, env={**os.environ, "WARPSPH_PRELOAD": "1"})
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["before"] == []
    assert r["after_set_up"] == r["expected"] == sorted(CORE)
    assert r["after_steps"] == r["after_set_up"]
    assert not set(r["after_steps"]) & FEATURES  # no micropolar, bodies, inflow, IISPH ... module


@pytest.mark.slow
def test_preload_reports_what_it_compiled(tmp_path, monkeypatch):
    """A module never compiled before (a kernel of its own, unique to this run) is compiled, then loaded."""
    name = f"warmup_probe_{uuid.uuid4().hex[:8]}"
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(f"""
        import warp as wp

        @wp.kernel
        def probe(a: wp.array(dtype=float)):
            a[wp.tid()] = float({uuid.uuid4().int % 1000})
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    first = warmup.preload([name], "cpu", max_workers=2)
    again = warmup.preload([name], "cpu")
    assert [(m.name, m.compiled) for m in first] == [(name, True)]
    assert [(m.name, m.compiled) for m in again] == [(name, False)]
    assert first[0].seconds > 0.0


@pytest.mark.parametrize("busy, threads", [(0.0, 8), (2.4, 6), (7.6, 1), (30.0, 1)])
def test_threads_are_the_idle_cores(monkeypatch, busy, threads):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    monkeypatch.setattr(warmup, "busy_cores", lambda: busy)
    assert warmup.idle_cores() == threads


def test_busy_cores_is_a_count():
    assert 0.0 <= warmup.busy_cores() < 10000


def test_warmup_verb_compiles_the_scene_modules_and_reports(capsys):
    assert main(["warmup", "--device", "cpu", "--scene", os.path.join(SCENES_DIR, "dam_break.json"),
                 "--workers", "2"]) == 0
    out = capsys.readouterr().out
    listed = {line.split()[0] for line in out.splitlines() if line.startswith("  ")}
    assert listed == CORE | {K + "diagnostics", K + "vorticity"}  # what warpsph run launches, no other
    last = out.splitlines()[-1]
    assert "of 13 modules compiled on cpu in" in last and "(2 threads)" in last
    assert f"kernel cache {wp.config.kernel_cache_dir}" in last


def test_warmup_verb_default_is_every_kernel_module():
    names = warmup.all_modules()
    assert CORE | FEATURES <= set(names) and K + "surface_preview" in names
    assert names[-1].startswith("warp.") and names[-1].endswith("sparse_marching_cubes")  # Warp's, for the preview
    assert K + "particles" not in names and K + "sph_kernel" not in names  # functions and structs only


@pytest.mark.parametrize("args, where, why", [
    (["--scene", "no_such_scene.json"], "no_such_scene.json", "cannot read the scene file"),
    (["--scene", "{bad}"], "bad.json: fluid.density", "expected a number > 0"),
    (["--workers", "0"], "--workers", "expected an integer >= 1"),
    (["--device", "tpu"], "--device", "unknown device 'tpu'"),
])
def test_warmup_verb_errors_name_the_file_or_option(tmp_path, capsys, monkeypatch, args, where, why):
    compiled = []
    monkeypatch.setattr(warmup, "preload", lambda *a, **k: compiled.append(a))
    if "{bad}" in args:
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(tank_scene(fluid={"density": -1.0})))
        args = [str(bad) if a == "{bad}" else a for a in args]
    assert main(["warmup", "--device", "cpu", *args] if "--device" not in args else ["warmup", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("warpsph: error: ") and where in err and why in err, err
    assert compiled == []  # refused before compiling anything


def _warmup_in(cache, *args):
    """``warpsph warmup ARGS`` in a process of its own whose kernel cache is the folder ``cache``, compiling: without
    warpsph's precompiled kernels (``WARPSPH_PRECOMPILED=0``; tests/test_precompiled.py has them)."""
    env = {**os.environ, "WARP_CACHE_PATH": str(cache), "WARPSPH_PRECOMPILED": "0"}
    return subprocess.run([sys.executable, "-m", "warpsph", "warmup", *args], env=env, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.slow
def test_warmup_compiles_for_a_gpu_architecture_without_a_gpu(tmp_path):
    """``--arch 90`` fills the kernel cache for H100/H200 on any machine (Warp's NVRTC): every module the dam
    break launches as CUBIN and as PTX for sm_90, the forms Warp loads there; a second call finds them."""
    scene = os.path.join(SCENES_DIR, "dam_break.json")
    first = _warmup_in(tmp_path, "--arch", "90", "--scene", scene, "--workers", "2")
    assert first.returncode == 0, first.stderr
    assert "13 of 13 modules compiled for sm_90" in first.stdout.splitlines()[-1]
    root = tmp_path / wp.__version__
    for name in CORE | {K + "diagnostics", K + "vorticity"}:
        (folder,) = warmup.cache_folders(name, root)
        assert sorted(p.name.split(".")[-2:] for p in folder.iterdir() if p.suffix in (".cubin", ".ptx")) == \
            [["sm90", "cubin"], ["sm90", "ptx"]], name
    again = _warmup_in(tmp_path, "--arch", "90", "--scene", scene)
    assert again.returncode == 0 and "0 of 13 modules compiled" in again.stdout.splitlines()[-1]
    bad = _warmup_in(tmp_path, "--arch", "72")
    assert bad.returncode == 2 and "--arch" in bad.stderr and "sm_72" in bad.stderr


@pytest.mark.slow
@pytest.mark.skipif(not wp.is_cuda_available(), reason="needs a CUDA device: the run that loads what --arch compiled")
def test_a_run_on_the_gpu_loads_what_warmup_compiled_for_its_architecture(tmp_path):
    """What ``--arch`` compiled on the CPU side is what a run on this GPU loads: after it, the run's own pass over
    the same modules compiles nothing."""
    arch = wp.get_device("cuda:0").arch
    scene = os.path.join(SCENES_DIR, "dam_break.json")
    assert _warmup_in(tmp_path, "--arch", str(arch), "--scene", scene).returncode == 0
    on_device = _warmup_in(tmp_path, "--device", "cuda:0", "--scene", scene)
    assert on_device.returncode == 0 and "0 of 13 modules compiled on cuda:0" in on_device.stdout.splitlines()[-1]
