"""Fault injection (#38): a `warpsph run` killed (SIGKILL at frames a seeded generator picks, in the middle of a save,
between a save's temporary file and its rename, at random moments in a row) or interrupted (SIGINT, run and resume)
leaves a single-file cache that pxr opens with frames 0..j (j at least the checkpoint's frame), and `warpsph resume`
then ends with the frames and the final positions of an uninterrupted run, bit for bit (cpu runs are deterministic).
A cache resume cannot continue is one line, exit 2, nothing changed."""

import json
import os
import resource
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warpsph.cli import main
from conftest import tank_scene
from test_reliability import stats_frames

pytestmark = pytest.mark.slow  # each test kills or interrupts real runs in processes of their own and resumes them

SEED = 38
FRAMES = 40
EVERY = 3  # --checkpoint-every
SCENE = tank_scene(radius=0.03, domain=(0.6, 0.4, 0.2), block=(0.2, 0.3, 0.2), output={"fps": 50, "frames": FRAMES})
_rng = np.random.default_rng(SEED)
KILL_FRAMES = [int(k) for k in sorted(_rng.choice(np.arange(EVERY + 2, FRAMES - 4), size=4, replace=False))]
SIZE_LIMITS = [round(float(f), 3) for f in _rng.uniform(0.25, 0.85, size=3)]  # of the finished cache's size
RENAME_SAVE = int(_rng.integers(3, 12))  # the save killed between its temporary file and the rename
LOOP_DELAYS = [round(float(d), 3) for d in _rng.uniform(0.0, 0.4, size=3)]  # SIGKILLs in a row, after a checkpoint
SIGINT_FRAMES = sorted(int(k) for k in _rng.choice(np.arange(EVERY + 2, FRAMES - 6), size=2, replace=False))


def points(path, frame):
    stage = Usd.Stage.Open(str(path))
    return np.array(UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr().Get(frame))


def frames_in(path):
    """The frames of the cache ``path``, opened with pxr (fails the test if pxr cannot open it)."""
    stage = Usd.Stage.Open(str(path))
    return [int(t) for t in UsdGeom.Points(stage.GetPrimAtPath("/World/Fluid")).GetPointsAttr().GetTimeSamples()]


def checkpoint_frame(path):
    with h5py.File(path, "r") as f:
        return int(f.attrs["frame"])


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted run: its scene file, final positions and cache size."""
    folder = tmp_path_factory.mktemp("reference")
    scene = folder / "scene.json"
    scene.write_text(json.dumps(SCENE))
    out = folder / "long.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--checkpoint-every", str(EVERY), "-q"]) == 0
    assert frames_in(out) == list(range(FRAMES + 1))
    return {"scene": scene, "final": points(out, FRAMES), "size": out.stat().st_size}


def start(tmp_path, reference, *argv, script=None, limit=None, killed=True, group=False, env=None, compiled=True):
    """`warpsph run` of the reference scene into tmp_path/long.usdc (or ``argv`` after the verb) in a child process;
    ``script`` runs instead of the CLI's main (it calls main itself). ``limit`` caps the size of any file it writes:
    the write that crosses it kills the child (SIGXFSZ), or with ``killed`` False fails (EFBIG, as Python has it);
    with ``compiled`` the same command runs first to its end without the limit, in a folder of its own, so that
    the limit meets the cache's saves and not Warp's kernel compiles (a module's hash in this test process may
    differ from a fresh process's, and a module may load only at a later step: a re-sort, a checkpoint).
    ``group``: the child leads a process group of its own (with its mesher workers: os.killpg kills them all).
    ``env``: variables set in the child."""
    argv = argv or ("run", str(reference["scene"]), "--out", str(tmp_path / "long.usdc"), "--checkpoint-every", str(EVERY))
    code = script or "import sys; from warpsph.cli import main; sys.exit(main(sys.argv[1:]))"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONDONTWRITEBYTECODE": "1", **(env or {})}
    if limit and compiled and not script:
        warm = tmp_path / "compiled"
        warm.mkdir()
        warm_argv = [str(warm / "long.usdc") if a == str(tmp_path / "long.usdc") else a for a in argv]
        subprocess.run([sys.executable, "-c", code, *warm_argv, "--device", "cpu", "-q"], env=env,
                       cwd=warm, check=True, capture_output=True)
    if limit and killed:  # Python ignores SIGXFSZ; a C program dies of it
        code = "import signal; signal.signal(signal.SIGXFSZ, signal.SIG_DFL)\n" + code

    def cap():
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.Popen([sys.executable, "-c", code, *argv, "--device", "cpu", "-q"], stderr=subprocess.PIPE,
                            text=True, env=env, cwd=tmp_path, preexec_fn=cap if limit else None, start_new_session=group)


def wait_rows(stats, rows, proc):
    """Waits until the stats CSV holds ``rows`` frames (or the child ended)."""
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if stats.exists() and len(stats.read_text().splitlines()) - 1 >= rows:
            return
        time.sleep(0.01)


def check_killed(tmp_path, cache="long.partial.usdc"):
    """The cache a killed run left (under its final name if the run had finished it): pxr opens it, frames 0..j, j at
    least the checkpoint's frame; returns j."""
    done = frames_in(tmp_path / cache if (tmp_path / cache).exists() else tmp_path / "long.usdc")
    assert done == list(range(len(done))) and done, done
    checkpoint = checkpoint_frame(tmp_path / "long.checkpoint.h5")
    assert checkpoint <= done[-1], (checkpoint, done[-1])
    assert done[-1] <= len(stats_frames(tmp_path / "long.stats.csv"))  # the row follows its frame's save
    return done[-1]


def resume_to_the_end(tmp_path, reference):
    """`warpsph resume` finishes the run: every frame once, the uninterrupted run's final positions."""
    out = tmp_path / "long.usdc"
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "-q"]) == 0
    assert frames_in(out) == list(range(FRAMES + 1))
    assert stats_frames(out.with_suffix(".stats.csv")) == list(range(FRAMES + 1))
    np.testing.assert_array_equal(points(out, FRAMES), reference["final"])
    assert sorted(p.name for p in tmp_path.glob("long*")) == ["long.checkpoint.h5", "long.stats.csv", "long.usdc"]


