"""One simulation over MPI processes (warpsph.distributed, issue #40): `mpiexec -n 2` on the CPU, a subdomain each,
against the same two subdomains in one process (threads) and against one domain."""

import importlib.util
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from warpsph import DecomposedSimulation, Simulation, scene_from_dict
from conftest import SCENES_DIR, by_id, shuffled

RADIUS = 0.04
STEPS = 40  # two frames at 25 fps
ROOT = os.path.join(os.path.dirname(__file__), "..")


def mpiexec():
    """The mpiexec beside this Python (the mpich wheel's, in the venv), else the one on PATH."""
    here = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    return here if os.path.exists(here) else shutil.which("mpiexec")


def missing():
    """Why the MPI test cannot run here, or None."""
    if importlib.util.find_spec("mpi4py") is None:
        return "mpi4py is not installed (pip install 'warpsph[distributed]')"
    try:
        importlib.import_module("mpi4py.MPI")  # loads libmpi
    except (ImportError, RuntimeError) as exc:
        return f"mpi4py finds no MPI library ({exc}; pip install 'warpsph[distributed]': the mpich wheel)"
    if mpiexec() is None:
        return "no mpiexec (pip install 'warpsph[distributed]': the mpich wheel has one)"
    return None


def dam_break_data():
    """The dam break with VR (3,600 particles at r = 4 cm) at a fixed dt. Cut along y (the column falls through the
    cut, so particles migrate every few steps; along the default x nothing crosses in 40 steps)."""
    with open(os.path.join(SCENES_DIR, "dam_break.json")) as f:
        data = json.load(f)
    data.update(particle_radius=RADIUS, models=[{"type": "vorticity_refinement"}])
    data["time"]["fixed_dt"] = 0.002
    return data


def test_a_missing_mpi4py_names_the_extra(monkeypatch):
    """Without mpi4py the distributed run says which extra to install."""
    from warpsph import distributed

    monkeypatch.setitem(sys.modules, "mpi4py", None)  # import mpi4py raises ImportError
    with pytest.raises(distributed.MissingMPI, match=r"warpsph\[distributed\]"):
        distributed.mpi()
    assert distributed.main(["scene.json"]) == 2


@pytest.mark.slow
def test_two_mpi_processes_match_two_subdomains_in_one_process(tmp_path):
    """Two frames (40 steps) of the dam break on two MPI processes; rank 0 writes the cache and the last frame."""
    reason = missing()
    if reason is not None:
        pytest.skip(reason)
    data = dam_break_data()
    scene_file = tmp_path / "dam_break.json"
    scene_file.write_text(json.dumps(data))
    out = tmp_path / "positions.npz"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.abspath(ROOT), os.environ.get("PYTHONPATH", "")])}
    command = [mpiexec(), "-n", "2", sys.executable, "-m", "warpsph.distributed", str(scene_file), "--device", "cpu",
               "--frames", "2", "--axis", "1", "--rebalance-interval", "10", "--positions", str(out),
               "--out", str(tmp_path / "out.usdc")]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert [line.split()[1] for line in done.stderr.splitlines() if line.startswith("frame ")] == ["0/2", "1/2", "2/2"]
    mpi = np.load(out)
    assert int(mpi["steps"]) == STEPS and int(mpi["arrived"]) > 0  # particles crossed between the processes
    assert min(mpi["owned"]) > 0

    scene = scene_from_dict(data, base_dir=SCENES_DIR)
    threads = DecomposedSimulation(scene, ["cpu"], subdomains=2, axis=1, rebalance_interval=10)
    one, other_order = Simulation(scene, device="cpu"), shuffled(scene, "cpu")
    for _ in range(STEPS):
        for sim in (threads, one, other_order):
            sim.step()
    assert np.array_equal(mpi["ids"], np.sort(threads.ids()))
    assert list(mpi["owned"]) == threads.owned_counts()
    assert int(mpi["arrived"]) == sum(s.arrived for s in threads.subdomains)
    # the same kernels, rows in the same order and the reductions summed in the same (subdomain) order: on the CPU
    # the processes' particles are the threads' bit for bit (measured: 0.0 m apart after 40 steps and 576 migrations)
    assert np.array_equal(mpi["x"], by_id(threads)) and np.array_equal(mpi["v"], threads.velocities())
    # against one domain: no further than rounding puts one domain whose rows start in another order, as
    # tests/test_decomposition.py allows (measured after 40 steps: 3.5e-4 m from one domain, the reordered one 1.6e-4 m;
    # 2.1e-6 and 2.0e-6 m after 10 steps, when the collapse has not yet amplified the float noise)
    drift = np.abs(mpi["x"] - by_id(one)).max()
    assert drift < max(3 * np.abs(by_id(other_order) - by_id(one)).max(), 1e-5) and drift < 0.25 * RADIUS

    from pxr import Usd  # rank 0 wrote the cache: the first frame's particles and the last's

    stage = Usd.Stage.Open(str(tmp_path / "out.usdc"))
    fluid = stage.GetPrimAtPath("/World/Fluid")
    assert len(fluid.GetAttribute("points").Get(0)) == len(mpi["ids"])


