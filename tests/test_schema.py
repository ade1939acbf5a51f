"""rose's codeless schemas: registered on import, up to date with schema.usda, valid in a stage."""

import filecmp

import pytest
from pxr import Gf, Usd, UsdGeom, UsdPhysics

import rose_usd  # noqa: F401  (registers the schemas)
from rose_usd.usd import schema
from rose_usd.usd.validate import usd_validation


@pytest.mark.parametrize("name", schema.ALL_APIS)
def test_registry_knows_every_api(name):
    """Each rose API is a known single-apply API schema with rose: properties."""
    registry = Usd.SchemaRegistry()
    definition = registry.FindAppliedAPIPrimDefinition(name)
    assert definition is not None
    assert registry.GetSchemaKind(name) == Usd.SchemaKind.SingleApplyAPI
    props = definition.GetPropertyNames()
    assert props and all(p.startswith("rose:") for p in props)


def test_prior_schema_fields():
    """The physics prior carries source and uncertainty fields (the issue's minimum)."""
    props = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(schema.PHYSICS_PRIOR_API).GetPropertyNames()
    for name in (
        "rose:prior:source",
        "rose:prior:massUncertainty",
        "rose:prior:frictionUncertainty",
        "rose:prior:densityRange",
    ):
        assert name in props


def test_generated_files_are_current(tmp_path):
    """generatedSchema.usda and plugInfo.json equal what usdGenSchema makes from schema.usda now."""
    schema.regenerate(tmp_path)
    for name in ("generatedSchema.usda", "plugInfo.json"):
        assert filecmp.cmp(tmp_path / name, schema.schema_dir() / name, shallow=False), (
            f"{name} is stale: python -m rose_usd.usd.schema --regenerate"
        )


def test_stage_using_every_api_validates():
    """A stage applying every rose API, with values set, passes all UsdValidation validators."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(world)
    for i, name in enumerate(schema.ALL_APIS):
        prim = UsdGeom.Scope.Define(stage, f"/World/P{i}").GetPrim()
        assert prim.ApplyAPI(name)
        assert name in prim.GetAppliedSchemas()
    p = stage.GetPrimAtPath("/World/P2")
    p.GetAttribute("rose:prior:densityRange").Set(Gf.Vec2f(500, 900))
    p.GetAttribute("rose:prior:source").Set("table")
    stage.GetPrimAtPath("/World/P5").GetAttribute("rose:gate:ssim").Set(0.9, Usd.TimeCode(3))
    _, errors, _ = usd_validation(stage)
    assert errors == []


def test_closed_choices_declare_allowed_tokens():
    """Closed-choice tokens (e.g. the prior's source) carry allowedTokens from the schema."""
    stage = Usd.Stage.CreateInMemory()
    prim = UsdGeom.Scope.Define(stage, "/P").GetPrim()
    prim.ApplyAPI(schema.PHYSICS_PRIOR_API)
    attr = prim.GetAttribute("rose:prior:source")
    allowed = attr.GetMetadata("allowedTokens")
    assert list(allowed) == ["table", "user", "oracle", "vlm"]
