"""``warpsph sweep`` (#20): a 4-cell Taylor-Green sweep (6 and 8 across, dfsph and vr, no warm-up: a few
seconds a cell on one CPU core) through the local executor and a local Ray instance (identical tables but for
the timings; each cell a Ray task given the CPUs and no GPU that warpsph asked for, read inside the cell; a cuda
sweep refused up front on an instance without GPUs), resumed without rerunning finished cells, finished after a SIGKILL of its driver, a blow-up
recorded as a result, and bad sweep files naming the key (exit 2, nothing written). Scene-file sweeps (two
models x two viscosities of a 360-particle slosh: the higher viscosity keeps less kinetic energy and enstrophy;
a blow-up with its step and message; models[K].KEY items), the Pareto study and the stress matrix through the
sweep (the same rows as their points computed in the process), and the plots drawn from a table."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from warpsph.validation import paper_tables
from conftest import as_in_a_terminal, signal_group
from warpsph.cli import main
from warpsph.errors import SceneError
from warpsph.sweep import assemble, cells, comparable, load_sweep, records, run_sweep, scene_of

PNG = b"\x89PNG\r\n\x1a\n"

SWEEP = {"base": "taylor-green", "axes": {"method": ["dfsph", "vr"], "resolution": [6, 8]}, "warm_up": False,
         "measures": ["particles", "error_pct", "steps", "ke_ratio", "wall_s"]}
EXPECTED = [("dfsph", 6, 216), ("dfsph", 8, 384), ("vr", 6, 216), ("vr", 8, 384)]


def _mtimes(out):
    return {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "local"
    lines = []
    table = run_sweep(SWEEP, out, executor="local", workers=2, log=lines.append)
    return out, table, lines


@pytest.mark.slow
def test_local_sweep_table(local):
    out, table, lines = local
    assert table["complete"] and table["counts"] == {"done": 4, "unstable": 0, "failed": 0, "missing": 0}
    assert [(r["method"], r["resolution"], r["particles"]) for r in table["rows"]] == EXPECTED
    for r in table["rows"]:
        assert r["status"] == "done" and 0 < r["error_pct"] < 100 and r["steps"] > 0 and r["wall_s"] > 0
        assert 0 < r["ke_ratio"] < 1 and r["device"] == "cpu"
    assert json.loads((out / "table.json").read_text())["rows"] == table["rows"]
    md = (out / "table.md").read_text()
    assert "| method | resolution | particles | error_pct | steps | ke_ratio | wall_s | status |" in md
    assert md.count("| done |") == 4
    assert len(list((out / "cells").glob("*.json"))) == 4 and not list(out.rglob("*.tmp"))
    assert any("4/4 done" in line and "ETA" in line for line in lines), lines


@pytest.mark.slow
def test_rerun_skips_finished_cells(local, tmp_path):
    out, table, _ = local
    before = _mtimes(out)
    lines = []
    again = run_sweep(SWEEP, out, workers=2, log=lines.append)
    assert _mtimes(out) == before and "[0 to run" in lines[0]
    assert again["rows"] == table["rows"]
    # a failed cell and a missing one are run again, the others are not
    cells = sorted((out / "cells").glob("*.json"))
    record = json.loads(cells[0].read_text())
    record.update(status="failed", error="RuntimeError: lost")
    cells[0].write_text(json.dumps(record))
    cells[1].unlink()
    before = _mtimes(out)
    lines = []
    run_sweep(SWEEP, out, workers=2, log=lines.append)
    after = _mtimes(out)
    assert "[2 to run" in lines[0]
    assert {name for name in after if after[name] != before.get(name)} == {cells[0].name, cells[1].name}


@pytest.fixture(scope="module")
def ray_cluster():
    """A local Ray instance of 2 CPUs and no GPU (whatever the machine has), shared by the real-Ray tests; its
    workers import tests/sweep_cells.py (PYTHONPATH). Skipped only without ray (warpsph[ray])."""
    ray = pytest.importorskip("ray", reason="the Ray executor needs ray (warpsph[ray])")
    path = os.pathsep.join(p for p in (os.path.dirname(os.path.abspath(__file__)), os.environ.get("PYTHONPATH")) if p)
    ray.init(num_cpus=2, num_gpus=0, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": path}})
    yield ray
    ray.shutdown()


@pytest.mark.slow
def test_ray_gives_the_same_table(local, ray_cluster, tmp_path):
    table = run_sweep(SWEEP, tmp_path / "ray", executor="ray", max_retries=1, log=lambda line: None)
    assert table["complete"]
    assert comparable(table) == comparable(local[1])


def _spy_remote(monkeypatch, ray, check):
    """ray.remote with each call's options passed to ``check`` first (it fails the test before a task starts)."""
    remote, asked = ray.remote, []

    def spy(*args, **options):
        asked.append(options)
        check(options)
        return remote(*args, **options)
    monkeypatch.setattr(ray, "remote", spy)
    return asked