def test_each_rank_takes_its_hosts_gpu_of_its_local_rank(monkeypatch):
    """rank_device: cuda:<local rank> modulo the host's GPUs for "cuda" or no device where CUDA is available."""
    import types

    import warp as wp

    from warpsph.distributed import rank_device

    monkeypatch.setattr(wp, "is_cuda_available", lambda: True)
    monkeypatch.setattr(wp, "get_cuda_device_count", lambda: 2)
    assert [rank_device(types.SimpleNamespace(local_rank=k)) for k in range(3)] == ["cuda:0", "cuda:1", "cuda:0"]
    assert rank_device(types.SimpleNamespace(local_rank=1), "cuda") == "cuda:1"
    assert rank_device(types.SimpleNamespace(local_rank=1), "cuda:0") == "cuda:0"
    monkeypatch.setattr(wp, "is_cuda_available", lambda: False)
    assert rank_device(types.SimpleNamespace(local_rank=1)) == "cpu"


@pytest.mark.slow
def test_the_mpi_benchmark_writes_ms_per_step_and_each_ranks_time_in_the_communicator(tmp_path):
    """--particles / --steps / --bench-json: bench steps' scene and timing over two processes (about 4 s)."""
    reason = missing()
    if reason is not None:
        pytest.skip(reason)
    out = tmp_path / "bench.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.abspath(ROOT), os.environ.get("PYTHONPATH", "")]),
           "WARPSPH_COMMIT": "abc1234"}
    scene = os.path.join(SCENES_DIR, "dam_break.json")
    command = [mpiexec(), "-n", "2", sys.executable, "-m", "warpsph.distributed", scene, "--particles", "1000",
               "--model", "none", "--warmup", "1", "--steps", "2", "--bench-json", str(out), "--device", "cpu", "-q"]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(out.read_text())
    assert json.loads(done.stdout) == result  # rank 0 prints what it writes
    assert result["ranks"] == 2 and result["devices"] == ["cpu", "cpu"] and result["commit"] == "abc1234"
    assert result["model"] == "none" and 500 < result["fluid_particles"] < 2000
    assert sum(result["particles_per_subdomain"]) == result["fluid_particles"]
    assert result["steps_total"] == 1 + 2 + 2 and result["ms_per_step"] > 0
    for seconds, calls in zip(result["comm_seconds_per_rank"], result["comm_calls_per_rank"]):
        assert set(seconds) == set(calls) == {"counts", "transfer", "exchange", "allreduce"}
        assert calls["counts"] == 2 * 2 and calls["exchange"] > 2 and all(s >= 0 for s in seconds.values())
        assert sum(seconds.values()) < 2 * result["ms_per_step"] / 1e3  # two timed steps
