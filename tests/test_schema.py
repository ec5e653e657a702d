"""The scene schema (pydantic, strict): `warpsph schema` for editors, the generated reference for the docs,
and errors that name the key."""

import dataclasses
import glob
import json
import os
import typing

import pytest

from warpsph import SceneError
from warpsph.cli import main
from warpsph.scene import Scene, model_types, reference_markdown, scene_from_dict
from conftest import SCENES_DIR, tank_scene


def schema_from_cli(capsys):
    assert main(["schema"]) == 0
    return json.loads(capsys.readouterr().out)


def test_every_scene_file_validates_against_the_printed_json_schema(capsys):
    jsonschema = pytest.importorskip("jsonschema", reason="validating against the JSON Schema needs jsonschema (the test extra installs it)")
    schema = schema_from_cli(capsys)
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    files = sorted(glob.glob(os.path.join(SCENES_DIR, "*.json")))
    assert len(files) >= 10
    for path in files:
        with open(path) as f:
            errors = list(validator.iter_errors(json.load(f)))
        assert not errors, (path, errors[0].message)
    # what the loader refuses, an editor flags too
    for bad in (tank_scene(partcle_radius=0.02), tank_scene(solver={"shifting": -1}),
                tank_scene(models=[{"type": "rankine", "beta": 2}]), tank_scene(models=[{"type": "rankin"}]),
                tank_scene(output={"up_axis": "X"}), tank_scene(gravity=[0, -9.81])):
        assert list(validator.iter_errors(bad)), bad


def _keys(cls, prefix=""):
    """Every key path of a schema class, lists as name[]."""
    for f in dataclasses.fields(cls):
        if f.name == "source":
            continue
        tp = typing.get_type_hints(cls)[f.name]
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        inner = args[0] if typing.get_origin(tp) is typing.Union else tp
        path = prefix + f.name
        if typing.get_origin(inner) is tuple and typing.get_args(inner)[-1] is Ellipsis:
            inner, path = typing.get_args(inner)[0], path + "[]"
        yield path
        if dataclasses.is_dataclass(inner):
            yield from _keys(inner, path + ".")


def test_the_reference_lists_every_key_with_its_unit_and_range(tmp_path, capsys):
    text = reference_markdown()
    for path in _keys(Scene):
        assert f"| `{path}` |" in text, path
    for name, params in model_types().items():
        assert f'"type": "{name}"' in text
        for path in _keys(params, "models[]."):
            assert f"| `{path}` |" in text, path
    assert "| `particle_radius` | a number > 0 | m | `required` |" in text
    assert "| `time.cfl` | a number in (0, 1] |" in text
    assert main(["schema", "--markdown", "--out", str(tmp_path / "ref.md")]) == 0
    assert (tmp_path / "ref.md").read_text() == text


@pytest.mark.parametrize("change, key, words", [
    ({"particle_radius": "0.02"}, "particle_radius", "expected a finite number > 0"),
    ({"solver": {"max_iterations": 2.0}}, "solver.max_iterations", "expected an integer >= 1"),
    ({"solver": {"sort_interval": True}}, "solver.sort_interval", "expected an integer"),
    ({"output": {"up_axis": "X"}}, "output.up_axis", 'expected "Y" or "Z"'),
    ({"domain": {"min": [0, 0, 0], "max": [0.4, 0.6, 0.4], "periodic": ["w"]}}, "domain.periodic[0]", '"x", "y" or "z"'),
    ({"models": [{"type": "rankine", "beta": 1.5}]}, "models[0].beta", "a number in [0, 1]"),
    ({"models": [{"type": "micropolar", "inverse_inertia": 0}]}, "models[0].inverse_inertia", "a number in (0, 10]"),
    ({"models": [{"beta": 1}]}, "models[0]", 'expected an object with a "type"'),
    ({"obstacles": [{"mesh": "a.obj", "motion": {"strat": 1}}]}, "obstacles[0].motion.strat", "did you mean 'start'"),
    ({"gravity": [0, -9.81, float("nan")]}, "gravity", "list of 3 numbers"),
    ({"source": "x.json"}, "source", "unknown key"),
])
def test_strict_types_and_ranges_name_the_key(change, key, words):
    with pytest.raises(SceneError) as info:
        scene_from_dict({**tank_scene(), **change})
    assert key in str(info.value) and words in str(info.value), str(info.value)


def test_a_scene_file_may_name_its_schema_for_editors(tmp_path, capsys):
    """The "$schema" key an editor reads (VS Code, JetBrains): the loader ignores it, the schema allows it."""
    schema_file = tmp_path / "scene.schema.json"
    assert main(["schema", "--out", str(schema_file)]) == 0
    schema = json.loads(schema_file.read_text())
    assert schema["properties"]["$schema"]["type"] == "string"
    path = tmp_path / "tank.json"
    path.write_text(json.dumps({"$schema": "./scene.schema.json", **tank_scene()}))
    assert Scene.load(path) == Scene.load(path)  # loads, and the key leaves no trace in the scene
    assert Scene.load(path).name == "tank" and Scene.from_dict({"$schema": "x", **tank_scene()}).name == "tank"
    jsonschema = pytest.importorskip("jsonschema", reason="validating against the JSON Schema needs jsonschema")
    assert not list(jsonschema.Draft202012Validator(schema).iter_errors(json.loads(path.read_text())))
    assert list(jsonschema.Draft202012Validator(schema).iter_errors({"$schema": 1, **tank_scene()}))


@pytest.mark.parametrize("value", [1, None, ["./scene.schema.json"]])
def test_a_schema_key_that_is_not_a_string_is_named(value):
    with pytest.raises(SceneError) as info:
        scene_from_dict({"$schema": value, **tank_scene()})
    assert "$schema" in str(info.value) and "a string" in str(info.value), str(info.value)


def test_a_schema_key_below_the_top_level_is_unknown():
    with pytest.raises(SceneError, match=r"fluid\.\$schema"):
        scene_from_dict({**tank_scene(), "fluid": {"$schema": "x"}})
