"""Sweep functions for tests/test_reliability.py (imported by name in the cells' spawned processes)."""

import os
import signal


def die_or_square(device, x):
    """x * x, except x = 2, whose process kills itself with SIGKILL (as the out-of-memory killer would), unless
    the file named by SWEEP_TEST_SURVIVE exists."""
    if x == 2 and not os.path.exists(os.environ.get("SWEEP_TEST_SURVIVE", "/nonexistent")):
        os.kill(os.getpid(), signal.SIGKILL)
    return {"square": x * x}


def ray_placed(device, viscosity, steps=3):
    """A tiny scene (a tank of 125 particles, ``steps`` steps) run on ``device``, with where Ray ran it: the
    resources Ray assigned the task, its GPU ids, node, worker, task and process (tests/test_sweep.py checks
    these against what warpsph asked for: its sweep's cells are Ray tasks)."""
    import ray

    from warpsph.scene import scene_from_dict
    from warpsph.simulation import Simulation

    sim = Simulation(scene_from_dict({"name": "placed", "particle_radius": 0.05, "fluid": {"viscosity": viscosity},
                                      "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
                                      "fluid_blocks": [{"start": [0, 0, 0], "end": [0.5, 0.5, 0.5]}]}), device=device)
    for _ in range(steps):
        sim.step()
    context = ray.get_runtime_context()
    return {"particles": sim.num_fluid, "steps": sim.step_count, "resources": context.get_assigned_resources(),
            "gpu_ids": [str(g) for g in ray.get_gpu_ids()], "node_id": context.get_node_id(),
            "worker_id": context.get_worker_id(), "task_id": context.get_task_id(), "pid": os.getpid()}
