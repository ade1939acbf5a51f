"""Make-like runs: up-to-date stages are skipped, a changed setting re-runs exactly its stage and
what depends on it, `run STAGE` runs only what that stage needs; provenance is recorded."""

import pytest
from conftest import oracle_options

from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd.stage import layer_file, read_provenance


def _mtimes(out):
    return {p.name: p.stat().st_mtime_ns for p in (out / "layers").glob("*.usda")}


def test_second_run_skips_everything(out_copy, sample_case):
    """Re-running an unchanged reconstruction rewrites no layer."""
    before = _mtimes(out_copy)
    outcomes = Pipeline(sample_case, out_copy, oracle_options()).run()
    assert [o.ran for o in outcomes] == [False] * 7
    assert _mtimes(out_copy) == before


def test_changed_setting_reruns_only_that_stage(out_copy, sample_case):
    """A new gate setting re-runs the gate, then collect (which needs it), and nothing upstream."""
    before = _mtimes(out_copy)
    options = Options(backends={"all": "oracle"}, settings={"gate": {"spp": "4", "physics": "false"}})
    outcomes = Pipeline(sample_case, out_copy, options).run()
    assert [o.name for o in outcomes if o.ran] == ["gate", "collect"]
    after = _mtimes(out_copy)
    assert {k for k in after if after[k] != before[k]} == {"gate.usda", "robot.usda"}
    prov = read_provenance(layer_file(out_copy, "gate"))
    assert prov["config"]["spp"] == 4 and prov["config"]["physics"] is False


def test_run_stage_runs_its_needs_only(tmp_path, sample_case):
    """`run trajectory` into an empty folder writes world, masks, scene (the object rests on it),
    object, trajectory -- not gate."""
    out = tmp_path / "out"
    Pipeline(sample_case, out, oracle_options()).run("trajectory")
    assert sorted(p.stem for p in (out / "layers").glob("*.usda")) == [
        "masks",
        "object",
        "scene",
        "trajectory",
        "world",
    ]
    assert (out / "rose.usda").is_file()


def test_provenance_records_what_made_the_layer(oracle_out):
    """Each layer's customLayerData holds stage, backend, config, input hashes, versions and wall time."""
    prov = read_provenance(layer_file(oracle_out, "object"))
    assert prov["stage"] == "object" and prov["backend"] == "oracle"
    assert set(prov["inputs"]) >= {"case", "gt", "layer:world", "layer:masks"}
    assert prov["versions"]["usd-core"] != "absent"
    assert prov["wall_time_s"] >= 0
    assert "config_hash" in prov and prov["config"]["backend"] == "oracle"


@pytest.mark.parametrize(
    "flag",
    [
        {"backends": {"capture": "nope"}},
        {"settings": {"gate": {"no_such_field": "1"}}},
        {"settings": {"gate": {"spp": "many"}}},
    ],
)
def test_bad_options_fail_before_anything_runs(tmp_path, sample_case, flag):
    """Unknown backends, settings and unparsable values are refused with a one-line error."""
    from rose_usd.errors import ConfigError

    out = tmp_path / "out"
    with pytest.raises(ConfigError):
        Pipeline(sample_case, out, Options(**flag)).run()
    assert not (out / "layers").exists() or not any((out / "layers").iterdir())


def test_removed_layers_are_left_to_be_made_again_only_when_the_run_will_not(capsys, monkeypatch):
    """A full reconstruct printed "[scene] removed the layers it made stale: object, trajectory,
    gate (re-run them, or `rose-usd reconstruct`)" and then re-ran them itself."""
    from rose_usd import registry
    from rose_usd.pipeline import Pipeline, StageOutcome

    monkeypatch.delenv("ROSE_USD_QUIET", raising=False)
    outcome = StageOutcome("scene", "ran", 1.0, "tsdf", removed=("object", "trajectory", "gate"))
    Pipeline._say_removed(outcome, list(registry.STAGES))
    Pipeline._say_removed(outcome, [registry.get(n) for n in ("capture", "segment", "scene", "object")])
    whole, until_object = capsys.readouterr().err.splitlines()
    assert whole.endswith("object, trajectory, gate (this run makes them again)"), whole
    assert until_object.endswith("(make them again with `rose-usd run gate ...` or `rose-usd reconstruct`)"), (
        until_object
    )
    # a layer is named for what it holds, a stage for what it does: the robot layer is collect's
    gate = StageOutcome("gate", "ran", 1.0, "mitsuba-newton", removed=("robot",))
    Pipeline._say_removed(gate, [registry.get("gate")])
    assert capsys.readouterr().err.strip().endswith("with `rose-usd run collect ...` or `rose-usd reconstruct`)")
