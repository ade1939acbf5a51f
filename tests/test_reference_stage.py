"""The sample's oracle reconstruction matches the committed reference dump in stages/ (normalized,
with tolerances, never byte for byte). Regenerate deliberately: pytest --update-reference."""

import json

from conftest import REFERENCE

from rose_usd.usd.diff import compare, load_dump
from rose_usd.usd.inspect import dump, normalize

# renderer and simulator figures move with library versions more than geometry does
TOLERANCES = {
    "rose:gate:ssim": (0.0, 3e-3),
    "ssim_mean": (0.0, 3e-3),
    "rose:gate:physics:displacement": (0.0, 1e-3),
    "rose:gate:physics:rotation": (0.0, 0.5),
    "results/physics": (0.0, 1e-3),
}


def test_matches_reference(oracle_out, request):
    """Prims, schemas, physics values, mesh stats, cameras, trajectories and gate results match stages/."""
    current = normalize(dump(oracle_out / "rose.usda"))
    if request.config.getoption("--update-reference"):
        REFERENCE.write_text(json.dumps(current, indent=1, sort_keys=True) + "\n")
    reference = load_dump(REFERENCE)
    differences = compare(reference, current, tolerances=TOLERANCES)
    assert differences == [], "\n".join(differences[:30])


def test_diff_notices_a_change(oracle_out, out_copy):
    """The comparison is not vacuous: a changed mass is reported with its key."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(out_copy / "layers" / "object.usda"))
    layer.GetAttributeAtPath("/World/Objects/Box.physics:mass").default *= 1.01
    layer.Save()
    differences = compare(load_dump(oracle_out / "rose.usda"), load_dump(out_copy / "rose.usda"))
    assert any("physics/mass_kg" in d for d in differences), differences


def test_timings_are_no_difference():
    """Two runs of one case differ by the stages' timings of their parts (the tracker's frames per
    second, collect's plan and build seconds): diff does not count them, but it counts the rest."""
    a = {"layers": [{"results": {"objects": {"Cup": {"frames_per_s": 35.4, "lost": 0}}, "plan_s": 3.1}}]}
    b = {"layers": [{"results": {"objects": {"Cup": {"frames_per_s": 51.3, "lost": 0}}, "plan_s": 2.2}}]}
    assert compare(normalize(a), normalize(b)) == []
    b["layers"][0]["results"]["objects"]["Cup"]["lost"] = 2
    assert compare(normalize(a), normalize(b)) == ["~ layers[0]/results/objects/Cup/lost: 0 -> 2"]