@pytest.mark.parametrize("frame", KILL_FRAMES)
def test_sigkill_at_a_frame_then_resume_matches_the_uninterrupted_run(tmp_path, reference, frame):
    proc = start(tmp_path, reference)
    wait_rows(tmp_path / "long.stats.csv", frame, proc)
    proc.kill()
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    check_killed(tmp_path)
    resume_to_the_end(tmp_path, reference)


SURFACE = ("--surface", "--surface-method", "preview")  # Warp's marching cubes: no pysplashsurf needed
SURFACE_KILLS = list(zip(KILL_FRAMES, [False, True, False, True]))  # (frame, --clips)


def samples(path, prim, attribute):
    """{frame: values} of ``prim``'s ``attribute`` in the cache ``path``."""
    stage = Usd.Stage.Open(str(path))
    attr = stage.GetPrimAtPath(prim).GetAttribute(attribute)
    return {int(t): np.array(attr.Get(t)) for t in attr.GetTimeSamples()}


@pytest.fixture(scope="module")
def surface_reference(reference, tmp_path_factory):
    """The uninterrupted run --surface (preview), single file and --clips: the cache of each."""
    caches = {}
    for clips in (False, True):
        out = tmp_path_factory.mktemp("surface_clips" if clips else "surface") / "long.usdc"
        assert main(["run", str(reference["scene"]), "--device", "cpu", "--out", str(out), "--checkpoint-every",
                     str(EVERY), *SURFACE, *(["--clips"] if clips else []), "-q"]) == 0
        assert sorted(samples(out, "/World/FluidSurface", "points")) == list(range(FRAMES + 1))
        caches[clips] = out
    return caches


