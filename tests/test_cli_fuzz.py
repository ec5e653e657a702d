"""Everything a user types or hands over ends in a result or a clear error (exit 2), never a traceback:
ordinary mistakes one by one, then random command lines and damaged scene, mesh and checkpoint files."""

import json

import h5py
import pytest
import trimesh
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from warpsph.cli import main
from conftest import tank_scene

SCENE = tank_scene(radius=0.05, output={"frames": 1})
BOX = trimesh.creation.box(extents=[0.12, 0.12, 0.12])
OBSTACLE = {"mesh": "box.obj", "translation": [0.2, 0.5, 0.2]}
FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def cli(argv):
    """main's exit code; argparse's own usage errors exit 2 through SystemExit."""
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


def workspace(root):
    """A folder with a good scene, a scene with a mesh, a finished run and some things that are not scenes."""
    root.mkdir(exist_ok=True)
    (root / "good.json").write_text(json.dumps(SCENE))
    (root / "mesh.json").write_text(json.dumps({**SCENE, "obstacles": [OBSTACLE]}))
    BOX.export(root / "box.obj")
    (root / "folder").mkdir(exist_ok=True)
    (root / "notes.txt").write_text("mine")
    return root


def outputs(root):
    return sorted(p.name for p in root.rglob("*") if p.name.startswith("o.") or p.name.startswith("o_"))


MISTAKES = {  # name: (files to write, command line, words the error must contain)
    "scene not UTF-8": ({"s.json": b"\xff\xfe{\x00}"}, ["run", "s.json"], "UTF-8"),
    "scene nested too deeply": ({"s.json": b"[" * 100000}, ["run", "s.json"], "nested"),
    "scene empty": ({"s.json": b""}, ["run", "s.json"], "not valid JSON"),
    "scene is a folder": ({}, ["run", "folder"], "cannot read"),
    "--out extension": ({}, ["run", "good.json", "--out", "o.txt"], "--out"),
    "--out under a file": ({}, ["run", "good.json", "--out", "notes.txt/o.usdc"], "not a directory"),
    "--out a folder": ({}, ["run", "good.json", "--out", "folder"], "directory"),
    "--device unknown": ({}, ["run", "good.json", "--device", "gpu0"], "--device"),
    "--device number": ({}, ["run", "good.json", "--device", "cuda:99"], "--device"),
    "--scale nan": ({}, ["run", "good.json", "--scale", "nan"], "--scale"),
    "--checkpoint-every negative": ({}, ["run", "good.json", "--checkpoint-every", "-1"], "--checkpoint-every"),
    "--preview negative": ({}, ["run", "good.json", "--preview", "-5"], "--preview"),
    "mesh of random bytes": ({"box.obj": bytes(range(256)) * 3}, ["run", "mesh.json"], "box.obj"),
    "mesh as text": ({"box.obj": "mesh".encode()}, ["run", "mesh.json"], "box.obj"),
    "mesh STL of random bytes": ({"box.stl": bytes(range(7, 250)) * 5, "m.json": json.dumps(
        {**SCENE, "obstacles": [{**OBSTACLE, "mesh": "box.stl"}]}).encode()}, ["run", "m.json"], "box.stl"),
    "mesh PLY header only": ({"box.ply": b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n", "m.json": json.dumps(
        {**SCENE, "obstacles": [{**OBSTACLE, "mesh": "box.ply"}]}).encode()}, ["run", "m.json"], "box.ply"),
    "mesh with a NaN vertex": ({"box.obj": b"v nan 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 2 3\nf 1 2 4\n"},
                               ["run", "mesh.json"], "box.obj"),
    "resume a scene file": ({}, ["resume", "good.json"], "checkpoint"),
    "resume a missing file": ({}, ["resume", "o.checkpoint.h5"], "o.checkpoint.h5"),
    "plot a missing cache": ({}, ["plot", "slice", "o.usdc"], "o.usdc"),
    "plot a scene file": ({}, ["plot", "energy", "notes.txt"], "notes"),
}


@pytest.mark.parametrize("name", MISTAKES)
def test_an_ordinary_mistake_is_a_clear_error(tmp_path, monkeypatch, capsys, name):
    files, argv, words = MISTAKES[name]
    monkeypatch.chdir(workspace(tmp_path))
    for path, data in files.items():
        (tmp_path / path).write_bytes(data)
    device = ["--device", "cpu"] if argv[0] in ("run", "resume") and "--device" not in argv else []
    assert cli(argv + device) == 2
    err = capsys.readouterr().err
    assert "warpsph: error:" in err and words in err, err
    assert "No module named" not in err
    assert not outputs(tmp_path)