PLACED_SWEEP = {"name": "placed", "base": {"function": "sweep_cells:ray_placed"},
                "axes": {"viscosity": [0.01, 0.05]}, "measures": ["particles", "steps"], "warm_up": False}


@pytest.mark.slow
def test_ray_cells_run_as_tasks_with_the_resources_asked(ray_cluster, tmp_path, monkeypatch, capsys):
    """A 2-cell sweep of a tiny scene through warpsph sweep --executor ray --num-cpus 0.5 on the CPU path: each
    cell is a Ray task of its own, run in a Ray worker (not the driver) on the instance's node, and Ray assigned
    it what warpsph asked for: 0.5 CPU and no GPU (the cell records ray.get_runtime_context() itself)."""
    ray = ray_cluster
    asked = _spy_remote(monkeypatch, ray, lambda options: None)
    path = tmp_path / "placed.json"
    path.write_text(json.dumps(PLACED_SWEEP))
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--executor", "ray", "--num-cpus", "0.5"]) == 0, \
        capsys.readouterr().err
    assert asked == [{"num_gpus": 0, "num_cpus": 0.5, "max_retries": 3}]
    records = [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))]
    nodes = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
    assert len(records) == 2 and all(r["status"] == "done" for r in records), records
    for r in records:
        row = r["row"]
        assert row["resources"] == {"CPU": 0.5} and row["gpu_ids"] == [], row
        assert r["device_alias"] == "cpu" and row["particles"] > 0 and row["steps"] == 3
        assert row["node_id"] in nodes and row["worker_id"]
        assert row["pid"] == r["pid"] != os.getpid()  # run_cell ran in the Ray worker that ran the cell
    assert len({r["row"]["task_id"] for r in records}) == 2  # a task per cell
    table = json.loads((out / "table.json").read_text())
    assert table["complete"] and [row["device"] for row in table["rows"]] == ["cpu", "cpu"]


@pytest.mark.slow
def test_ray_refuses_cuda_on_a_cluster_without_gpus(ray_cluster, tmp_path, monkeypatch, capsys):
    """A sweep file's "device": "cuda" on a Ray instance without GPUs (started by this process before the sweep,
    as a script would) is refused before any cell is submitted, naming the sweep file's key; before, it was
    taken for a cluster joined that might gain GPU nodes, and the cells waited forever."""
    ray = ray_cluster
    assert not ray.cluster_resources().get("GPU")
    asked = _spy_remote(monkeypatch, ray, lambda options: pytest.fail(f"a cell was submitted: {options}"))
    path = tmp_path / "cuda.json"
    path.write_text(json.dumps({**PLACED_SWEEP, "device": "cuda"}))
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--executor", "ray"]) == 2
    err = capsys.readouterr().err
    assert f"{path}: device: the cells ask for 1 GPU each, and the Ray instance has 0" in err, err
    assert len(err.splitlines()) == 1 and not asked and not out.exists()


class FakeRef:
    def __init__(self, value):
        self.value = value


class FakeRay:
    """Ray's calls that the executor makes, run in this process: what each task asked for is kept."""

    def __init__(self, gpus):
        self.gpus, self.options, self.started = gpus, [], False

    def is_initialized(self):
        return self.started

    def init(self, **kwargs):
        self.started = True

    def cluster_resources(self):
        return {"CPU": 2.0, **({"GPU": float(self.gpus)} if self.gpus else {})}

    def remote(self, **options):
        self.options.append(options)
        return lambda fn: type("Remote", (), {"remote": staticmethod(lambda cell: FakeRef(fn(cell)))})

    def wait(self, refs, num_returns=1):
        return refs[:num_returns], refs[num_returns:]

    def get(self, ref):
        return ref.value


FUNCTION_SWEEP = {"name": "squares", "base": {"function": "sweep_cells:die_or_square"}, "axes": {"x": [1, 3]},
                  "measures": ["square"], "warm_up": False}


@pytest.fixture
def fake_ray(monkeypatch):
    """A Ray with one GPU; the cells' devices are kept and the cells run on the CPU (this machine's)."""
    import warpsph.sweep

    ray, devices, run_cell = FakeRay(gpus=1), [], warpsph.sweep.run_cell
    monkeypatch.setitem(sys.modules, "ray", ray)
    monkeypatch.syspath_prepend(os.path.dirname(__file__))
    monkeypatch.setattr(warpsph.sweep, "run_cell", lambda cell, device: devices.append(device) or run_cell(cell, "cpu"))
    return ray, devices


