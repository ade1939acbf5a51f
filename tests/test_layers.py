"""Layer ownership and composition of the sample's oracle reconstruction (house-style tests 1-2)."""

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom

from rose_usd import registry
from rose_usd.case.gt import GroundTruth
from rose_usd.usd import paths
from rose_usd.usd.stage import layer_file, open_stage


def _layer(out, name):
    return Sdf.Layer.FindOrOpen(str(layer_file(out, name)))


@pytest.mark.parametrize("stage", registry.STAGES, ids=lambda s: s.name)
def test_each_layer_holds_only_its_own_specs(oracle_out, stage):
    """Every spec in a stage's layer lies under the paths that stage owns."""
    assert paths.ownership_violations(_layer(oracle_out, stage.layer), stage.layer) == []


def test_ownership_check_catches_a_foreign_spec():
    """A scene layer that defines an object prim is reported (the check is not vacuous)."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.Xform.Define(stage, "/World/Scene/Visual")
    UsdGeom.Xform.Define(stage, "/World/Objects/Intruder")
    problems = paths.ownership_violations(layer, "scene")
    assert any("/World/Objects/Intruder" in p for p in problems)
    traj = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(traj)
    UsdGeom.Xform.Define(stage, "/World/Objects/Box")  # trajectory may only override, not define
    assert paths.ownership_violations(traj, "trajectory")


def test_root_metadata_and_sublayer_order(oracle_out):
    """rose.usda carries the contract's metadata and sublayers strongest first in contract order."""
    stage = open_stage(oracle_out / "rose.usda")
    root = stage.GetRootLayer()
    assert root.defaultPrim == "World"
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetFramesPerSecond() == 30
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 47)
    names = [p.rsplit("/", 1)[-1].split(".")[0] for p in root.subLayerPaths]
    assert names == list(paths.LAYER_ORDER)


def test_winning_opinions_come_from_the_expected_layer(oracle_out):
    """Mass from the object layer, animated pose from the trajectory layer, camera from the world layer."""
    stage = open_stage(oracle_out / "rose.usda")
    obj = stage.GetPrimAtPath(paths.object_path("Box"))

    def strongest(attr, time=Usd.TimeCode.Default()):
        return attr.GetPropertyStack(time)[0].layer.identifier.rsplit("/", 1)[-1]

    assert strongest(obj.GetAttribute("physics:mass")) == "object.usda"
    assert strongest(obj.GetAttribute("xformOp:translate"), Usd.TimeCode(10)) == "trajectory.usda"
    assert (
        obj.GetAttribute("xformOp:translate").GetResolveInfo(Usd.TimeCode(10)).GetSource()
        == Usd.ResolveInfoSourceTimeSamples
    )
    assert strongest(stage.GetPrimAtPath(paths.CAMERA).GetAttribute("rose:camera:K")) == "world.usda"
    assert strongest(stage.GetPrimAtPath(paths.GATE).GetAttribute("rose:gate:ssimMean")) == "gate.usda"


@pytest.mark.parametrize("muted", ["trajectory", "scene", "masks", "gate", "robot"])
def test_muting_a_layer_removes_exactly_that_stage(oracle_out, muted):
    """With one layer muted, the prims and properties it owns vanish or fall back, and nothing else changes."""

    def snapshot(stage):
        out = {}
        for prim in stage.Traverse():
            for attr in prim.GetAttributes():
                if attr.HasAuthoredValue():
                    out[f"{prim.GetPath()}.{attr.GetName()}"] = (attr.GetNumTimeSamples(), str(attr.Get())[:80])
        return out

    full = snapshot(open_stage(oracle_out / "rose.usda"))
    part = snapshot(open_stage(oracle_out / "rose.usda", muted=(muted,)))
    claims = paths.OWNERSHIP[muted]
    changed = {k for k in full.keys() | part.keys() if full.get(k) != part.get(k)}
    assert changed, f"muting {muted} changed nothing"
    for key in changed:
        prim_path, prop = key.split(".", 1)
        assert any(c.covers_property(Sdf.Path(prim_path), prop) for c in claims), f"muting {muted} changed {key}"


def test_time_code_t_is_frame_t(oracle_out, sample_case):
    """The trajectory sample at time code t is ground-truth frame t (no 24/30 fps rescaling)."""
    stage = open_stage(oracle_out / "rose.usda")
    xf = UsdGeom.Xformable(stage.GetPrimAtPath(paths.object_path("Box")))
    truth = GroundTruth(sample_case / "gt").object_poses("Box")
    for t in (0, 17, 33, 47):
        pose = np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(t))).T
        np.testing.assert_allclose(pose, truth[t], atol=1e-6)