@pytest.mark.parametrize("frame, clips", SURFACE_KILLS)
def test_sigkill_of_a_surface_run_then_resume_matches_the_uninterrupted_particles_and_meshes(
        tmp_path, reference, surface_reference, frame, clips):
    """run --surface SIGKILLed (its process group) at a seeded frame: the cache opens with frames 0..j and the mesh of every frame up to
    the checkpoint's; resume ends with the uninterrupted run's particles and meshes in every frame, bit for bit.
    Before, a checkpoint did not wait for the meshes in flight: the frames meshed after it were lost with the kill,
    and the resumed run, which meshes only the frames after the checkpoint, left them without a mesh."""
    out = tmp_path / "long.usdc"
    clip = ["--clips"] if clips else []
    proc = start(tmp_path, reference, "run", str(reference["scene"]), "--out", str(out), "--checkpoint-every",
                 str(EVERY), *SURFACE, *clip, group=True)
    wait_rows(tmp_path / "long.stats.csv", frame, proc)
    os.killpg(proc.pid, signal.SIGKILL)  # the run and its mesher workers (`kill -9 -PGID`)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    checkpoint = checkpoint_frame(out.with_suffix(".checkpoint.h5"))
    if clips:  # the frame layers, each readable with its particles and (up to the checkpoint) its mesh
        layers = sorted(p for p in (tmp_path / "long.clips").glob("frame.*.usdc") if ".tmp." not in p.name)
        assert [p.name for p in layers] == [f"frame.{k:06d}.usdc" for k in range(len(layers))]
        assert len(layers) > checkpoint
        for k, layer in enumerate(layers[:checkpoint + 1]):
            assert list(samples(layer, "/World/Fluid", "points")) == [k]
            assert list(samples(layer, "/World/FluidSurface", "points")) == [k], (k, checkpoint)
    else:
        check_killed(tmp_path)
        meshed = sorted(samples(tmp_path / "long.partial.usdc", "/World/FluidSurface", "points"))
        assert meshed[:checkpoint + 1] == list(range(checkpoint + 1)), (meshed, checkpoint)
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "-q"]) == 0
    for prim, attribute in [("/World/Fluid", "points"), ("/World/Fluid", "velocities"),
                            ("/World/FluidSurface", "points"), ("/World/FluidSurface", "faceVertexIndices")]:
        got, want = samples(out, prim, attribute), samples(surface_reference[clips], prim, attribute)
        assert sorted(got) == sorted(want) == list(range(FRAMES + 1)), (prim, attribute)
        for k in want:
            np.testing.assert_array_equal(got[k], want[k], err_msg=f"{prim}.{attribute} at frame {k}")
    expected = ["long.checkpoint.h5", "long.stats.csv", "long.usdc"]
    if clips:
        expected = sorted(expected + ["long.clips", "long.manifest.usdc", "long.topology.usdc"])
    assert sorted(p.name for p in tmp_path.glob("long*")) == expected


@pytest.mark.parametrize("share, killed", list(zip(SIZE_LIMITS, [True, True, False])))
def test_killed_or_failing_in_the_middle_of_a_save(tmp_path, reference, share, killed):
    """A file-size limit stops the run inside the write that crosses it, a save of the cache: SIGXFSZ kills it, or the
    write fails (EFBIG, like a full disk or a quota half-way). An in-place save (before #38) had written new values
    over the table of contents and not yet the header: USD could not open the cache."""
    proc = start(tmp_path, reference, limit=int(share * reference["size"]), killed=killed)
    _, err = proc.communicate(timeout=120)
    if killed:
        assert proc.returncode == -signal.SIGXFSZ, err
        check_killed(tmp_path)
        assert list(tmp_path.glob("long.partial.tmp.*"))  # the save it was in
    else:
        assert proc.returncode == 2, err
        check_killed(tmp_path, "long.usdc")
        assert "USD could not write long.partial.tmp.usdc: File too large" in err and "keeps the frames before" in err
        assert len(err.splitlines()) == 1
    resume_to_the_end(tmp_path, reference)


