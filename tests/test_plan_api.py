"""The plan (``auto`` resolved from what a case holds), the preflight that fails before anything is
written, staleness by code, and the Python API (``rose_usd.reconstruct``)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import oracle_options

import rose_usd
import rose_usd.pipeline as pipeline_module
from rose_usd import registry
from rose_usd.capture.config import CaptureBackend
from rose_usd.cli import main
from rose_usd.errors import ConfigError, InputError
from rose_usd.pipeline import Options, Pipeline
from rose_usd.segment.config import SegmentBackend, SegmentConfig
from rose_usd.stage_api import source_files
from rose_usd.usd.stage import layer_file, read_provenance


def _plan(case, **options) -> dict[str, str]:
    pipe = Pipeline(case, case.parent / "unused-out", Options(**options))
    return {s.name: pipe.config(s).backend.value for s in registry.STAGES}


def _snapshot(folder):
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*")} if folder.exists() else None


def test_auto_resolves_each_stage_from_what_the_case_holds(case_copy):
    """The sample (RGB-D, a prompt, ground truth) gets the real backends, never oracle; each input
    another tool made switches its stage to that tool's importer."""
    assert _plan(case_copy) == {
        "capture": "rgbd",
        "segment": "classical",
        "scene": "tsdf",
        "object": "fusion",
        "trajectory": "tracker",
        "gate": "mitsuba-newton",
        "collect": "newton",
    }
    perception = case_copy / "perception"
    (perception / "ob_in_cam").mkdir(parents=True)
    (perception / "ob_in_cam" / "000000.txt").write_text(" ".join(map(str, np.eye(4).ravel())))
    (perception / "Box.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (perception / "masks").mkdir()
    shutil.copy(case_copy / "gt" / "masks" / "Box" / "000000.png", perception / "masks" / "00000.png")
    plan = _plan(case_copy)
    assert (plan["segment"], plan["object"], plan["trajectory"]) == ("sam2", "imported", "foundationpose")
    # named backends win over auto; "all" applies a name to every stage that has it
    assert _plan(case_copy, backends={"all": "oracle", "gate": "auto"})["object"] == "oracle"
    shutil.rmtree(perception / "masks")
    shutil.rmtree(case_copy / "depth")
    assert _plan(case_copy, backends={"capture": "oracle"})["segment"] == "flow"  # no depth: 2D masks
    shutil.rmtree(perception)
    plan = _plan(case_copy)  # frames alone: the RGB-only backends
    assert (plan["capture"], plan["scene"], plan["object"], plan["trajectory"]) == (
        "sfm",
        "stereo",
        "silhouette",
        "silhouette",
    )


@pytest.mark.parametrize(
    "backend, missing",
    [
        ("object=oracle", "gt/scene.json"),
        ("trajectory=oracle", "gt/scene.json"),
        ("object=imported", "perception/Box.glb"),
        ("trajectory=foundationpose", "perception/ob_in_cam"),
        ("segment=sam2", "perception/masks"),
    ],
)
def test_a_missing_input_fails_before_anything_is_written(tmp_path, case_copy, capsys, backend, missing):
    """A backend whose input the case lacks fails at once with one line naming the file, and the
    output folder -- fresh or holding an earlier reconstruction -- is left as it was."""
    shutil.rmtree(case_copy / "gt")
    fresh = tmp_path / "fresh"
    assert main(["reconstruct", str(case_copy), "-o", str(fresh), "--backend", backend]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and missing in err and len(err.splitlines()) == 1
    assert not fresh.exists()
    kept = tmp_path / "kept"
    (kept / "layers").mkdir(parents=True)
    (kept / "layers" / "world.usda").write_text("#usda 1.0\n")
    before = _snapshot(kept)
    assert main(["run", "gate", str(case_copy), "-o", str(kept), "--backend", backend]) == 1
    assert _snapshot(kept) == before


def test_a_depth_backend_on_a_case_without_depth_names_what_is_missing(case_copy):
    shutil.rmtree(case_copy / "depth")
    with pytest.raises(InputError, match="needs metric depth"):
        Pipeline(case_copy, case_copy.parent / "out", Options(backends={"capture": "oracle", "object": "fusion"})).plan(
            "object"
        )
    with pytest.raises(InputError, match="capture=sfm"):
        Pipeline(case_copy, case_copy.parent / "out", Options(backends={"scene": "tsdf"})).plan("scene")


def test_source_files_follow_imports_within_the_package():
    """The code a backend runs: its module, its packages' __init__ and what they import from
    rose_usd, transitively; nothing from outside the package."""
    files = {
        p.relative_to(p.parents[1]).as_posix() if p.parent.name != "rose_usd" else p.name
        for p in source_files("rose_usd.trajectory.oracle")
    }
    assert {"trajectory/oracle.py", "trajectory/__init__.py", "trajectory/config.py", "trajectory/author.py"} <= files
    assert "oracle.py" in files and "__init__.py" in files  # rose_usd/oracle.py, rose_usd/__init__.py
    assert not any(f.startswith(("bench/", "synth/", "gate/")) for f in files)


def test_a_layer_made_by_other_code_is_stale(out_copy, sample_case, monkeypatch):
    """The package version and a hash of the backend's source are in the staleness key."""
    pipe = Pipeline(sample_case, out_copy, oracle_options())
    assert all(pipe.is_current(s) for s in registry.STAGES)
    prov = read_provenance(layer_file(out_copy, "world"))
    assert prov["code"].startswith(rose_usd.__version__ + "+")
    monkeypatch.setattr(pipeline_module, "code_version", lambda stage, backend: prov["code"] + "-changed")
    pipe = Pipeline(sample_case, out_copy, oracle_options())
    assert not any(pipe.is_current(s) for s in registry.STAGES)


def test_reconstruct_takes_names_enums_and_config_instances(tmp_path, sample_case):
    """until runs a stage and what it needs; a second call skips them; force re-runs the target."""
    backends = {"capture": CaptureBackend.ORACLE, "segment": SegmentConfig(backend=SegmentBackend.ORACLE)}
    out = tmp_path / "out"
    first = rose_usd.reconstruct(sample_case, out, backends=backends, until="segment", validate=False)
    assert first.plan == {"capture": "oracle", "segment": "oracle"}
    assert [o.status for o in first.outcomes] == ["ran", "ran"]
    assert sorted(p.stem for p in (out / "layers").glob("*.usda")) == ["masks", "world"]
    again = rose_usd.reconstruct(sample_case, out, backends=backends, until="segment", validate=False)
    assert [o.status for o in again.outcomes] == ["skipped", "skipped"]
    forced = rose_usd.reconstruct(sample_case, out, backends=backends, until="segment", force=True, validate=False)
    assert [o.status for o in forced.outcomes] == ["skipped", "ran"]
    # a config instance is the stage's whole config
    instance = SegmentConfig(backend=SegmentBackend.ORACLE, min_height_m=0.006)
    other = rose_usd.reconstruct(
        sample_case, out, backends={"capture": "oracle", "segment": instance}, until="segment", validate=False
    )
    assert [o.status for o in other.outcomes] == ["skipped", "ran"]
    config = read_provenance(layer_file(out, "masks"))["config"]
    assert config["backend"] == "oracle" and config["min_height_m"] == 0.006
    with pytest.raises(ConfigError, match="no backend"):
        rose_usd.reconstruct(sample_case, out, backends={"segment": CaptureBackend.ORACLE.value + "x"})
    with pytest.raises(ConfigError, match="SegmentConfig instance"):
        rose_usd.reconstruct(sample_case, out, backends={"capture": SegmentConfig()})


def test_reconstruct_returns_the_stage_the_gate_and_the_validation(out_copy, sample_case):
    result = rose_usd.reconstruct(sample_case, out_copy, backends={"all": "oracle"})
    assert all(o.status == "skipped" for o in result.outcomes)
    assert result.ok and result.gate.passed and result.validation.ok
    assert result.gate.ssim_mean > 0.9 and set(result.gate.rest_displacement_m) == {"Box"}
    assert result.stage.GetPrimAtPath("/World/Objects/Box")
    assert "gate PASS" in result.summary()
    # what was made, in a line: the true box's sides (8.76 x 8.14 x 7.90 cm) and its mass; no scale prior
    (line,) = [x for x in result.summary().splitlines() if x.startswith("objects: ")]
    assert line.startswith("objects: Box (mesh) 8.8 x 8.1 x 7.9 cm, ") and line.endswith(" kg"), line


def test_a_failing_stage_is_an_outcome_with_check_false(out_copy, sample_case, monkeypatch):
    """With check=False the error is recorded, later stages are 'not run', the failed stage's layer
    stays as it was; with check=True the error propagates."""
    import rose_usd.trajectory.oracle as trajectory_oracle

    def broken(ctx):
        raise InputError("the poses are broken", path=sample_case / "gt" / "objects" / "Box.tum", hint="fix them")

    monkeypatch.setattr(trajectory_oracle, "run", broken)
    before = _snapshot(out_copy)
    oracle = {"all": "oracle"}
    result = rose_usd.reconstruct(sample_case, out_copy, backends=oracle, until="trajectory", force=True, check=False)
    status = {o.name: o.status for o in result.outcomes}
    assert status == {"capture": "skipped", "segment": "skipped", "scene": "skipped", "object": "skipped"} | {
        "trajectory": "failed"
    }
    assert not result.ok and "Box.tum: the poses are broken" in result.error
    assert layer_file(out_copy, "trajectory").stat().st_mtime_ns == before[layer_file(out_copy, "trajectory")]
    with pytest.raises(InputError, match="poses are broken"):
        rose_usd.reconstruct(sample_case, out_copy, backends=oracle, until="trajectory", force=True)


def test_the_public_names_are_documented_and_importable():
    for name in rose_usd.__all__:
        value = getattr(rose_usd, name)
        if name not in ("__version__", "STAGES"):
            assert (value.__doc__ or "").strip(), f"rose_usd.{name} has no docstring"
    assert [s.name for s in rose_usd.STAGES] == list(registry.STAGE_NAMES)


def test_deferred_warnings_are_given_only_when_replayed(capsys):
    """Work that may be thrown away warns into a list; the stage keeps only what is replayed."""
    from types import SimpleNamespace

    from rose_usd.stage_api import StageContext

    writer = SimpleNamespace(provenance={})
    ctx = StageContext(SimpleNamespace(name="object"), None, None, None, None, writer)
    with ctx.deferred_warnings() as kept:
        ctx.warn("a fit that is not kept")
        with ctx.deferred_warnings() as inner:
            ctx.warn("nested")
    assert kept == ["a fit that is not kept"] and inner == ["nested"]
    said = capsys.readouterr()
    assert "warnings" not in writer.provenance and "not kept" not in said.out + said.err
    ctx.warn(kept[0])
    assert writer.provenance["warnings"] == ["a fit that is not kept"]


def test_a_stage_run_again_says_why(tmp_path, case_copy, capsys, monkeypatch):
    """A stage whose layer exists but is stale says why it runs again: other settings, other
    inputs; a current one is up to date (a new user saw only "[scene] backend tsdf" after a code
    change)."""
    from rose_usd.cli import main

    monkeypatch.setenv("ROSE_USD_QUIET", "0")
    base = ["run", "segment", str(case_copy), "-o", str(tmp_path / "out"), "--backend", "all=oracle"]
    assert main(base) == 0
    assert "runs again" not in capsys.readouterr().err  # a new folder: nothing to say
    assert main(base) == 0
    assert "[segment] up to date" in capsys.readouterr().err
    assert main([*base, "--set", "segment.min_height_m=0.005"]) == 0
    err = capsys.readouterr().err
    assert "[segment] runs again: its settings changed (segment.min_height_m " in err, err
    assert " -> 0.005)" in err, err
    toml = case_copy / "rose.toml"
    toml.write_text(toml.read_text() + "\n# edited\n[segment]\nmin_height_m = 0.006\n")
    assert main(base) == 0  # a comment and a stage's own table: that stage alone runs again
    err = capsys.readouterr().err
    assert "[capture] up to date" in err and "[segment] runs again: its settings changed (segment.min_height_m" in err
    toml.write_text(toml.read_text().replace('category = "box"', 'category = "box"\nsize_m = 0.1', 1))
    assert main(base) == 0
    err = capsys.readouterr().err
    assert "[capture] runs again: what it was made from changed (case: rose.toml)" in err, err


def test_a_collect_object_name_that_names_no_object_stops_before_any_stage(tmp_path, case_copy, capsys):
    """``--set collect.object_name=Nope`` stopped inside collect, once every stage before it had
    run (4-12 min on a real clip): the case's objects are known before anything runs."""
    from rose_usd.cli import main

    out = tmp_path / "out"
    assert main(["reconstruct", str(case_copy), "-o", str(out), "--set", "collect.object_name=Nope"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "error: --set: collect.object_name = 'Nope' is not an object of this case. the objects of rose.toml: Box."
    ], err
    assert not out.exists()
    (case_copy / "rose.toml").write_text((case_copy / "rose.toml").read_text() + '\n[collect]\nobject_name = "Bx"\n')
    assert main(["run", "collect", str(case_copy), "-o", str(out)]) == 1
    assert "error: " + str(case_copy / "rose.toml") in capsys.readouterr().err


def test_api_errors_name_its_arguments_and_the_cli_its_flags(tmp_path, sample_case, capsys):
    """A new user's `rose_usd.reconstruct(..., settings=...)` typo was blamed on `--set:`, a flag
    they never typed; the command line's errors still name its flags."""
    from rose_usd.cli import main
    from rose_usd.errors import ConfigError

    for kw, named in (
        ({"settings": {"gate": {"sp": 3}}}, "settings=: "),
        ({"backends": {"segment": "sam"}}, "backends=: "),
    ):
        with pytest.raises(ConfigError) as err:
            rose_usd.reconstruct(sample_case, tmp_path / "out", **kw)
        assert err.value.one_line().startswith(named), err.value.one_line()
    assert main(["run", "segment", str(sample_case), "-o", str(tmp_path / "out"), "--backend", "segment=sam"]) == 1
    assert capsys.readouterr().err.startswith(
        "error: --backend: stage 'segment' has no backend 'sam'. did you mean sam2?"
    )
    assert not (tmp_path / "out").exists()
