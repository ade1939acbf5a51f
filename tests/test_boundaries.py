"""The layers are the only interface between stages: which package may import which.

- A stage package (capture, segment, scene, object, trajectory, gate) imports no other stage
  package; what it needs from an earlier stage it reads from that stage's layer
  (``rose_usd.layers``).
- A backend module (a ``StageDef.backends`` entry) imports no sibling backend module; what two
  backends of a stage share sits in a shared module of that stage.
- Neutral packages (core, geometry, layers, io, usd, render, sim, case, ...) import no stage
  package, and nothing below the orchestration (pipeline, plan, api, cli, registry, bench, synth, batch)
  imports it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from rose_usd import registry
from rose_usd.usd import tokens
from rose_usd.usd.schema import schema_dir

PACKAGE = Path(__file__).resolve().parents[1] / "rose_usd"
STAGES = set(registry.STAGE_NAMES)
ORCHESTRATION = {"pipeline", "plan", "api", "cli", "registry", "bench", "synth", "batch", "__main__"}
BACKEND_MODULES = {stage.name: {entry.split(":")[0] for entry in stage.backends.values()} for stage in registry.STAGES}


def imported_modules(source: str) -> list[tuple[int, str]]:
    """(line, module) of every rose_usd import in ``source``, function-local ones included."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("rose_usd"):
            if node.module == "rose_usd":  # from rose_usd import x: x may be a subpackage
                out += [(node.lineno, f"rose_usd.{a.name}") for a in node.names]
            else:
                out.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("rose_usd")]
    return out


def violations(module: str, source: str) -> list[str]:
    """What ``module`` (dotted name) imports that it may not."""
    parts = module.split(".")
    top = parts[1] if len(parts) > 1 else ""
    bad = []
    for line, target in imported_modules(source):
        tparts = target.split(".")
        ttop = tparts[1] if len(tparts) > 1 else ""
        where = f"{module}:{line} imports {target}"
        if top in ORCHESTRATION:
            continue
        if ttop in ORCHESTRATION:
            bad.append(f"{where} (orchestration)")
        elif top in STAGES and ttop in STAGES and ttop != top:
            bad.append(f"{where} (another stage: read its layer through rose_usd.layers)")
        elif top not in STAGES and ttop in STAGES:
            bad.append(f"{where} (a neutral package imports a stage)")
        elif top in STAGES and module in BACKEND_MODULES[top]:
            siblings = BACKEND_MODULES[top] - {module}
            if any(target == s or target.startswith(s + ".") for s in siblings):
                bad.append(f"{where} (a sibling backend: move what they share into a shared module)")
    return bad


def package_modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def test_no_import_crosses_a_boundary():
    bad = [v for module, path in sorted(package_modules().items()) for v in violations(module, path.read_text())]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(
    ("module", "line", "why"),
    [
        ("rose_usd.object.fusion", "from rose_usd.scene.tsdf import fuse_static", "another stage"),
        ("rose_usd.object.fusion", "    from rose_usd.segment import tracks", "another stage"),
        ("rose_usd.object.imported", "from rose_usd.object.fusion import run", "a sibling backend"),
        ("rose_usd.geometry.mesh", "import rose_usd.object.author", "a neutral package imports a stage"),
        ("rose_usd.layers.masks", "from rose_usd.pipeline import Pipeline", "orchestration"),
    ],
)
def test_a_crossing_import_is_caught(module, line, why):
    """The same check on a module's real source with one forbidden import added."""
    source = package_modules()[module].read_text()
    assert not violations(module, source)
    spliced = source + ("\n\ndef _added():\n" + line if line.startswith(" ") else "\n" + line + "\n")
    found = violations(module, spliced)
    assert len(found) == 1 and why in found[0], found


def test_shared_modules_are_allowed():
    """A backend may import its stage's shared modules; an orchestration module anything."""
    assert not violations("rose_usd.object.imported", "from rose_usd.object.rest import resting_clouds")
    assert not violations("rose_usd.object.fusion", "from rose_usd.layers.masks import read_masks")
    assert not violations("rose_usd.pipeline", "from rose_usd.object.fusion import run")


def test_attribute_names_are_defined_once():
    """tokens.py names exactly the schema's rose: properties, and no other module spells one out."""
    schema = set(re.findall(r"rose:[A-Za-z:]+[A-Za-z]", (schema_dir() / "schema.usda").read_text()))
    declared = {v for k, v in vars(tokens).items() if k.isupper()}
    assert declared == schema
    spelled = [
        f"{path.relative_to(PACKAGE.parent)}: {node.value}"
        for path in PACKAGE.rglob("*.py")
        if path.name != "tokens.py"
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in schema
    ]
    assert not spelled, "\n".join(spelled)
