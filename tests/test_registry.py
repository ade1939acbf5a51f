"""Every registered stage is complete: layer, ownership, config, backends (trimesh's exporter registry walk)."""

import dataclasses
import enum

import pytest

from rose_usd import plan, registry
from rose_usd.usd import paths


@pytest.mark.parametrize("stage", registry.STAGES, ids=lambda s: s.name)
def test_stage_definition_is_complete(stage):
    """The stage owns a known layer with an ownership claim, a frozen keyword-only config whose
    backend enum matches the backends table, and every backend resolves to a callable."""
    assert stage.layer in paths.LAYER_ORDER
    assert stage.layer in paths.OWNERSHIP
    params = stage.config.__dataclass_params__
    assert params.frozen
    config = stage.config()
    backend_enum = type(config.backend)
    assert issubclass(backend_enum, enum.Enum)
    assert {m.value for m in backend_enum} == set(stage.backends) | {"auto"}
    assert config.backend.value == "auto", "auto is every stage's default backend"
    assert stage.name in plan.AUTO_RULES
    assert set(stage.requires) <= set(stage.backends)
    for needs in stage.requires.values():
        assert set(needs) <= set(plan.REQUIREMENTS)
    assert stage.requires_of("oracle") == (("gt",) if "oracle" in stage.backends else ())
    for name in stage.backends:
        assert callable(stage.backend_function(name))
    for f in dataclasses.fields(stage.config):
        assert f.kw_only, f"{stage.name}.{f.name} must be keyword-only"
    for need in stage.needs:
        assert registry.STAGE_NAMES.index(need) < registry.STAGE_NAMES.index(stage.name), (
            "registry order must be a run order"
        )


def test_layers_are_unique_per_stage():
    """One stage, one layer."""
    layers = [s.layer for s in registry.STAGES]
    assert len(layers) == len(set(layers))
