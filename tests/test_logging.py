"""Output through the ``warpsph`` logger: -q/-v on every command, progress as a rich bar on a
terminal and as plain lines elsewhere, and nothing from a library run unless the program asks."""

import argparse
import json
import logging
import os
import pty
import select
import subprocess
import sys
import time

import pytest

from conftest import make_sim, tank_scene
from warpsph.cli import CUDA_DRIVER_WARNING, build_parser, main
from warpsph.log import NORMAL, QUIET, VERBOSE, verbosity

ANSI = "\x1b["
COMMANDS = [["run", "s.json"], ["resume", "o.checkpoint.h5"], ["plot", "energy", "o.usdc"], ["surface", "o.usdc"],
            ["validate", "taylor-green", "--resolutions", "8"], ["sweep", "s.json", "--out", "d"]]


def write_tank(tmp_path, frames=2, **keys):
    path = tmp_path / "tank.json"
    path.write_text(json.dumps(tank_scene(radius=0.05, output={"fps": 20, "frames": frames}, **keys)))
    return path


def run_tank(tmp_path, *flags, **keys):
    """``warpsph run`` on a 64-particle tank (2 frames, on the CPU)."""
    return main(["run", str(write_tank(tmp_path, **keys)), "--device", "cpu", "--out", str(tmp_path / "o.usdc"),
                 "--overwrite", *flags])


def subcommands(parser, path=()):
    """(command words, parser) of every subcommand under ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from subcommands(sub, (*path, name))


def test_every_command_takes_quiet_and_verbose_before_or_after_its_name():
    parser = build_parser()
    for words, sub in subcommands(parser):
        options = {o for a in sub._actions for o in a.option_strings}
        assert {"-q", "--quiet", "-v", "--verbose"} <= options, words
    for argv in COMMANDS:
        for flags, level in [([], NORMAL), (["-q"], QUIET), (["--quiet"], QUIET), (["-v"], VERBOSE),
                             (["--verbose"], VERBOSE)]:
            for line in (flags + argv, argv + flags):
                args = parser.parse_args(line)
                assert verbosity(args.quiet, args.verbose) == level, line


def test_quiet_shows_warnings_and_errors_only(tmp_path, capsys):
    assert run_tank(tmp_path, "--quiet", solver={"clamp_pressure": False}) == 0  # an obsolete key: a warning
    err = capsys.readouterr().err
    assert err.startswith("warpsph: warning: ") and "solver.clamp_pressure" in err
    assert all(line.startswith("warpsph: warning: ") for line in err.splitlines()), err
    assert main(["-q", "run", str(tmp_path / "missing.json"), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("warpsph: error: ") and "missing.json" in err and len(err.splitlines()) == 1, err


def test_verbose_adds_a_debug_line_per_frame(tmp_path, capsys):
    assert run_tank(tmp_path, "-v") == 0
    lines = capsys.readouterr().err.splitlines()
    timing = [line for line in lines if line.startswith("debug: frame ")]
    assert len(timing) == 3 and all(" s wall, " in line for line in timing), lines
    assert any(line.startswith("done: frame 2") for line in lines)


def test_the_warpsph_logger_records_the_run(tmp_path, caplog, capsys):
    assert run_tank(tmp_path) == 0
    messages = [r.getMessage() for r in caplog.records if r.name == "warpsph.cli" and r.levelno == logging.INFO]
    assert messages[0].startswith("tank on cpu: 64 fluid")
    assert any(m.startswith("done: frame 2, ") for m in messages)
    assert "warpsph: tank on cpu: 64 fluid" in capsys.readouterr().err  # shown as before


def test_progress_outside_a_terminal_is_plain_lines(tmp_path, caplog, capsys):
    """Captured stderr is no terminal: an info line per frame, never a bar, even with rich installed."""
    assert run_tank(tmp_path) == 0
    err = capsys.readouterr().err
    assert ANSI not in err and "\r" not in err
    progress = [r.getMessage() for r in caplog.records if r.getMessage().startswith("frame ")]
    assert [m.split()[1] for m in progress] == ["0/2", "1/2", "2/2"]
    assert all(f"{m}\n" in err for m in progress)


TERMINAL = """
import sys
if sys.argv.pop(1) == "without-rich":
    sys.modules["rich"] = None  # import rich fails