KILL_BEFORE_RENAME = textwrap.dedent("""
    import os, signal, sys
    from warpsph.io import usd
    fsync, saves = usd.fsync, []
    def kill_before_rename(path):
        fsync(path)
        if str(path).endswith(".tmp.usdc"):
            saves.append(path)
            if len(saves) == int(os.environ["KILL_AT_SAVE"]):
                os.kill(os.getpid(), signal.SIGKILL)  # the temporary file is whole and synced, not yet renamed
    usd.fsync = kill_before_rename
    from warpsph.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def test_killed_between_the_temporary_file_and_the_rename(tmp_path, reference, monkeypatch):
    monkeypatch.setenv("KILL_AT_SAVE", str(RENAME_SAVE))
    proc = start(tmp_path, reference, script=KILL_BEFORE_RENAME)
    proc.communicate(timeout=120)
    assert proc.returncode == -signal.SIGKILL
    last = check_killed(tmp_path)
    assert frames_in(tmp_path / "long.partial.tmp.usdc")[-1] > last  # the newer whole copy, left out
    resume_to_the_end(tmp_path, reference)


KILL_AT_FIRST_FRAME = textwrap.dedent("""
    import os, signal, sys
    from warpsph.io import usd
    def killed(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGKILL)  # the cache is made, frame 0 not written
    usd.UsdPointCache.write_frame = killed
    from warpsph.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def test_killed_before_the_first_frame_then_run_again_with_overwrite(tmp_path, reference):
    """Killed after the cache was made and before frame 0: the file USD had created at once was an empty layer
    without warpsph's mark, and `run --overwrite` refused it as not written by warpsph. Now it is made whole."""
    proc = start(tmp_path, reference, script=KILL_AT_FIRST_FRAME)
    proc.communicate(timeout=120)
    assert proc.returncode == -signal.SIGKILL
    assert frames_in(tmp_path / "long.partial.usdc") == []
    out = tmp_path / "long.usdc"
    assert main(["run", str(reference["scene"]), "--device", "cpu", "--out", str(out), "--overwrite", "-q"]) == 0
    assert frames_in(out) == list(range(FRAMES + 1))
    np.testing.assert_array_equal(points(out, FRAMES), reference["final"])


def test_sigkill_at_random_moments_in_a_row(tmp_path, reference):
    """SIGKILL a run, then each resume of it, at random moments (seeded) after a checkpoint: whatever it was doing
    (stepping, saving the cache, writing the checkpoint), the next resume goes on from what is on disk."""
    stats = tmp_path / "long.stats.csv"
    proc = start(tmp_path, reference)
    for delay in LOOP_DELAYS:
        rows = len(stats_frames(stats)) if stats.exists() else 0
        wait_rows(stats, rows + EVERY + 1, proc)
        time.sleep(delay)
        proc.kill()
        proc.communicate(timeout=60)
        if proc.returncode == 0:  # it finished first
            break
        assert proc.returncode == -signal.SIGKILL
        check_killed(tmp_path)
        proc = start(tmp_path, reference, "resume", str(tmp_path / "long.checkpoint.h5"))
    else:
        proc.kill()
        proc.communicate(timeout=60)
    if proc.returncode == 0:
        assert frames_in(tmp_path / "long.usdc") == list(range(FRAMES + 1))
        np.testing.assert_array_equal(points(tmp_path / "long.usdc", FRAMES), reference["final"])
    else:
        check_killed(tmp_path)
        resume_to_the_end(tmp_path, reference)


def test_sigint_during_run_and_during_resume(tmp_path, reference):
    """Ctrl-C at a random frame of the run, then of its resume: each stops with 130 and a cache under the final name
    holding frames 0..F, F the checkpoint's frame; the last resume matches the uninterrupted run."""
    out, stats = tmp_path / "long.usdc", tmp_path / "long.stats.csv"
    proc = start(tmp_path, reference)
    for frame in SIGINT_FRAMES:
        wait_rows(stats, max(frame, len(stats_frames(stats)) + 2 if stats.exists() else 0), proc)  # past the set-up
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
        assert frames_in(out) == list(range(checkpoint_frame(out.with_suffix(".checkpoint.h5")) + 1))
        assert not (tmp_path / "long.partial.usdc").exists()
        proc = start(tmp_path, reference, "resume", str(out.with_suffix(".checkpoint.h5")))
    proc.kill()
    proc.communicate(timeout=60)
    resume_to_the_end(tmp_path, reference)


def snapshot(folder):
    return {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.iterdir())}


def short_run(tmp_path, frames):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(tank_scene(radius=0.05, output={"frames": frames})))
    out = tmp_path / "o.usdc"
    assert main(["run", str(scene), "--device", "cpu", "--out", str(out), "--checkpoint-every", "1", "-q"]) == 0
    return out


def test_resume_goes_on_from_the_copy_that_holds_the_checkpoints_frames(tmp_path):
    """A damaged OUT.usdc beside a readable OUT.partial.usdc holding frames 0..F: resume continues the readable one
    (it replaced the partial copy with the damaged one and stopped)."""
    out = short_run(tmp_path, 3)
    partial = tmp_path / "o.partial.usdc"
    partial.write_bytes(out.read_bytes())
    out.write_bytes(out.read_bytes()[:1000])
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "--frames", "5", "-q"]) == 0
    assert frames_in(out) == list(range(6)) and not partial.exists()