@pytest.mark.parametrize("sweep_device, num_gpus, asked, on", [
    ("cuda", None, 1, "cuda:0"), ("cuda", 0.25, 0.25, "cuda:0"), ("cuda:0", 2, 2, "cuda:0"),
    ("cpu", None, 0, "cpu"), ("cpu", 0, 0, "cpu"), (None, None, 0, "cpu"), (None, 0.5, 0.5, "cuda:0"),
])
def test_ray_cells_ask_for_the_sweeps_device(tmp_path, fake_ray, sweep_device, num_gpus, asked, on):
    """The sweep file's device under Ray: cuda cells ask for num_gpus (1, or the fraction given) and run on the GPU
    Ray assigns; cpu cells ask for none. The device was ignored: cuda cells ran on the CPU, asking for no GPU."""
    ray, devices = fake_ray
    ray.gpus = 2
    sweep = {**FUNCTION_SWEEP, **({"device": sweep_device} if sweep_device else {})}
    table = run_sweep(sweep, tmp_path / "out", executor="ray", num_gpus=num_gpus, log=lambda line: None)
    assert table["complete"] and {r["x"]: r["square"] for r in table["rows"]} == {1: 1, 3: 9}
    assert ray.options == [{"num_gpus": asked, "num_cpus": 1, "max_retries": 3}] and devices == [on, on]


def test_ray_sweep_file_device_through_the_cli(tmp_path, capsys, fake_ray):
    ray, devices = fake_ray
    path = tmp_path / "sweep.json"
    path.write_text(json.dumps({**FUNCTION_SWEEP, "device": "cuda"}))
    assert main(["sweep", str(path), "--out", str(tmp_path / "out"), "--executor", "ray", "--num-gpus", "0.5"]) == 0
    assert ray.options[0]["num_gpus"] == 0.5 and devices == ["cuda:0", "cuda:0"]
    assert main(["sweep", str(path), "--out", str(tmp_path / "again"), "--executor", "ray"]) == 0
    assert ray.options[1]["num_gpus"] == 1


@pytest.mark.parametrize("sweep_device, options, gpus, key, words", [
    ("cpu", ["--num-gpus", "0.5"], 1, "--num-gpus", "0.5 GPUs per cell, but the sweep file's device is cpu"),
    ("cuda", ["--num-gpus", "0"], 1, "--num-gpus", "0 gives the cells no GPU"),
    ("cuda:1", [], 1, "device", "Ray places each cell itself"),
    ("cuda", ["--devices", "cpu", "--num-gpus", "1"], 1, "--num-gpus", "1 GPUs per cell, but --devices is cpu"),
    ("cuda", [], 0, "device", "the cells ask for 1 GPU each, and the Ray instance has 0"),
    ("cuda", ["--num-gpus", "0.5"], 0, "--num-gpus", "the cells ask for 0.5 GPU each, and the Ray instance has 0"),
])
def test_ray_refuses_a_device_it_cannot_honour(tmp_path, capsys, fake_ray, sweep_device, options, gpus, key, words):
    """Refused before any cell runs, naming the option or the sweep file's key."""
    ray, devices = fake_ray
    ray.gpus = gpus
    path = tmp_path / "sweep.json"
    path.write_text(json.dumps({**FUNCTION_SWEEP, "device": sweep_device}))
    assert main(["sweep", str(path), "--out", str(tmp_path / "out"), "--executor", "ray", *options]) == 2
    err = capsys.readouterr().err
    assert f"{key}: {words}" in err and len(err.splitlines()) == 1, err
    assert not ray.options and not devices


def test_a_yaml_sweep_file_is_the_same_sweep(tmp_path):
    yaml = pytest.importorskip("yaml", reason="YAML sweep files need pyyaml")
    as_json, as_yaml = tmp_path / "s.json", tmp_path / "s.yaml"
    as_json.write_text(json.dumps(SWEEP))
    as_yaml.write_text(yaml.safe_dump(SWEEP))
    assert cells(load_sweep(as_yaml)) == cells(load_sweep(as_json))
    as_yaml.write_text("axes: [unclosed")
    with pytest.raises(SceneError, match="not valid YAML"):
        load_sweep(as_yaml)