from warpsph.cli import main
sys.exit(main(sys.argv[1:]))
"""


def on_a_terminal(argv, cwd):
    """Runs ``argv`` with stderr on a pseudo-terminal; returns its exit code and what it wrote there."""
    master, slave = pty.openpty()
    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "100"}
    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave, env=env, cwd=cwd)
    os.close(slave)
    chunks, deadline = [], time.time() + 240
    try:
        while time.time() < deadline:
            if select.select([master], [], [], 0.5)[0]:
                try:
                    data = os.read(master, 65536)
                except OSError:  # EIO: the child closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        code = proc.wait(timeout=60)
    finally:
        os.close(master)
    return code, b"".join(chunks).decode(errors="replace").replace("\r\n", "\n")


@pytest.mark.slow
@pytest.mark.parametrize("rich", ["with-rich", "without-rich"])
def test_progress_on_a_terminal(tmp_path, rich):
    """A terminal gets a rich bar when rich is installed, else the plain lines."""
    if rich == "with-rich":
        pytest.importorskip("rich", reason="the progress bar needs rich (warpsph[rich]; the test extra installs it)")
    scene = write_tank(tmp_path)
    code, err = on_a_terminal([sys.executable, "-c", TERMINAL, rich, "run", str(scene), "--device", "cpu",
                               "--out", str(tmp_path / "o.usdc")], tmp_path)
    assert code == 0, err
    assert "warpsph: tank on cpu: " in err and "done: frame 2, " in err
    if rich == "with-rich":
        assert ANSI in err and "2/2" in err and "frame 2/2  t=" not in err
    else:
        assert ANSI not in err and "\r" not in err
        assert "\nframe 1/2  t=" in err and "\nframe 2/2  t=" in err


CHANNEL = {"name": "channel", "particle_radius": 0.02, "domain": {"min": [0, 0, 0], "max": [1.0, 0.4, 0.2]},
           "emitters": [{"min": [0, 0, 0], "max": [0.04, 0.2, 0.2], "velocity": [1.0, 0, 0]}],
           "output": {"fps": 20, "frames": 2}}  # room for 0.1 s of inflow: a longer run fills it

LIBRARY = f"""
import warpsph
sim = warpsph.Simulation(warpsph.Scene.from_dict({CHANNEL!r}), device="cpu")
sim.run(frames=5)
assert sim.inflow._warned
"""


@pytest.mark.slow
def test_a_library_run_logs_but_shows_nothing_by_default(tmp_path, caplog):
    sim = make_sim(CHANNEL)
    sim.run(frames=5)
    warned = [r for r in caplog.records if r.name == "warpsph.inflow" and r.levelno == logging.WARNING]
    assert len(warned) == 1 and "capacity" in warned[0].getMessage()
    done = subprocess.run([sys.executable, "-c", LIBRARY], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    shown = [line for line in (done.stdout + done.stderr).splitlines() if CUDA_DRIVER_WARNING not in line]
    assert shown == []


QUIET_LIBRARY = """
import logging, sys
setup = sys.argv[1]
if setup == "debug-logging":
    logging.basicConfig(level=logging.DEBUG, stream=sys.stderr)
if setup == "warp-first":  # the program imported Warp and chose its level before warpsph
    import warp as wp
    wp.config.log_level = wp.LOG_DEBUG
import warpsph
sim = warpsph.Simulation(warpsph.Scene.from_dict({scene!r}), device=sys.argv[2])
sim.run(frames=1)
import warp as wp
print("level", wp.config.log_level, file=sys.stderr)
"""


@pytest.mark.slow
@pytest.mark.parametrize("setup, banner, level", [("plain", False, 30), ("debug-logging", True, 20),
                                                   ("warp-first", True, 10)])
def test_the_library_prints_no_warp_banner_unless_asked(tmp_path, device, setup, banner, level):
    """``import warpsph; warpsph.Simulation(...)`` writes nothing on stdout: Warp's banner and module-load lines
    stay off unless the program shows warpsph's debug records or set Warp's level itself."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    script = QUIET_LIBRARY.format(scene=tank_scene(radius=0.05, output={"fps": 20, "frames": 1}))
    path = os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))  # the caller's paths kept after it
    done = subprocess.run([sys.executable, "-c", script, setup, device], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": path}, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"level {level}\n" in done.stderr
    assert ("Warp " in done.stdout and "initialized" in done.stdout) == banner, done.stdout
    if not banner:
        assert done.stdout == ""


def test_every_command_takes_log_before_or_after_its_name():
    parser = build_parser()
    for words, sub in subcommands(parser):
        assert "--log" in {o for a in sub._actions for o in a.option_strings}, words
    for argv in COMMANDS:
        assert parser.parse_args(argv).log is None
        for line in (["--log", "a.log"] + argv, argv + ["--log", "a.log"]):
            assert parser.parse_args(line).log == "a.log", line


@pytest.mark.parametrize("flags, shown, hidden", [([], [" INFO warpsph.cli: tank on cpu: 64 fluid"], ["DEBUG"]),
                                                  (["-v"], [" DEBUG warpsph.cli: frame 1: "], []),
                                                  (["-q"], [" WARNING warpsph: "], ["INFO"])])
def test_log_appends_the_records_to_a_file_and_still_shows_them(tmp_path, capsys, flags, shown, hidden):
    """--log FILE: the records at the level -q/-v chose, timed, in FILE (missing folders made, appended to);
    stderr shows them as without --log."""
    log_file = tmp_path / "logs" / "run.log"
    for n in range(2):  # each run its own scene file: Python shows a warning once per message
        (tmp_path / str(n)).mkdir()
        assert run_tank(tmp_path / str(n), *flags, "--log", str(log_file), solver={"clamp_pressure": False}) == 0
        err = capsys.readouterr().err
        assert "solver.clamp_pressure" in err and ("tank on cpu" in err) == (flags != ["-q"])
    text = log_file.read_text()
    lines = text.splitlines()
    assert all(line[:4].isdigit() and line[4] == "-" for line in lines if not line.startswith(" ")), text
    for words in shown:
        assert sum(words in line for line in lines) == 2, (words, text)  # both runs, appended
    for words in hidden:
        assert f" {words} " not in text, text


def test_a_log_file_that_cannot_be_written_is_named(tmp_path, capsys):
    assert main(["schema", "--log", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("warpsph: error: ") and "--log" in err and "directory" in err, err
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["--log", str(blocker / "run.log"), "schema"]) == 2
    err = capsys.readouterr().err
    assert "--log" in err and str(blocker) in err, err
    assert not logging.getLogger("warpsph").handlers[1:], "no handler left behind"