def test_resume_of_a_cache_behind_its_checkpoint_says_what_is_lost_and_changes_nothing(tmp_path, capsys):
    """A readable cache that ends before the checkpoint's frame (an older copy put back): resume went on and left a
    hole (frames 3..4 missing). Now: one line naming the file and the frames lost, exit 2, every file as it was (a
    cache USD cannot open: test_reliability's test_resume_of_a_damaged_cache_says_so)."""
    out = short_run(tmp_path, 4)
    assert main(["run", str(tmp_path / "scene.json"), "--device", "cpu", "--out", str(tmp_path / "early.usdc"),
                 "--frames", "2", "-q"]) == 0
    os.replace(tmp_path / "early.usdc", out)  # frames 0..2 of the 0..4 the checkpoint follows
    for p in tmp_path.glob("early.*"):
        p.unlink()
    capsys.readouterr()
    before = snapshot(tmp_path)
    assert main(["resume", str(out.with_suffix(".checkpoint.h5")), "--device", "cpu", "--frames", "6", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(out) in err and "o.usdc holds frames 0..2, not frames 3..4" in err, err
    assert "frames 0..4 cannot be recovered" in err and "Traceback" not in err
    assert snapshot(tmp_path) == before



def _children(pid):
    """The pids of ``pid``'s child processes (Linux: /proc/PID/task/*/children)."""
    found = set()
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            found.update(int(c) for c in open(f"/proc/{pid}/task/{task}/children").read().split())
        except OSError:
            pass
    return found


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (not yet reaped by its new parent) counts as gone
        return open(f"/proc/{pid}/stat").read().split(") ")[1].split()[0] != "Z"
    except OSError:
        return False


def test_sigkill_of_a_run_with_its_cache_in_a_process_of_its_own(tmp_path, reference):
    """run --cache-process, SIGKILLed alone (as the out-of-memory killer does): the cache's writer process exits
    with it, the cache opens with frames 0..j past the checkpoint, and resume ends as the uninterrupted run."""
    proc = start(tmp_path, reference, "run", str(reference["scene"]), "--out", str(tmp_path / "long.usdc"),
                 "--checkpoint-every", str(EVERY), "--cache-process")
    wait_rows(tmp_path / "long.stats.csv", KILL_FRAMES[1], proc)
    children = _children(proc.pid)
    assert children  # the writer (and multiprocessing's resource tracker)
    proc.kill()
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    deadline = time.time() + 20
    while time.time() < deadline and any(_alive(c) for c in children):
        time.sleep(0.05)
    assert not [c for c in children if _alive(c)]
    check_killed(tmp_path)
    resume_to_the_end(tmp_path, reference)


def test_a_failing_save_in_the_cache_s_process_stops_the_run_in_one_line(tmp_path, reference):
    """The file-size limit (EFBIG, like a full disk half-way) hits a save in the writer process: the run stops
    (exit 2) with the same one line as a cache in the run's own process, the cache keeps the frames before."""
    proc = start(tmp_path, reference, "run", str(reference["scene"]), "--out", str(tmp_path / "long.usdc"),
                 "--checkpoint-every", str(EVERY), "--cache-process", limit=int(SIZE_LIMITS[0] * reference["size"]),
                 killed=False)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    check_killed(tmp_path, "long.usdc")
    assert "USD could not write long.partial.tmp.usdc: File too large" in err and "keeps the frames before" in err
    assert len(err.splitlines()) == 1, err
    resume_to_the_end(tmp_path, reference)


def test_a_full_disk_at_the_kernel_compile_stops_the_run_in_one_line(tmp_path, reference):
    """A first run on an empty kernel cache whose disk is full (the file-size limit, EFBIG, hits Warp's compile):
    one line that names the kernel cache, exit 2, no output written; not Warp's traceback."""
    cache = tmp_path / "kernels"
    proc = start(tmp_path, reference, limit=4096, killed=False, env={"WARP_CACHE_PATH": str(cache)}, compiled=False)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert str(cache) in err and "kernel cache" in err and "File too large" in err, err
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith("long")]
