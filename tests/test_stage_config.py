"""Stage configs: per-backend settings, strict types, and a staleness hash over what runs."""

from __future__ import annotations

import pytest

from rose_usd import registry
from rose_usd.errors import ConfigError
from rose_usd.object.config import ObjectBackend, ObjectConfig
from rose_usd.segment.config import SegmentConfig
from rose_usd.stage_config import build_config, config_hash, config_to_dict, flatten, setting_names
from rose_usd.trajectory.config import TrajectoryConfig


def _object(**values):
    return build_config("object", ObjectConfig, values, source=None)


def test_settings_are_shared_or_a_backends_own():
    names = setting_names(ObjectConfig)
    assert "voxel_m" in names and "fusion.revolution_tolerance" in names and "imported.scale_search_steps" in names
    assert flatten({"fusion": {"revolution_tolerance": 0.04}, "voxel_m": 0.003}) == {
        "fusion.revolution_tolerance": 0.04,
        "voxel_m": 0.003,
    }
    cfg = _object(**{"backend": "fusion", "fusion.revolution_tolerance": "0.04", "voxel_m": 0.003})
    assert cfg.backend is ObjectBackend.FUSION and cfg.fusion.revolution_tolerance == 0.04 and cfg.voxel_m == 0.003


def test_hash_covers_the_running_backend_only():
    """An imported-only setting leaves a fusion layer current; a fusion one does not."""
    base = _object(backend="fusion")
    assert config_hash(_object(backend="fusion", imported={"scale_search_steps": 9})) == config_hash(base)
    assert config_hash(_object(backend="fusion", fusion={"revolution_tolerance": 0.04})) != config_hash(base)
    assert config_hash(_object(backend="fusion", voxel_m=0.003)) != config_hash(base)
    assert "imported" not in config_to_dict(base) and "imported" in config_to_dict(base, running_only=False)


@pytest.mark.parametrize(
    ("values", "needle"),
    [
        ({"imported.scale_search_steps": 2.9}, "is not valid: not an integer"),
        ({"imported.scale_search_steps": "2.9"}, "not an integer"),
        ({"imported.scale_search_steps": True}, "not an integer"),
        ({"imported.scale_search_steps": "abc"}, "scale_search_steps = 'abc' is not valid: not an integer"),
        ({"voxel_m": "high"}, "object.voxel_m = 'high' is not valid: not a number"),
        ({"voxel_m": float("nan")}, "not finite"),
        ({"backend": "colmap"}, "one of auto, fusion, imported, silhouette, oracle"),
        ({"revolution_tolerance": 0.04}, "did you mean object.fusion.revolution_tolerance"),
        ({"voxel_mm": 0.004}, "did you mean object.voxel_m?"),
        ({"voxl_m": 0.004}, "did you mean object.voxel_m?"),
    ],
)
def test_a_value_that_does_not_fit_is_one_line_error(values, needle):
    with pytest.raises(ConfigError) as err:
        _object(**values)
    assert needle in err.value.one_line(), err.value.one_line()
    assert not err.value.one_line().endswith("?."), err.value.one_line()  # a question ends the line


def test_settings_that_contradict_each_other_are_one_line_error():
    """scene.stereo's far plane must lie beyond its near one, from the command line or the API."""
    from rose_usd.scene.config import SceneConfig, StereoConfig
    from rose_usd.stage_config import check_config

    with pytest.raises(ConfigError) as err:
        build_config("scene", SceneConfig, {"stereo.near": 2, "stereo.far": 1}, source="--set")
    assert "scene.stereo.far = 1 is not beyond near = 2" in err.value.one_line(), err.value.one_line()
    with pytest.raises(ConfigError):
        check_config("scene", SceneConfig(stereo=StereoConfig(near=0.5, far=0.5)), source=None)
    assert build_config("scene", SceneConfig, {"stereo.near": 0.5, "stereo.far": 0.6}, source=None).stereo.far == 0.6


