"""The oracle reconstruction of the sample passes the gate: SSIM >= 0.98, object at rest in Newton,
closed colliders; the stage validates and loads in Newton."""

import json

import pytest
from pxr import Usd

from rose_usd.usd import paths
from rose_usd.usd.stage import open_stage
from rose_usd.usd.validate import validate


def test_oracle_ssim_at_least_098(oracle_out):
    """Cameras, intrinsics, colors and the trajectory survive the trip through USD: mean SSIM >= 0.98."""
    stage = open_stage(oracle_out / "rose.usda")
    gate = stage.GetPrimAtPath(paths.GATE)
    mean = gate.GetAttribute("rose:gate:ssimMean").Get()
    assert mean >= 0.98, f"mean SSIM {mean:.4f}"
    per_frame = gate.GetAttribute("rose:gate:ssim")
    assert per_frame.GetNumTimeSamples() == 48
    assert min(per_frame.Get(t) for t in per_frame.GetTimeSamples()) > 0.95


def test_object_rests_in_newton(oracle_out):
    """Loaded in Newton, the object at frame 0 moves less than 5 mm in 1 s."""
    stage = open_stage(oracle_out / "rose.usda")
    gate = stage.GetPrimAtPath(paths.GATE)
    assert list(gate.GetAttribute("rose:gate:physics:objects").Get()) == ["Box"]
    moved = list(gate.GetAttribute("rose:gate:physics:displacement").Get())
    assert moved[0] < 0.005, f"moved {moved[0] * 1000:.2f} mm"
    assert gate.GetAttribute("rose:gate:physics:duration").Get() == pytest.approx(1.0)
    assert gate.GetAttribute("rose:gate:physics:passed").Get()
    assert gate.GetAttribute("rose:gate:geometry:passed").Get()
    assert gate.GetAttribute("rose:gate:passed").Get()


def test_stage_validates_and_loads_in_newton(oracle_out):
    """The composed stage has no composition errors, zero UsdValidation errors, and Newton builds
    one body for the object."""
    report = validate(oracle_out / "rose.usda")
    assert report.validators >= 28
    assert report.errors == []
    assert report.newton["bodies"] == 1
    assert report.newton["path_body_map"] == {"/World/Objects/Box": 0}
    assert report.newton["gravity"] == pytest.approx([0.0, 0.0, -9.81])


def test_report_pictures_exist(oracle_out):
    """The gate leaves pictures a person would look at, and a summary."""
    report = oracle_out / "report"
    for name in ("ssim.png", "compare.png", "ssim.csv", "gate.json"):
        assert (report / name).stat().st_size > 0
    summary = json.loads((report / "gate.json").read_text())
    assert summary["passed"] and summary["frames_rendered"] == 48


def test_newton_reads_default_pose_frame_0(oracle_out):
    """The object's default xform is its frame-0 pose; time samples hold the trajectory."""
    stage = open_stage(oracle_out / "rose.usda")
    prim = stage.GetPrimAtPath(paths.object_path("Box"))
    translate = prim.GetAttribute("xformOp:translate")
    assert translate.Get(Usd.TimeCode.Default()) == translate.Get(Usd.TimeCode(0))
    assert translate.GetNumTimeSamples() == 48
