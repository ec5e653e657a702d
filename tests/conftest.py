"""Shared test helpers: the device list (cpu always, cuda when present) and tiny scenes."""

import os

import warp as wp

wp.config.log_level = wp.LOG_WARNING
wp.init()

from warpsph.scene import scene_from_dict  # noqa: E402
from warpsph.simulation import Simulation  # noqa: E402


def devices():
    out = ["cpu"]
    if wp.is_cuda_available():
        out.append("cuda:0")
    return out


def pytest_generate_tests(metafunc):
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", devices())


def tank_scene(radius=0.02, domain=(0.4, 0.6, 0.4), block=(0.4, 0.4, 0.4), **overrides):
    """A box of water resting on the floor of a closed tank (all in metres)."""
    data = {
        "name": "tank",
        "particle_radius": radius,
        "domain": {"min": [0.0, 0.0, 0.0], "max": list(domain)},
        "fluid_blocks": [{"start": [0.0, 0.0, 0.0], "end": list(block)}],
    }
    data.update(overrides)
    return data


def make_sim(data, device="cpu", base_dir=None, **kwargs):
    return Simulation(scene_from_dict(data, base_dir=base_dir), device=device, **kwargs)


SCENES_DIR = os.path.join(os.path.dirname(__file__), "..", "scenes")


def fail_frame_writes(monkeypatch, clips, frame, error):
    """Makes the USD cache (single file or clips) raise ``error`` when it writes ``frame``; returns the cache
    class and its own write_frame, to put back."""
    from warpsph.io import usd

    cls = usd.UsdClipCache if clips else usd.UsdPointCache
    original = cls.write_frame

    def write_frame(self, n, *args, **kwargs):
        if n == frame:
            raise error
        return original(self, n, *args, **kwargs)

    monkeypatch.setattr(cls, "write_frame", write_frame)
    return cls, original


def interrupt_a_long_run(tmp_path, script, *options, pause):
    """Runs ``python -c script run SCENE --out long.usdc --quiet OPTIONS`` on a 400-frame tank in a child process,
    sends it SIGINT ``pause`` seconds after its stats CSV holds two frames, and returns (out, exit code, stderr)."""
    import json
    import signal
    import subprocess
    import sys
    import time

    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2),
                                           output={"fps": 50, "frames": 400})))
    out = tmp_path / "long.usdc"
    proc = subprocess.Popen([sys.executable, "-c", script, "run", str(scene), "--device", "cpu", "--out", str(out),
                             "--quiet", *options], stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"}, cwd=tmp_path)
    stats = out.with_suffix(".stats.csv")
    deadline = time.time() + 120
    while time.time() < deadline and (not stats.exists() or len(stats.read_text().splitlines()) < 3):
        time.sleep(0.05)
    time.sleep(pause)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    return out, proc.returncode, err


def signal_group(proc, sig, timeout=60):
    """Sends ``sig`` to the process group of ``proc`` (started with ``start_new_session``), as a terminal's Ctrl-C
    does, and waits for it; a group still there after ``timeout`` s (or an error) is killed. Returns its stderr."""
    import os
    import signal

    try:
        os.killpg(proc.pid, sig)
        _, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return err


def as_in_a_terminal():
    """``preexec_fn`` of a child that a test interrupts as a terminal's Ctrl-C would: SIGINT at its default, so
    Python raises KeyboardInterrupt (a shell's background job, such as CI started with ``&``, has it ignored, and
    the child inherits that)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def by_id(sim):
    """A simulation's (or decomposed simulation's) positions in particle-id order."""
    import numpy as np

    return sim.positions()[np.argsort(sim.ids(), kind="stable")]


def shuffled(scene, device):
    """One domain whose rows start in another order: how far float sums in another order alone drift."""
    import numpy as np

    sim = Simulation(scene, device=device)
    order = np.random.default_rng(0).permutation(sim.num_fluid)
    return Simulation(scene, device=device, particles=(sim.positions()[order], sim.velocities()[order], sim.ids()[order]))