def test_whole_numbers_are_kept():
    assert _object(**{"imported.scale_search_steps": "9"}).imported.scale_search_steps == 9
    assert _object(**{"imported.scale_search_steps": 9.0}).imported.scale_search_steps == 9
    assert (
        build_config("trajectory", TrajectoryConfig, {"tracker.min_points": "40"}, source=None).tracker.min_points == 40
    )


def test_prompts_and_sam2_ids_are_typed():
    cfg = build_config(
        "segment", SegmentConfig, {"prompts": "Box=3:10,20,30,40;Cup=0:5,6", "sam2.ids": "Box=1, Cup=2"}, source=None
    )
    assert [(p.name, p.prompt.frame, p.prompt.box, p.prompt.point) for p in cfg.prompts] == [
        ("Box", 3, (10.0, 20.0, 30.0, 40.0), None),
        ("Cup", 0, None, (5.0, 6.0)),
    ]
    assert cfg.sam2.ids == (("Box", 1), ("Cup", 2))
    assert build_config("segment", SegmentConfig, {"sam2": {"ids": {"Box": 3}}}, source=None).sam2.ids == (("Box", 3),)
    assert config_to_dict(cfg)["prompts"][0] == {
        "name": "Box",
        "prompt": {"frame": 3, "box": [10, 20, 30, 40], "point": None},
    }
    for bad in ({"sam2.ids": "Box=x"}, {"sam2.ids": "Box=1.5"}, {"prompts": "Box=0:1,2,3"}):
        with pytest.raises(ConfigError):
            build_config("segment", SegmentConfig, bad, source=None)


def test_rose_toml_tables_and_command_line_settings(case_copy, tmp_path):
    """[object.fusion] in rose.toml sets the fusion backend's own setting; --set overrides it."""
    from rose_usd import registry
    from rose_usd.pipeline import Options, Pipeline

    toml = case_copy / "rose.toml"
    toml.write_text(
        toml.read_text() + "\n[object.fusion]\nrevolution_tolerance = 0.04\n[segment.sam2]\nids = { Box = 2 }\n"
    )
    pipe = Pipeline(case_copy, tmp_path / "out")
    assert pipe.config(registry.get("object")).fusion.revolution_tolerance == 0.04
    assert pipe.config(registry.get("segment")).sam2.ids == (("Box", 2),)
    pipe = Pipeline(case_copy, tmp_path / "out", Options(settings={"object": {"fusion.revolution_tolerance": "0.06"}}))
    assert pipe.config(registry.get("object")).fusion.revolution_tolerance == 0.06


@pytest.mark.parametrize("stage", registry.STAGES, ids=lambda s: s.name)
def test_every_default_can_be_given_back(stage):
    """Each setting's default, given on the command line, passes its own type and range check
    (a 0 that means "off" must not be refused as out of range)."""
    config = stage.config()
    values = flatten(config_to_dict(config, running_only=False), setting_names(stage.config))
    rebuilt = build_config(stage.name, stage.config, values, source="--set")
    assert config_to_dict(rebuilt, running_only=False) == config_to_dict(config, running_only=False)


def test_a_short_setting_misspelt_gets_its_suggestion():
    """`--set gate.spx=3` listed every gate setting where `object.silhouete...` got a "did you mean"."""
    from rose_usd.gate.config import GateConfig

    with pytest.raises(ConfigError, match=r"did you mean gate\.spp\?"):
        build_config("gate", GateConfig, {"spx": 3}, source="--set")


def test_every_setting_is_explained_by_rose_usd_stages(capsys):
    """`rose-usd stages STAGE` prints each setting's default and the docstring under its field; a
    new user asked for units and meanings, and for one stage at a time."""
    from rose_usd import registry
    from rose_usd.cli import main
    from rose_usd.stage_config import setting_docs

    for stage in registry.STAGES:
        docs = setting_docs(stage.config)
        assert docs and all(docs.values()), [k for k, v in docs.items() if not v]
    assert main(["stages", "gate"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("gate ") and "capture " not in out
    assert "gate.physics_dt_s = 0.00166667\n" in out and "Time step of the rest check [s]" in out
    assert main(["stages", "bogus"]) == 1