def test_a_damaged_checkpoint_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(workspace(tmp_path))
    assert cli(["run", "good.json", "--device", "cpu", "--out", "o.usdc", "--checkpoint-every", "1", "--quiet"]) == 0
    checkpoint = tmp_path / "o.checkpoint.h5"
    data = checkpoint.read_bytes()
    checkpoint.write_bytes(data[: len(data) // 2])  # cut short
    assert cli(["resume", checkpoint, "--device", "cpu"]) == 2
    with h5py.File(checkpoint, "w") as f:  # the marker without the contents
        f.attrs["format"] = "warpsph-checkpoint-1"
        f.attrs["scene"] = "{}"
    assert cli(["resume", checkpoint, "--device", "cpu"]) == 2
    assert capsys.readouterr().err.count("warpsph: error: ") == 2


OPTIONS = {
    "--out": st.sampled_from(["o.usdc", "o.usda", "o.usd", "o.txt", "o", "folder", "notes.txt", "notes.txt/o.usdc",
                              "new/o_sub.usdc", ""]),
    "--frames": st.integers(-2, 2).map(str),
    "--scale": st.sampled_from(["1", "0.5", "2", "0", "-1", "nan", "inf", "1e-9", "x"]),
    "--device": st.sampled_from(["cpu", "CPU", "cuda", "cuda:7", "auto", "", "tpu"]),
    "--checkpoint-every": st.integers(-2, 2).map(str),
    "--on-instability": st.sampled_from(["stop", "reduce-dt", "ignore"]),
    "--preview": st.sampled_from(["0", "-1", "x"]),
}
FLAGS = ["--dry-run", "--overwrite", "--clips", "--particles-h5"]


@st.composite
def command_lines(draw):
    command = draw(st.sampled_from(["run", "resume", "plot"]))
    if command == "plot":
        kind = draw(st.sampled_from(["energy", "slice"]))
        argv = ["plot", kind, draw(st.sampled_from(["o.usdc", "o.stats.csv", "good.json", "folder", "missing.usdc"]))]
        argv += ["--out", draw(st.sampled_from(["p.png", "p.pdf", "p.txt", "folder", "notes.txt/p.png", "new/p.png"]))]
        if kind == "slice":
            argv += ["--frame", str(draw(st.integers(-1, 3)))]
        return argv
    targets = {"run": ["good.json", "mesh.json", "missing.json", "folder", "notes.txt", "box.obj"],
               "resume": ["o.checkpoint.h5", "o.usdc", "good.json", "missing.h5", "folder"]}[command]
    argv = [command, draw(st.sampled_from(targets))]
    options = sorted(OPTIONS) if command == "run" else ["--frames", "--device"]
    for option in draw(st.lists(st.sampled_from(options), unique=True, max_size=4)):
        argv += [option, draw(OPTIONS[option])]
    if command == "run":
        argv += draw(st.lists(st.sampled_from(FLAGS), unique=True, max_size=3))
    if "--device" not in argv and draw(st.booleans()):
        argv += ["--device", "cpu"]
    return argv + ["--quiet"]


@FUZZ
@given(argv=command_lines(), finished=st.booleans())
def test_random_command_lines_run_or_say_why(tmp_path_factory, argv, finished):
    """``finished``: the folder holds a finished run o.usdc (with its checkpoint at frame 1)."""
    import os

    root = workspace(tmp_path_factory.mktemp("cli"))
    if finished:
        assert cli(["run", root / "good.json", "--device", "cpu", "--out", root / "o.usdc", "--checkpoint-every", "1",
                    "--quiet"]) == 0
    if argv[0] != "plot" and "--frames" not in argv:
        argv += ["--frames", "1"]
    cwd = os.getcwd()
    os.chdir(root)
    try:
        code = cli(argv)
    finally:
        os.chdir(cwd)
    event(f"{argv[0]}: exit {code}")
    assert code in (0, 2), argv
    assert (root / "notes.txt").read_text() == "mine" and (root / "folder").is_dir()


def mutate(data, draw):
    """Random byte edits: replace, insert, delete, truncate."""
    data = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        action = draw(st.sampled_from(["replace", "insert", "delete", "truncate"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if action == "replace" and data:
            data[at] = draw(st.integers(0, 255))
        elif action == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=4))
        elif action == "delete" and data:
            del data[at]
        else:
            data = data[:at]
    return bytes(data)


def small_enough(text):
    """Whether a (mutated) scene is small enough to run here: a digit edited in the radius or the
    domain can ask for millions of particles."""
    try:
        data = json.loads(text)
        radius, lo, hi = data["particle_radius"], data["domain"]["min"], data["domain"]["max"]
        return float(radius) >= 0.02 and all(abs(float(x)) <= 2.0 for x in [*lo, *hi])
    except Exception:
        return True  # it is refused before sampling


MESHES = {"obj": BOX.export(file_type="obj").encode(), "stl": BOX.export(file_type="stl_ascii").encode(),
          "ply": BOX.export(file_type="ply", encoding="ascii")}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    root = workspace(tmp_path_factory.mktemp("checkpoint"))
    assert cli(["run", root / "mesh.json", "--device", "cpu", "--out", root / "o.usdc", "--checkpoint-every", "1",
                "--quiet"]) == 0
    return root / "o.checkpoint.h5"


@FUZZ
@given(st.data())
def test_damaged_scene_mesh_and_checkpoint_files_run_or_say_why(tmp_path_factory, checkpoint, data):
    root = workspace(tmp_path_factory.mktemp("files"))
    kind = data.draw(st.sampled_from(["scene", "checkpoint", *MESHES]))
    if kind == "checkpoint":  # beside the cache it continues
        for path in checkpoint.parent.glob("o.*"):
            if path.is_file():
                (root / path.name).write_bytes(path.read_bytes())
        (root / checkpoint.name).write_bytes(mutate(checkpoint.read_bytes(), data.draw))
        code = cli(["resume", root / checkpoint.name, "--device", "cpu", "--quiet"])
        event(f"{kind}: exit {code}")
        assert code in (0, 2, 3)
        return
    if kind == "scene":
        text = mutate(json.dumps({**SCENE, "obstacles": [OBSTACLE]}).encode(), data.draw)
        if not small_enough(text):
            return
        (root / "s.json").write_bytes(text)
    else:
        (root / "s.json").write_text(json.dumps({**SCENE, "obstacles": [{**OBSTACLE, "mesh": f"box.{kind}"}]}))
        (root / f"box.{kind}").write_bytes(mutate(MESHES[kind], data.draw))
    code = cli(["run", root / "s.json", "--device", "cpu", "--out", root / "o.usdc", "--frames", "1", "--quiet"])
    event(f"{kind}: exit {code}")
    assert code in (0, 2, 3)