@pytest.mark.slow
def test_killed_driver_rerun_finishes_the_missing_cells(tmp_path):
    sweep = tmp_path / "sweep.json"
    sweep.write_text(json.dumps(SWEEP))
    out = tmp_path / "out"
    driver = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "sweep", str(sweep), "--out", str(out),
                               "--workers", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    try:
        deadline = time.time() + 60
        while time.time() < deadline and not list((out / "cells").glob("*.json")):
            time.sleep(0.05)
        os.killpg(driver.pid, signal.SIGKILL)  # the driver and the cell in flight
    finally:
        driver.wait()
    first = _mtimes(out)
    assert 1 <= len(first) < 4 and not (out / "table.json").exists()
    _rerun_runs_the_rest(sweep, out, first, workers=2)


def _rerun_runs_the_rest(sweep, out, first, workers):
    """The same sweep again: it runs only the cells not in ``first`` (the finished ones' modification times) and
    leaves those records as they were; the table is complete."""
    lines = []
    table = run_sweep(sweep, out, workers=workers, log=lines.append)
    assert f"[{4 - len(first)} to run" in lines[0]
    after = _mtimes(out)
    assert len(after) == 4 and all(after[name] == first[name] for name in first)
    assert table["complete"] and [(r["method"], r["resolution"], r["particles"]) for r in table["rows"]] == EXPECTED


def _alive_in_group(pgid):
    """The pids of the process group ``pgid`` that are not zombies (an exited multiprocessing resource tracker
    whose parent is gone can stay a zombie where pid 1 does not reap)."""
    alive = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(stat.parent.name))
    return alive


@pytest.mark.slow
def test_ctrl_c_of_the_sweep_keeps_the_finished_cells_and_a_rerun_runs_the_rest(tmp_path):
    """SIGINT to the sweep's process group (Ctrl-C in a terminal: the driver and the cell in flight) after the first
    cell: exit 130 and one line, no traceback, the finished cells kept, no table, no cell process left; the rerun
    runs only the cells not finished and leaves the others' records as they were."""
    sweep = tmp_path / "sweep.json"
    sweep.write_text(json.dumps(SWEEP))
    out = tmp_path / "out"
    driver = subprocess.Popen([sys.executable, "-m", "warpsph.cli", "sweep", str(sweep), "--out", str(out),
                               "--workers", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              start_new_session=True, preexec_fn=as_in_a_terminal)
    try:
        deadline = time.time() + 60
        while time.time() < deadline and not list((out / "cells").glob("*.json")):
            time.sleep(0.05)
    finally:
        err = signal_group(driver, signal.SIGINT)
    assert driver.returncode == 130, err
    last = err.strip().splitlines()[-1]  # after the progress lines
    assert "Traceback" not in err and last.startswith("warpsph: SIGINT: the sweep stopped; ") and "run the same command again to run the other" in last, err
    deadline = time.time() + 5  # the resource tracker ends once it sees the driver gone
    while _alive_in_group(driver.pid) and time.time() < deadline:
        time.sleep(0.05)
    assert [Path(f"/proc/{pid}/cmdline").read_bytes()[:200] for pid in _alive_in_group(driver.pid)] == []  # no cell left
    first = _mtimes(out)
    assert 1 <= len(first) < 4 and not (out / "table.json").exists()
    assert all(json.loads((out / "cells" / name).read_text())["status"] == "done" for name in first)
    _rerun_runs_the_rest(sweep, out, first, workers=1)


@pytest.mark.slow
def test_blow_up_is_a_result(tmp_path):
    # dam-front 4 across with a fixed 50 ms step and two solver iterations leaves the domain at step 2
    sweep = {"base": "dam-front", "axes": {"resolution": [4]}, "warm_up": False,
             "fixed": {"time.fixed_dt": 0.05, "solver.max_iterations": 2}}
    table = run_sweep(sweep, tmp_path, log=lambda line: None)
    row = table["rows"][0]
    assert table["complete"] and table["counts"]["unstable"] == 1
    assert row["status"] == "unstable" and "unstable at step" in row["unstable"] and row["error_pct"] is None
    assert "unstable: unstable at step" in (tmp_path / "table.md").read_text()
    lines = []
    run_sweep(sweep, tmp_path, log=lines.append)  # a result: not run again
    assert "[0 to run" in lines[0]


@pytest.mark.parametrize("change, key", [
    ({"base": "no-such-case"}, "base"),
    ({"base": "scenes/dam_break.json"}, "base"),
    ({"base": {"function": "warpsph.validation.pareto:no_such"}}, "base.function"),
    ({"base": {"function": "warpsph.validation.pareto:point"}, "axes": {"methd": ["dfsph"]}}, "axes.methd"),
    ({"axes": {}}, "axes"),
    ({"axes": {"method": ["sph2"], "resolution": [8]}}, "axes.method[0]"),
    ({"axes": {"method": ["dfsph"], "resolution": [3]}}, "axes.resolution[0]"),
    ({"axes": {"method": ["dfsph"], "resolution": 8}}, "axes.resolution"),
    ({"axes": {"resolution": [8], "cfl": [1.5]}}, "axes.cfl[0]"),
    ({"axes": {"resolution": [8], "solver.bogus": [1]}}, "axes.solver.bogus[0]"),
    ({"axes": {"resolution": [8], "gravity": [0]}}, "axes.gravity"),
    ({"axes": {"method": ["dfsph"]}}, "axes"),
    ({"measures": ["error_pct", "speed"]}, "measures[1]"),
    ({"workers": 2}, "workers"),
])
def test_bad_sweep_file_names_the_key(tmp_path, capsys, change, key):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**SWEEP, **change}))
    assert_refused(path, key, tmp_path, capsys)


