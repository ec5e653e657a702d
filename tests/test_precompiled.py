"""warpsph's precompiled CUDA kernels (#43, warpsph/precompiled/): the shipped set is current for the source (the
default scene's modules for sm_90 as CUBIN and PTX, and every module built), what is copied into Warp's kernel cache is
what Warp looks up and loads without compiling, and nothing is copied for a module built from another source, for
another Warp, for a file that is not the one built, on the CPU, or with WARPSPH_PRECOMPILED=0. On the CPU: Warp
computes a module's hash and the names of its CUDA files without a GPU."""

import copy
import json
import lzma
import os
import shutil
import tomllib
from pathlib import Path

import pytest
import warp as wp

from conftest import SCENES_DIR, make_sim, tank_scene
from warpsph import load_scene, precompiled, warmup
from warpsph.cli import main

ROOT = Path(__file__).resolve().parent.parent
REBUILD = "the shipped kernels are stale: run python tools/build_precompiled.py (and commit warpsph/precompiled/)"
DAM_BREAK = os.path.join(SCENES_DIR, "dam_break.json")


def dam_break_modules():
    """The modules `warpsph run scenes/dam_break.json` loads (the README's scene, with its frame diagnostics)."""
    return warmup.scene_modules(load_scene(DAM_BREAK), frames=True)


