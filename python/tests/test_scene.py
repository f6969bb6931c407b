"""Scenes: embedded, from a file or TOML text, with overrides; errors name the field."""

import pytest

import needle
from conftest import COARSE, ROOT


def test_embedded_scenes_load():
    assert needle.BUILTIN_SCENES == ["simple", "complex"]
    for name in needle.BUILTIN_SCENES:
        scene = needle.Scene(name)
        assert scene.name == name
        assert scene.planned_steps > 100


def test_a_scene_file_loads_as_str_or_path():
    path = ROOT / "scenes" / "simple.toml"
    by_str = needle.Scene(str(path))
    by_path = needle.Scene(path)
    embedded = needle.Scene("simple")
    # The embedded scene is the shipped file.
    assert by_str.to_toml() == by_path.to_toml() == embedded.to_toml()


def test_a_scene_from_toml_text_round_trips():
    text = needle.Scene("complex").to_toml()
    scene = needle.Scene.from_toml(text, name="mine.toml")
    assert scene.name == "complex"
    assert scene.to_toml() == text


def test_overrides_are_applied():
    base = needle.Scene("simple")
    scene = needle.Scene(
        "simple",
        overrides={
            "gel.box.nodes": 600,
            "inverse.delta_q": 0.001,
            "inverse.method": "paper",
            "gel.box.min": [250, -30.0, 0.0],
            "solver.background_factorization": False,
        },
    )
    text = scene.to_toml()
    assert "nodes = 600" in text
    assert "delta_q = 0.001" in text
    assert 'method = "paper"' in text
    assert "background_factorization = false" in text
    assert text != base.to_toml()
    # The same through with_overrides; the original is unchanged.
    assert base.with_overrides({"gel.box.nodes": 600}).to_toml() != base.to_toml()
    assert "nodes = 1500" in base.to_toml()


def test_overrides_change_the_simulation():
    coarse = needle.Simulation("simple", overrides={"gel.box.nodes": 300})
    finer = needle.Simulation("simple", overrides={"gel.box.nodes": 600})
    assert coarse.gel_positions.shape[0] < finer.gel_positions.shape[0]


@pytest.mark.parametrize(
    "overrides, field",
    [
        ({"gel.young_modulus": -1.0}, "gel.young_modulus"),
        ({"gel.box.nodes": "many"}, "gel.box.nodes"),
        ({"inverse.no_such_field": 1}, "inverse.no_such_field"),
        ({"inverse.method": "guess"}, "inverse.method"),
    ],
)
def test_a_bad_override_raises_naming_the_field(overrides, field):
    with pytest.raises(needle.SceneError) as info:
        needle.Scene("simple", overrides=overrides)
    e = info.value
    assert isinstance(e, ValueError)
    assert e.field == field
    assert f"`{field}`" in str(e)
    assert e.reason and e.reason in str(e)
    # The same from a simulation and a run.
    with pytest.raises(needle.SceneError, match=field.replace(".", r"\.")):
        needle.Simulation("simple", overrides=overrides)
    with pytest.raises(needle.SceneError, match=field.replace(".", r"\.")):
        needle.run("simple", overrides=overrides, steps=1)


def test_an_override_value_that_is_no_scene_value_is_a_type_error():
    with pytest.raises(TypeError, match="gel.box.nodes"):
        needle.Scene("simple", overrides={"gel.box.nodes": object()})


def test_an_unknown_scene_name_raises():
    with pytest.raises(needle.SceneError, match="neither a scene file nor an embedded scene"):
        needle.Scene("nowhere")


def test_a_missing_file_raises_naming_it(tmp_path):
    missing = tmp_path / "missing.toml"
    with pytest.raises(needle.SceneError) as info:
        needle.Scene(missing)
    assert str(missing) in str(info.value)
    assert info.value.file == str(missing)


def test_a_bad_file_raises_naming_the_file_and_field(tmp_path):
    bad = tmp_path / "bad.toml"
    text = needle.Scene("simple").to_toml()
    bad.write_text(text.replace("poisson_ratio = 0.45", "poisson_ratio = 0.7"))
    with pytest.raises(needle.SceneError) as info:
        needle.Scene(bad)
    assert info.value.file == str(bad)
    assert info.value.field == "gel.poisson_ratio"

    broken = tmp_path / "broken.toml"
    broken.write_text("name = [unclosed")
    with pytest.raises(needle.SceneError) as info:
        needle.Scene(str(broken))
    assert info.value.file == str(broken)
    assert info.value.field == ""


def test_a_scene_that_cannot_be_set_up_raises_setup_error():
    # The path's end below the gel's fixed bottom: refused at set-up, naming the field.
    overrides = dict(COARSE)
    overrides["path.formula"] = {"x": "300", "y": "0", "z": "60 - 80*s"}
    with pytest.raises(needle.SetupError) as info:
        needle.Simulation("simple", overrides=overrides)
    assert isinstance(info.value, ValueError)
    assert "path" in str(info.value)
    with pytest.raises(needle.SetupError):
        needle.run("simple", overrides=overrides)


def test_a_scene_argument_of_another_type_is_a_type_error():
    with pytest.raises(TypeError, match="needle.Scene, a scene name or a path"):
        needle.Scene(42)