def assert_refused(path, key, tmp_path, capsys):
    """The sweep file is refused naming ``key``, by the API and by the CLI, which writes nothing."""
    with pytest.raises(SceneError) as exc:
        load_sweep(path)
    assert exc.value.key == key, str(exc.value)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out)]) == 2
    assert f"{path}: {key}:" in capsys.readouterr().err
    assert not out.exists()


# --- scene-file sweeps -----------------------------------------------------------------------------------

# a block of 360 particles thrown sideways at 1 m/s into a closed box (periodic in z), under gravity
TINY_SCENE = {"name": "slosh", "particle_radius": 0.01, "gravity": [0, -9.81, 0],
              "domain": {"min": [0, 0, 0], "max": [0.4, 0.3, 0.12], "periodic": ["z"]},
              "fluid_blocks": [{"start": [0, 0, 0], "end": [0.2, 0.12, 0.12], "velocity": [1.0, 0, 0]}],
              "output": {"fps": 20, "frames": 4}}
VR = [{"type": "vorticity_refinement", "alpha": 1.0}]
SCENE_SWEEP = {"scene": "tiny.json", "time": 0.2, "warm_up": False,
               "axes": {"models": [[], VR], "fluid.viscosity": [0.01, 0.1]},
               "measures": ["particles", "ke_ratio", "enstrophy_end", "blow_up_step", "steps", "density_iterations",
                            "wall_s"]}


def _scene_sweep(folder, **change):
    (folder / "tiny.json").write_text(json.dumps(TINY_SCENE))
    path = folder / "sweep.json"
    path.write_text(json.dumps({**SCENE_SWEEP, **change}))
    return path