def current(names):
    """The modules ``names`` that the shipped set has for their source now (all, unless it is stale: then the two
    tests above say so, and these test the copying of the rest)."""
    man = precompiled.manifest()
    return [n for n in names
            if man["modules"].get(precompiled.warp_module(n).name, {}).get("hash")
            == precompiled.module_hash(precompiled.warp_module(n))]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty kernel cache of the test's own (Warp's compile and load read wp.config.kernel_cache_dir)."""
    root = tmp_path / "kernel-cache"
    root.mkdir()
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(root))
    monkeypatch.delenv(precompiled.ENV, raising=False)
    return root


def files_in(root):
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


def copy_of_the_set(tmp_path, names):
    """A copy of the shipped set with the modules ``names`` only (to change it; the shipped manifest stays as read)."""
    man = copy.deepcopy(precompiled.manifest())
    out = tmp_path / "set"
    out.mkdir(parents=True)
    kept = {}
    for module in map(precompiled.warp_module, names):
        entry = man["modules"][module.name]
        shutil.copytree(precompiled.FOLDER / entry["dir"], out / entry["dir"])
        kept[module.name] = entry
    return out, {**man, "modules": kept}


def write_manifest(folder, man):
    (folder / precompiled.MANIFEST).write_text(json.dumps(man))
    return folder


def test_the_shipped_set_is_current_for_the_default_scene_on_sm_90():
    man = precompiled.manifest()
    assert man is not None, f"no {precompiled.FOLDER / precompiled.MANIFEST}: {REBUILD}"
    assert precompiled.for_this_warp(man), (f"built with Warp {man['warp']} (CUDA {man['cuda_toolkit']}), this is "
                                            f"Warp {wp.config.version} (CUDA {precompiled.toolkit()}): {REBUILD}")
    names = dam_break_modules()
    assert len(names) == 13
    for module in map(precompiled.warp_module, names):
        entry = man["modules"].get(module.name)
        assert entry is not None, f"{module.name} is not shipped: {REBUILD}"
        assert entry["hash"] == precompiled.module_hash(module), f"{module.name} changed: {REBUILD}"
        assert entry["dir"] == module.get_module_identifier(block_dim=module.options["block_dim"])
        for use_ptx in (False, True):  # the two files Warp may look up on an H100/H200, as its driver allows
            binary, meta = precompiled.lookup_names(module, arch=90, use_ptx=use_ptx)
            assert binary.endswith(".sm90.ptx" if use_ptx else ".sm90.cubin")
            assert {binary, meta} <= set(entry["files"])
            for f in (binary, meta):
                assert (precompiled.FOLDER / entry["dir"] / f"{f}.xz").is_file()


def test_every_kernel_module_is_shipped_and_current():
    """A kernel changed without rebuilding the set: that module compiles on a first run, as before. This test says
    so (the default scene's own test above says which of its modules)."""
    man = precompiled.manifest()
    stale = [m.name for m in map(precompiled.warp_module, warmup.all_modules())
             if man["modules"].get(m.name, {}).get("hash") != precompiled.module_hash(m)]
    assert stale == [], f"{', '.join(stale)}: {REBUILD}"
    assert set(man["archs"]) >= {80, 86, 89, 90}


def test_the_set_is_small_and_is_package_data():
    man = precompiled.manifest()
    listed = {f"{e['dir']}/{f}.xz" for e in man["modules"].values() for f in e["files"]}
    on_disk = {f for f in files_in(precompiled.FOLDER) if f.endswith(".xz")}
    assert on_disk == listed  # no file left over from an older build, none missing
    size = sum((precompiled.FOLDER / f).stat().st_size for f in on_disk)
    assert size < 10 * 2**20
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "warpsph.precompiled" in setuptools["packages"]
    data = setuptools["package-data"]["warpsph.precompiled"]
    shipped = on_disk | {precompiled.MANIFEST}
    assert all(any(Path(f).match(pattern) for pattern in data) for f in shipped), data


def test_what_is_copied_is_what_warp_looks_up_and_loads_without_compiling(cache):
    names = current(dam_break_modules())
    written = precompiled.seed(names, arch=90, use_ptx=False)
    modules = list(map(precompiled.warp_module, names))
    expected = sorted(f"{m.get_module_identifier()}/{f}" for m in modules
                      for f in precompiled.lookup_names(m, arch=90, use_ptx=False))
    assert sorted(p.relative_to(cache).as_posix() for p in written) == files_in(cache) == expected
    assert precompiled.seed(names, arch=90, use_ptx=False) == []  # there already
    # Warp's own ahead-of-time compile for sm_90 finds every binary and writes nothing (it would write the source,
    # the binary and the metadata of a module it compiled)
    wp.compile_aot_module(precompiled.warp_module(names[-1]), arch=90, use_ptx=False)
    assert files_in(cache) == expected
    assert len(precompiled.seed(names, arch=90, use_ptx=True)) == len(names)  # the PTX beside the metadata


def test_warmup_for_sm_90_finds_the_default_scene_shipped(cache, capsys):
    """`warpsph warmup --arch 90 --scene scenes/dam_break.json` on an empty cache: nothing to compile."""
    assert main(["warmup", "--arch", "90", "--scene", DAM_BREAK, "--workers", "1"]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert f"{13 - len(current(dam_break_modules()))} of 13 modules compiled for sm_90" in last
    assert len([f for f in files_in(cache) if not f.endswith(".cu")]) == 13 * 3  # metadata, CUBIN and PTX each


def test_nothing_is_copied_when_turned_off(cache, monkeypatch):
    names = dam_break_modules()
    for off in ("0", "off", "false"):
        monkeypatch.setenv(precompiled.ENV, off)
        assert not precompiled.enabled()
        assert precompiled.seed(names, arch=90, use_ptx=False) == []
    assert files_in(cache) == []
    monkeypatch.setenv(precompiled.ENV, "1")
    assert len(precompiled.seed(names, arch=90, use_ptx=False)) == 2 * len(current(names))


def test_nothing_is_copied_without_warps_kernel_cache(cache, monkeypatch):
    monkeypatch.setattr(wp.config, "cache_kernels", False)
    assert precompiled.seed(dam_break_modules(), arch=90, use_ptx=False) == []
    assert files_in(cache) == []


def test_nothing_is_copied_on_the_cpu(cache):
    assert precompiled.seed(dam_break_modules(), "cpu") == []
    assert files_in(cache) == []


def test_an_architecture_not_built_copies_nothing(cache):
    assert precompiled.seed(dam_break_modules(), arch=87, use_ptx=False) == []  # Jetson Orin
    assert files_in(cache) == []


def test_a_module_built_from_another_source_is_not_copied(cache, tmp_path):
    names = current(dam_break_modules())[-2:]
    folder, man = copy_of_the_set(tmp_path, names)
    changed, kept = (precompiled.warp_module(n).name for n in names)
    man["modules"][changed]["hash"] = "0" * 64  # as if built before a kernel changed
    written = precompiled.seed(names, arch=90, use_ptx=False, folder=write_manifest(folder, man))
    assert {p.parent.name for p in written} == {man["modules"][kept]["dir"]}


def test_a_file_that_is_not_the_one_built_is_not_copied(cache, tmp_path):
    names = current(dam_break_modules())[-1:]
    folder, man = copy_of_the_set(tmp_path, names)
    entry = man["modules"][names[0]]
    binary, _ = precompiled.lookup_names(precompiled.warp_module(names[0]), arch=90, use_ptx=False)
    (folder / entry["dir"] / f"{binary}.xz").write_bytes(lzma.compress(b"not a cubin"))
    assert precompiled.seed(names, arch=90, use_ptx=False, folder=write_manifest(folder, man)) == []
    assert files_in(cache) == []


def test_another_warp_copies_nothing(cache, tmp_path):
    names = current(dam_break_modules())[-1:]
    for key, value in (("warp", "1.18.0"), ("cuda_toolkit", "12.9")):
        folder, man = copy_of_the_set(tmp_path / key, names)
        man[key] = value
        assert precompiled.seed(names, arch=90, use_ptx=False, folder=write_manifest(folder, man)) == []
    assert files_in(cache) == []


def test_a_simulation_copies_its_scene_modules_whether_or_not_it_preloads(monkeypatch):
    calls = []
    monkeypatch.setattr(precompiled, "seed", lambda names, device=None, **k: calls.append((list(names), device)))
    for preload in (True, False):
        sim = make_sim(tank_scene(radius=0.05), preload=preload)
        assert calls[-1] == (warmup.scene_modules(sim.scene, bodies=sim.bodies, fluid=sim.num_fluid), sim.device)
    assert len(calls) == 2


class FakeGpu:
    """What Warp's file naming asks of a CUDA device (no GPU here): its architecture, the form its driver takes
    (Warp compiles PTX where the driver is at least its toolkit's version, else CUBIN) and the arch Warp compiles for."""

    is_cpu, is_cuda = False, True

    def __init__(self, arch, form):
        self.arch, self.form = arch, form

    def get_cuda_output_format(self, preferred=None):
        return self.form

    def get_cuda_compile_arch(self):
        return self.arch

    def _get_cuda_arch_suffix(self, arch):
        return ""


@pytest.mark.parametrize("arch, form, copied", [(90, "cubin", ".sm90.cubin"), (90, "ptx", ".sm90.ptx"),
                                                (80, "cubin", ".sm80.cubin"), (110, "cubin", None)])
def test_a_gpu_gets_the_file_warp_names_for_it(cache, monkeypatch, arch, form, copied):
    gpu = FakeGpu(arch, form)
    monkeypatch.setattr(wp, "get_device", lambda d=None: gpu if d is gpu else pytest.fail(f"asked for {d}"))
    written = precompiled.seed(dam_break_modules(), gpu)
    if copied is None:  # sm_110 (Thor) is not shipped: it compiles
        assert written == []
    else:
        assert len(written) == 2 * len(current(dam_break_modules()))
        assert sorted({p.name.split("_")[-1].split(".", 1)[1] for p in written}) == sorted(["meta", copied[1:]])


FIRST_STEP = """
import sys
import warp as wp
from warpsph import load_scene
from warpsph.simulation import Simulation
sim = Simulation(load_scene(sys.argv[1], scale=0.05), device="cuda:0")
sim.step()
wp.synchronize()
"""


@pytest.mark.slow
@pytest.mark.skipif(not wp.is_cuda_available(), reason="needs a CUDA device of an architecture shipped")
@pytest.mark.parametrize("shipped", [True, False])
def test_a_first_run_on_the_gpu_compiles_nothing_shipped(tmp_path, shipped):
    """A fresh process on an empty kernel cache sets up the dam break and steps: with the set, no module is compiled
    (Warp writes a module's generated source only when it compiles it); with WARPSPH_PRECOMPILED=0, all 11 are."""
    import subprocess
    import sys

    if wp.get_device("cuda:0").arch not in precompiled.manifest()["archs"]:
        pytest.skip(f"sm_{wp.get_device('cuda:0').arch} is not shipped")
    env = {**os.environ, "WARP_CACHE_PATH": str(tmp_path), precompiled.ENV: "1" if shipped else "0"}
    out = subprocess.run([sys.executable, "-c", FIRST_STEP, DAM_BREAK], env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    compiled = sorted(p.name for p in tmp_path.rglob("*.cu"))
    binaries = sorted(p.name for p in tmp_path.rglob("*") if p.suffix in (".cubin", ".ptx"))
    assert len(binaries) == 11
    assert compiled == ([] if shipped else sorted(b.rsplit(".", 2)[0] + ".cu" for b in binaries))


def test_a_missing_or_broken_file_copies_nothing_of_its_module(cache, tmp_path):
    names = current(dam_break_modules())[-1:]
    binary, meta = precompiled.lookup_names(precompiled.warp_module(names[0]), arch=90, use_ptx=False)
    for broken in ("missing", "not xz"):
        folder, man = copy_of_the_set(tmp_path / broken.replace(" ", "_"), names)
        path = folder / man["modules"][names[0]]["dir"] / f"{binary}.xz"
        path.unlink() if broken == "missing" else path.write_bytes(b"not xz")
        assert precompiled.seed(names, arch=90, use_ptx=False, folder=write_manifest(folder, man)) == []
    assert files_in(cache) == []