@pytest.fixture(scope="module")
def scene_sweep(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene_sweep")
    path = _scene_sweep(folder)
    return path, run_sweep(path, folder / "out", workers=2, log=lambda line: None), folder / "out"


@pytest.mark.slow
def test_scene_sweep_measures_and_the_viscosity_direction(scene_sweep):
    """Measured (cpu): KE end/start 0.575 / 0.319 (plain), 0.541 / 0.277 (VR) at nu 0.01 / 0.1 after 0.2 s."""
    path, table, out = scene_sweep
    assert table["complete"] and table["kind"] == "scene" and table["axes"] == ["models", "fluid.viscosity"]
    assert [(r["models"], r["fluid.viscosity"]) for r in table["rows"]] == [([], 0.01), ([], 0.1), (VR, 0.01), (VR, 0.1)]
    for r in table["rows"]:
        assert r["status"] == "done" and r["particles"] == 360 and r["blow_up_step"] is None
        assert 0 < r["ke_ratio"] < 1 and r["enstrophy_end"] > 0 and r["steps"] > 50 and r["wall_s"] > 0
        assert r["density_iterations"] >= 2  # solver.min_iterations
    for models in ([], VR):
        low, high = [r for r in table["rows"] if r["models"] == models]
        assert high["ke_ratio"] < 0.8 * low["ke_ratio"], (low, high)
        assert high["enstrophy_end"] < 0.6 * low["enstrophy_end"], (low, high)
    for cell, record in records(path, out):  # the cell files keep every measure, per frame too
        row = record["row"]
        assert len(row["kinetic_energy"]) == row["frames"] + 1 == 5 and row["time_reached"] >= 0.2 - 1e-6
        assert row["ke_ratio"] == pytest.approx(row["ke_end"] / row["ke_start"])
    md = (out / "table.md").read_text()
    assert "| models | fluid.viscosity | particles | ke_ratio |" in md and "vorticity_refinement(alpha=1)" in md


@pytest.mark.slow
def test_scene_sweep_cells_keep_the_energies_and_enstrophy_per_frame(scene_sweep):
    """The per-frame series the paper tables read (#21): rotational energy (0 without a model, > 0 with VR's
    spin) and enstrophy beside the kinetic energy, one value a frame."""
    path, table, out = scene_sweep
    for cell, record in records(path, out):
        row = record["row"]
        n = row["frames"] + 1
        assert len(row["kinetic_energy"]) == len(row["rotational_energy"]) == len(row["enstrophy"]) == n
        assert row["enstrophy"][-1] == pytest.approx(row["enstrophy_end"], rel=1e-4)
        assert row["enstrophy"][0] == pytest.approx(row["enstrophy_start"], rel=1e-4)
        assert row["particles_end"] == row["particles"] == 360  # no emitter, no sink
        if cell["params"]["models"]:
            assert all(e > 0 for e in row["rotational_energy"][1:])
        else:
            assert row["rotational_energy"] == [0.0] * n


@pytest.mark.slow
def test_scene_sweep_region_gives_the_enstrophy_inside_a_box(tmp_path):
    """"region": the cells also measure the enstrophy of the particles inside a box: all of it for a box around the
    domain, a part for the right half, none for a box off the fluid."""
    def run(region, name):
        (tmp_path / name).mkdir()
        path = _scene_sweep(tmp_path / name, axes={"models": [VR]}, time=0.1, region=region)
        run_sweep(path, tmp_path / name / "out", workers=1, log=lambda line: None)
        return [record["row"] for _, record in records(path, tmp_path / name / "out")][0]

    everything = run({"min": [-1, -1, -1], "max": [1, 1, 1]}, "all")
    assert everything["region_enstrophy"] == everything["enstrophy"] and max(everything["enstrophy"]) > 0
    half = run({"min": [0.1, -1, -1], "max": [1, 1, 1]}, "half")
    assert 0 < max(half["region_enstrophy"]) < max(half["enstrophy"])
    assert max(run({"min": [0.35, 0.25, 0], "max": [0.4, 0.3, 0.12]}, "none")["region_enstrophy"]) == 0


@pytest.mark.slow
def test_scene_sweep_counts_the_particles_an_emitter_added(tmp_path):
    """An inflow scene starts with one layer (25 particles); particles_end counts what the emitter added."""
    scene = {"name": "channel", "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [1.0, 0.4, 0.2]},
             "emitters": [{"min": [0, 0, 0], "max": [0.04, 0.2, 0.2], "velocity": [1.0, 0, 0]}],
             "output": {"fps": 20, "frames": 2}}
    (tmp_path / "channel.json").write_text(json.dumps(scene))
    sweep = {"scene": str(tmp_path / "channel.json"), "time": 0.1, "warm_up": False, "axes": {"models": [[]]},
             "measures": ["particles", "particles_end"]}
    [row] = run_sweep(sweep, tmp_path / "out", log=lambda line: None)["rows"]
    assert row["status"] == "done" and row["particles"] == 25 and row["particles_end"] >= 25 * 3


@pytest.mark.slow
def test_scene_sweep_records_a_blow_up_with_its_step(tmp_path):
    path = _scene_sweep(tmp_path, axes={"time.fixed_dt": [0.05]}, fixed={"solver.max_iterations": 2})
    table = run_sweep(path, tmp_path / "out", log=lambda line: None)
    [row] = table["rows"]
    assert table["complete"] and row["status"] == "unstable" and 1 <= row["blow_up_step"] <= 4
    assert row["unstable"].startswith(f"unstable at step {row['blow_up_step']} ")
    [(_, record)] = records(path, tmp_path / "out")
    assert record["row"]["instability"]["step"] == row["blow_up_step"] and record["row"]["steps"] == row["blow_up_step"]


def test_scene_keys_apply_models_first(tmp_path):
    path = _scene_sweep(tmp_path, axes={"models[0].beta": [0.0, 1.0], "scale": [1.0, 0.125]},
                        fixed={"models": [{"type": "rankine", "beta": 0.6}], "cfl": 0.3})
    spec = load_sweep(path)
    assert spec["columns"] == ["models[0].beta", "scale"] and spec["fixed"]["time.cfl"] == 0.3
    scenes = [scene_of(cell) for cell in cells(spec)]
    assert [s.models[0].beta for s in scenes] == [0.0, 0.0, 1.0, 1.0]
    assert [s.particle_radius for s in scenes] == pytest.approx([0.01, 0.02, 0.01, 0.02])
    assert all(s.time.cfl == 0.3 for s in scenes) and len({c["id"] for c in cells(spec)}) == 4
    method = load_sweep(_scene_sweep(tmp_path, axes={"method": ["vr"], "models[0].alpha": [0.5]}))
    assert [scene_of(c).models[0].alpha for c in cells(method)] == [0.5]


@pytest.mark.parametrize("change, key", [
    ({"axes": {"sclae": [0.1]}}, "axes.sclae"),
    ({"axes": {"resolution": [8]}}, "axes.resolution"),
    ({"axes": {"models[0].bet": [1.0]}, "fixed": {"models": [{"type": "rankine", "beta": 0.6}]}}, "axes.models[0].bet[0]"),
    ({"axes": {"models[1].beta": [1.0]}, "fixed": {"models": [{"type": "rankine", "beta": 0.6}]}}, "axes.models[1].beta[0]"),
    ({"axes": {"models": [[], [{"type": "rankin"}]]}}, "axes.models[1]"),
    ({"axes": {"models": [[], {"type": "rankine"}]}}, "axes.models[1]"),
    ({"axes": {"cfl": [0.5, 1.5]}}, "axes.cfl[1]"),
    ({"axes": {"scale": [0]}}, "axes.scale[0]"),
    ({"axes": {"method": ["sph2"]}}, "axes.method[0]"),
    ({"axes": {"method": ["vr"], "models": [[]]}}, "axes.models[0]"),
    ({"axes": None, "cells": [{"fluid.viscosity": 0.01}, {"fluid.viscosty": 0.1}]}, "cells[1].fluid.viscosty"),
    ({"frames": 3}, "time"),
    ({"time": -1}, "time"),
    ({"measures": ["ke_ratio", "energy"]}, "measures[1]"),
    ({"region": {"min": [0, 0], "max": [1, 1, 1]}}, "region"),
])
def test_bad_scene_sweep_names_the_key(tmp_path, capsys, change, key):
    path = _scene_sweep(tmp_path, **change)
    if change.get("axes", 0) is None:
        path.write_text(json.dumps({k: v for k, v in json.loads(path.read_text()).items() if k != "axes"}))
    assert_refused(path, key, tmp_path, capsys)


def test_scene_and_base_keys_say_what_they_need(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for sweep, key, words in [(_scene_sweep(tmp_path / "a", scene="no_such_scene.json"), "scene", "no such scene file"),
                              (_scene_sweep(tmp_path / "b", base="taylor-green"), "scene", "not both"),
                              ({**SWEEP, "base": "scenes/dam_break.json"}, "base", 'give it as "scene"'),
                              ({**SWEEP, "scale": 0.1}, "scale", "only for a scene-file sweep")]:
        with pytest.raises(SceneError, match=words) as exc:
            load_sweep(sweep)
        assert exc.value.key == key


# --- the studies through the sweep ---------------------------------------------------------------------

TIMINGS = {"wall_s", "setup_s", "measure_s", "ms_per_step", "wall_per_sim_s", "load_average", "warmup_s", "pareto"}


@pytest.mark.slow
def test_pareto_through_the_sweep_gives_the_points_of_the_process(tmp_path):
    from warpsph.validation.pareto import METHODS, lamb_oseen_point, study

    out = tmp_path / "pareto.json"
    report = study(["dfsph"], [8], [0.05], device="cpu", out=str(out), T=0.05, frames=2, png=False, quiet=True)
    assert report["complete"] and report["sweep"] == str(tmp_path / "pareto.sweep")
    [cell] = (tmp_path / "pareto.sweep" / "cells").glob("*.json")
    assert json.loads(cell.read_text())["status"] == "done"
    [point] = report["points"]
    here = lamb_oseen_point(METHODS["dfsph"][1], 8, 0.05, "cpu", T=0.05, frames=2)  # the old study's loop body
    here = {"method": "dfsph", "label": METHODS["dfsph"][0], "models": [], "resolution": 8, "tolerance": 0.05, **here}
    assert {k: v for k, v in point.items() if k not in TIMINGS} == json.loads(
        json.dumps({k: v for k, v in here.items() if k not in TIMINGS}))
    mtime = cell.stat().st_mtime_ns  # the same command again: nothing runs
    again = study(["dfsph"], [8], [0.05], device="cpu", out=str(out), T=0.05, frames=2, png=False, quiet=True)
    assert cell.stat().st_mtime_ns == mtime and again["points"] == json.loads(out.read_text())["points"]


def _plain_cell_in_the_process(scene_path, scale, seconds):
    """The stress matrix's plain cell as it ran in the process: plain DFSPH, every frame measured."""
    import dataclasses

    from warpsph.cli import _init_warp
    from warpsph.diagnostics import Diagnostics
    from warpsph.scene import load_scene
    from warpsph.simulation import Simulation

    _init_warp()
    sim = Simulation(dataclasses.replace(load_scene(scene_path, scale=scale), models=()), device="cpu")
    diagnostics, frames = Diagnostics(), []
    sim.run(until_time=seconds, on_frame=lambda s, f: frames.append(diagnostics.measure(s, f)))
    stats = sim.statistics()
    return {"steps": sim.step_count, "time_reached": sim.time, "frames": len(frames),
            "ke_end": frames[-1]["kinetic_energy"], "density_iterations": stats["density_iterations"],
            "max_density_error_pct": 100 * max(f["density_error_max"] for f in frames)}


@pytest.mark.slow
def test_stress_through_the_sweep_gives_the_cells_of_the_process(tmp_path):
    from warpsph.validation.stress import REPO, stress

    scene = REPO / "scenes" / "dam_break.json"
    report = stress(scene, scale=0.02, seconds=0.05, axes=["alpha"], values={"alpha": [1.0]}, device="cpu",
                    log=lambda *a: None, sweep_dir=tmp_path / "cells")
    assert [c["name"] for c in report["cells"]] == ["plain DFSPH", "alpha = 1"]
    assert len(list((tmp_path / "cells").glob("*/cells/*.json"))) == 2
    plain = report["cells"][0]
    here = _plain_cell_in_the_process(scene, 0.02, 0.05)
    assert {k: plain[k] for k in here} == here
    assert plain["dt_min_step"] == report["dt_cfl"] > 0 and plain["ke_end_rel_dfsph"] == 1.0


def test_the_gpu_pareto_sweep_file_is_valid():
    """sweeps/pareto_gpu.json (#20's GPU item): both vortices, four methods, 256/128/64 across (largest first)."""
    spec = load_sweep(Path(__file__).resolve().parent.parent / "sweeps" / "pareto_gpu.json")
    assert spec["kind"] == "function" and spec["device"] == "cuda" and spec["fixed"] == {"tolerance": 0.01}
    params = [c["params"] for c in cells(spec)]
    assert len(params) == 24 and params[0] == {"resolution": 256, "case": "taylor-green", "method": "dfsph",
                                               "tolerance": 0.01}
    assert {p["method"] for p in params} == {"dfsph", "vr", "rankine1", "micropolar"}


# --- plots from a table ------------------------------------------------------------------------------------

@pytest.mark.slow
def test_plots_from_the_tables(local, scene_sweep, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the PNGs need matplotlib (the test extra installs it)")
    out, _, _ = local  # time and error measures: a Pareto plot and a heat map
    sweep = tmp_path / "sweep.json"
    sweep.write_text(json.dumps(SWEEP))
    assert main(["sweep", str(sweep), "--out", str(out), "--plot"]) == 0  # finished: nothing runs, the plots are drawn
    for name in ("table.pareto.png", "table.heat_map.png"):
        assert (out / name).read_bytes()[:8] == PNG
    assert "table.pareto.png" in capsys.readouterr().out
    _, _, scene_out = scene_sweep  # no error measure: the heat map only
    assert main(["plot", "results", str(scene_out / "table.json"), "--out-dir", str(tmp_path / "figs")]) == 0
    assert (tmp_path / "figs" / "table.heat_map.png").read_bytes()[:8] == PNG
    assert not (tmp_path / "figs" / "table.pareto.png").exists()


@pytest.mark.slow
def test_tables_name_the_commit_that_ran_the_cells(tmp_path, monkeypatch):
    """A cell records the code that ran it (WARPSPH_COMMIT on a host whose copy has no .git); the sweep's table
    and the paper tables made later, in a checkout at another commit, name that commit, not their own. A cell
    from before the key: the table says the commit is its own."""
    path = _scene_sweep(tmp_path, axes={"models": [[]]}, time=0.05)
    monkeypatch.setenv("WARPSPH_COMMIT", "ran1234")
    run_sweep(path, tmp_path / "out", workers=1, log=lambda line: None)
    monkeypatch.setenv("WARPSPH_COMMIT", "later99")
    (_, record), = records(path, tmp_path / "out")
    assert record["commit"] == "ran1234"
    assert assemble(load_sweep(path), tmp_path / "out")["commit"] == "ran1234"
    meta, _ = paper_tables.load(path, tmp_path / "out")
    assert (meta["commit"], meta["commit_from"]) == ("ran1234", "cells")

    cell_file = next((tmp_path / "out" / "cells").glob("*.json"))
    old = json.loads(cell_file.read_text())
    del old["commit"]
    cell_file.write_text(json.dumps(old))
    table = assemble(load_sweep(path), tmp_path / "out")
    assert (table["commit"], table["commit_from"]) == ("later99", "table")
    meta, _ = paper_tables.load(path, tmp_path / "out")
    assert "this checkout's" in paper_tables.header({**meta, "device": "cpu", "warp": "1.19.0"})
