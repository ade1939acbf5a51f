"""Property-based fuzzing of what a user hands rose_usd (issue 25): rose.toml, cam_K.txt, frames,
depth maps and every importer's files. The only allowed outcomes are a one-line RoseError or a
result that holds the reader's promises (finite numbers, in range, of the right shape).

The default run has a bounded budget (``ROSE_FUZZ_EXAMPLES``, default 25 per property); the
benchmark job's ``test_fuzz_long`` runs every property again and again for
``ROSE_FUZZ_MINUTES`` (default 10).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rose_usd import registry
from rose_usd.errors import RoseError

# a numpy warning would print on stderr beside the one-line error: the readers must not raise any
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning", "error::UserWarning")

EXAMPLES = int(os.environ.get("ROSE_FUZZ_EXAMPLES", "25"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def one_line(exc: RoseError) -> None:
    text = exc.one_line()
    assert "\n" not in text and text.strip(), text


def outcome(fn, *args):
    """fn's result, or None after checking that it failed with a one-line RoseError."""
    try:
        return fn(*args)
    except RoseError as exc:
        one_line(exc)
        return None


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory, sample_case) -> Path:
    """A copy of the sample without gt/ (most properties rewrite one of its files)."""
    dst = tmp_path_factory.mktemp("fuzz") / "case"
    shutil.copytree(sample_case, dst, ignore=shutil.ignore_patterns("gt"))
    return dst


# ----------------------------------------------------------------------------- strategies
KEYS = [
    "fps", "objects", "backends", "name", "category", "prompt", "frame", "box", "point", "mass_kg", "friction",
    "restitution", "hollow", "size_m", "density_kg_m3", "mesh", "mesh_up", "mesh_units", *registry.STAGE_NAMES,
    "depth_max_m", "rgbd", "track_width", "spp", "prompts", "tsdf", "voxel_m", "gravity", "fusion",
]  # fmt: skip
scalars = st.one_of(
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(max_size=12),
    st.sampled_from(["auto", "oracle", "Box", "box", "x", "-y", "0:1,2,30,40", "Interactor", "rgbd", "plane"]),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)
documents = st.dictionaries(st.sampled_from(KEYS), values, max_size=5)


def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else json.dumps(k)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v) if abs(v) < 2**63 else f'"{v}"'
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"


def to_toml(doc: dict) -> str:
    return "\n".join(f"{_key(k)} = {_toml_value(v)}" for k, v in doc.items()) + "\n"


def mutate(data: bytes, edits) -> bytes:
    out = bytearray(data)
    for pos, byte, kind in edits:
        if not out:
            break
        i = pos % len(out)
        if kind == 0:
            out[i] = byte
        elif kind == 1:
            del out[i:]
        else:
            out.insert(i, byte)
    return bytes(out)


byte_edits = st.lists(st.tuples(st.integers(0, 10**7), st.integers(0, 255), st.integers(0, 2)), min_size=1, max_size=8)


# ----------------------------------------------------------------------------- rose.toml
def check_pipeline(case: Path, out: Path) -> None:
    """Parse the case and every stage's settings, plan a run and preflight it."""
    from rose_usd.pipeline import Pipeline

    pipe = Pipeline(case, out)
    for stage in registry.STAGES:
        config = pipe._unresolved[stage.name]
        for f in config.__dataclass_fields__:
            v = getattr(config, f)
            assert not (isinstance(v, float) and not math.isfinite(v)), (stage.name, f, v)
    for spec in pipe.case.config.objects:
        for key, v in spec.overrides.items():
            if key in ("mass_kg", "density_kg_m3", "size_m"):
                assert isinstance(v, float) and math.isfinite(v) and v > 0, (key, v)
            if key in ("friction", "restitution"):
                assert isinstance(v, float) and math.isfinite(v) and v >= 0, (key, v)
            if key == "hollow":
                assert isinstance(v, bool)
    pipe.plan("capture")


def fuzz_toml_structured(case_dir, tmp_path, doc):
    (case_dir / "rose.toml").write_text(to_toml(doc))
    outcome(check_pipeline, case_dir, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def fuzz_toml_bytes(case_dir, tmp_path, edits):
    base = (
        b'fps = 30\n[[objects]]\nname = "Box"\ncategory = "box"\nmass_kg = 0.2\nhollow = false\n'
        b'prompt = { frame = 0, box = [174, 90, 208, 127] }\n[backends]\nscene = "tsdf"\n'
        b"[capture]\ndepth_max_m = 2.5\n[capture.rgbd]\ntrack_width = 160\n"
    )
    (case_dir / "rose.toml").write_bytes(mutate(base, edits))
    outcome(check_pipeline, case_dir, tmp_path / "out")


@FUZZ
@given(doc=documents)
def test_fuzz_rose_toml(case_dir, tmp_path, doc):
    """Random rose.toml documents: a one-line error or a typed, in-range reading."""
    fuzz_toml_structured(case_dir, tmp_path, doc)


@FUZZ
@given(edits=byte_edits)
def test_fuzz_rose_toml_bytes(case_dir, tmp_path, edits):
    """A valid rose.toml with random byte edits (cuts, insertions, non-UTF-8)."""
    fuzz_toml_bytes(case_dir, tmp_path, edits)


# ----------------------------------------------------------------------------- cam_K.txt
numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(10**6), 10**6), st.just(0.5))
K_texts = st.one_of(
    st.lists(st.lists(numbers, min_size=0, max_size=4), max_size=4).map(
        lambda rows: "\n".join(" ".join(repr(float(v)) for v in row) for row in rows)
    ),
    st.text(max_size=40),
    st.tuples(st.floats(1, 5000), st.floats(1, 5000), st.floats(-50, 400), st.floats(-50, 300)).map(
        lambda k: f"{k[0]} 0 {k[2]}\n0 {k[1]} {k[3]}\n0 0 1\n"
    ),
)


def fuzz_K(case_dir, text):
    from rose_usd.case import load_case

    (case_dir / "rose.toml").write_text("fps = 30\n")
    (case_dir / "cam_K.txt").write_text(text)
    case = outcome(load_case, case_dir)
    if case is not None:  # accepted: it must be a camera of this image
        K = case.K()
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        assert np.all(np.isfinite(K)) and 0.8 <= fx / fy <= 1.25
        assert 0.25 * 320 <= cx <= 0.75 * 320 and 0.25 * 240 <= cy <= 0.75 * 240
        assert 32 < fx < 6400 and 32 < fy < 6400


@FUZZ
@given(text=K_texts)
def test_fuzz_cam_K(case_dir, text):
    """Random cam_K.txt: a one-line error, or intrinsics a camera of a 320x240 image can have."""
    try:
        fuzz_K(case_dir, text)
    finally:
        shutil.copy(Path(__file__).parents[1] / "samples" / "push-box" / "cam_K.txt", case_dir / "cam_K.txt")


# ----------------------------------------------------------------------------- images
def fuzz_image(case_dir, edits, which):
    from rose_usd.case import load_case

    src = Path(__file__).parents[1] / "samples" / "push-box" / which / "000003.png"
    target = case_dir / which / "000003.png"
    try:
        target.write_bytes(mutate(src.read_bytes(), edits))
        case = outcome(load_case, case_dir)
        if case is None:
            return
        if which == "rgb":
            img = outcome(case.rgb, 3)
            assert img is None or (img.shape == (240, 320, 3) and img.dtype == np.uint8)
        else:
            depth = outcome(case.depth_m, 3)
            assert depth is None or (depth.shape == (240, 320) and np.all(np.isfinite(depth)) and depth.min() >= 0)
    finally:
        shutil.copy(src, target)


@FUZZ
@given(edits=byte_edits, which=st.sampled_from(["rgb", "depth"]))
def test_fuzz_frame_png(case_dir, edits, which):
    """A frame or depth PNG with random byte edits: a one-line error or a well-formed image."""
    fuzz_image(case_dir, edits, which)


# ----------------------------------------------------------------------------- importers
def fuzz_pose(tmp_path, text):
    from rose_usd.io.foundationpose import read_pose

    (tmp_path / "p.txt").write_text(text)
    pose = outcome(read_pose, tmp_path / "p.txt")
    if pose is not None:
        assert pose.shape == (4, 4) and np.all(np.isfinite(pose)) and np.abs(pose[:3, 3]).max() <= 100
        assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-2)


pose_texts = st.one_of(
    st.lists(st.lists(numbers, min_size=0, max_size=5), max_size=5).map(
        lambda rows: "\n".join(" ".join(repr(float(v)) for v in row) for row in rows)
    ),
    st.tuples(numbers, numbers, numbers).map(lambda t: "1 0 0 {!r}\n0 1 0 {!r}\n0 0 1 {!r}\n0 0 0 1\n".format(*t)),
    st.text(max_size=40),
)


def fuzz_geocalib(tmp_path, doc):
    from rose_usd.io.geocalib import read_geocalib

    (tmp_path / "geocalib.json").write_text(json.dumps(doc, allow_nan=True))
    calib = outcome(read_geocalib, tmp_path / "geocalib.json")
    if calib is not None:
        assert np.all(np.isfinite(calib.up_cam)) and abs(np.linalg.norm(calib.up_cam) - 1) < 1e-3
        assert isinstance(calib.frame, int) and calib.frame >= 0
        assert math.isfinite(calib.roll) and math.isfinite(calib.pitch)
        assert calib.K is None or (calib.K.shape == (3, 3) and np.all(np.isfinite(calib.K)))


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.floats(), st.integers(-(10**9), 10**9), st.text(max_size=6)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=5), inner, max_size=3)),
    max_leaves=10,
)
geocalib_docs = st.one_of(
    json_values,
    st.fixed_dictionaries(
        {"gravity": st.one_of(json_values, st.just([0.0, -1.0, 0.0]))},
        optional={
            "rp": json_values,
            "frame": json_values,
            "K": json_values,
            "vfov": json_values,
            "roll_uncertainty": json_values,
        },
    ),
)


def fuzz_imu(tmp_path, text):
    from rose_usd.io.imu import read_gravity

    (tmp_path / "gravity.txt").write_text(text)
    g = outcome(read_gravity, tmp_path / "gravity.txt", 4)
    if g is not None:
        assert g.shape == (4, 3) and np.all(np.isfinite(g)) and np.all(np.linalg.norm(g, axis=1) > 0)


def fuzz_tum(tmp_path, text):
    from rose_usd.io.tum import read_tum

    (tmp_path / "t.tum").write_text(text)
    got = outcome(read_tum, tmp_path / "t.tum")
    if got is not None:
        times, poses = got
        assert np.all(np.isfinite(poses)) and np.all(np.diff(times) > 0)


def fuzz_imu_tum(tmp_path, text):
    fuzz_imu(tmp_path, text)
    fuzz_tum(tmp_path, text)


def fuzz_mask(tmp_path, edits):
    from rose_usd.io.sam2 import read_masks, read_object_mask, write_id_mask

    folder = tmp_path / "masks"
    shutil.rmtree(folder, ignore_errors=True)
    ids = np.zeros((24, 32), np.uint8)
    ids[5:15, 5:20] = 1
    write_id_mask(folder / "00000.png", ids)
    path = folder / "00000.png"
    path.write_bytes(mutate(path.read_bytes(), edits))
    entries = outcome(read_masks, folder)
    if entries is not None:
        mask = outcome(read_object_mask, entries[0], 1)
        assert mask is None or mask.dtype == bool


def fuzz_npz(tmp_path, arrays, which):
    from rose_usd.io.megasam import read_megasam
    from rose_usd.io.unidepth import read_unidepth

    path = tmp_path / "x.npz"
    np.savez(path, **arrays)
    if which == "megasam":
        got = outcome(read_megasam, path)
        if got is not None:
            assert np.all(np.isfinite(got.cam_c2w)) and np.abs(got.cam_c2w[:, :3, 3]).max() <= 1e4
    else:
        got = outcome(read_unidepth, path)
        if got is not None:
            assert 1 < got.fov_deg < 179 and got.depth_m.ndim == 2


def megasam_arrays(draw_scale, draw_k, depth_value):
    images = np.zeros((2, 8, 10, 3), np.uint8)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, :3, 3] = draw_scale
    K = np.array([[8.0, 0, 5], [0, 8.0, 4], [0, 0, 1]]) * np.array([[draw_k, 1, 1], [1, draw_k, 1], [1, 1, 1]])
    return {"images": images, "depths": np.full((2, 8, 10), depth_value, np.float16), "intrinsic": K, "cam_c2w": c2w}


def fuzz_mesh(tmp_path, text):
    from rose_usd.io.meshfile import read_mesh_file

    (tmp_path / "m.obj").write_text(text)
    mesh = outcome(read_mesh_file, tmp_path / "m.obj")
    if mesh is not None:
        assert np.all(np.isfinite(mesh.vertices)) and len(mesh.faces) > 0


obj_texts = st.lists(
    st.one_of(
        st.tuples(numbers, numbers, numbers).map(lambda v: "v {!r} {!r} {!r}".format(*map(float, v))),
        st.tuples(st.integers(-3, 6), st.integers(-3, 6), st.integers(-3, 6)).map(lambda f: "f {} {} {}".format(*f)),
        st.text(max_size=10),
    ),
    max_size=10,
).map("\n".join)


@FUZZ
@given(text=pose_texts)
def test_fuzz_foundationpose(tmp_path, text):
    """FoundationPose pose files: a one-line error or a finite rigid pose within 100 m."""
    fuzz_pose(tmp_path, text)


@FUZZ
@given(doc=geocalib_docs)
def test_fuzz_geocalib(tmp_path, doc):
    """geocalib.json documents: a one-line error or a finite unit up vector, a frame index, a 3x3 K."""
    fuzz_geocalib(tmp_path, doc)


@FUZZ
@given(text=st.one_of(pose_texts, st.text(max_size=30)))
def test_fuzz_imu_and_tum(tmp_path, text):
    """imu/gravity.txt and TUM files: a one-line error or finite, well-formed values."""
    fuzz_imu_tum(tmp_path, text)


@FUZZ
@given(edits=byte_edits)
def test_fuzz_sam2_mask(tmp_path, edits):
    """A SAM 2 mask PNG with random byte edits: a one-line error or a boolean mask."""
    fuzz_mask(tmp_path, edits)


@FUZZ
@given(
    scale=numbers,
    k=st.one_of(numbers, st.just(1.0)),
    depth=st.one_of(st.just(np.nan), st.just(0.0), st.floats(0.001, 200)),
    which=st.sampled_from(["megasam", "unidepth"]),
)
def test_fuzz_npz_importers(tmp_path, scale, k, depth, which):
    """MegaSaM and UniDepth npz files with random poses, intrinsics and depth."""
    with np.errstate(all="ignore"):
        if which == "megasam":
            arrays = megasam_arrays(scale, k, depth)
        else:
            arrays = {"depth": np.full((8, 10), depth, np.float32), "fov": np.float32(scale)}
    fuzz_npz(tmp_path, arrays, which)


@FUZZ
@given(text=obj_texts)
def test_fuzz_mesh_file(tmp_path, text):
    """OBJ meshes with random vertices, faces and junk: a one-line error or a finite mesh."""
    fuzz_mesh(tmp_path, text)


def test_cam_K_and_depth_fuzz_restore(case_dir):
    """The fuzzed case folder is left as the sample was (each property restores what it broke)."""
    sample = Path(__file__).parents[1] / "samples" / "push-box"
    for rel in ("cam_K.txt", "rgb/000003.png", "depth/000003.png"):
        assert (case_dir / rel).read_bytes() == (sample / rel).read_bytes()
    img = cv2.imread(str(case_dir / "rgb" / "000003.png"))
    assert img is not None


@pytest.mark.slow
def test_fuzz_long(tmp_path_factory, sample_case):
    """The benchmark job's fuzz run: every property above, again and again, for ROSE_FUZZ_MINUTES (10)."""
    minutes = float(os.environ.get("ROSE_FUZZ_MINUTES", "10"))
    case = tmp_path_factory.mktemp("fuzz-long") / "case"
    shutil.copytree(sample_case, case, ignore=shutil.ignore_patterns("gt"))
    long = settings(FUZZ, max_examples=200)
    properties = [
        long(given(doc=documents)(lambda doc: fuzz_toml_structured(case, tmp, doc))),
        long(given(edits=byte_edits)(lambda edits: fuzz_toml_bytes(case, tmp, edits))),
        long(given(text=K_texts)(lambda text: fuzz_K(case, text))),
        long(given(edits=byte_edits, which=st.sampled_from(["rgb", "depth"]))(lambda edits, which: fuzz_image(case, edits, which))),  # noqa: E501
        long(given(text=pose_texts)(lambda text: fuzz_pose(tmp, text))),
        long(given(doc=geocalib_docs)(lambda doc: fuzz_geocalib(tmp, doc))),
        long(given(text=st.one_of(pose_texts, st.text(max_size=30)))(lambda text: fuzz_imu_tum(tmp, text))),
        long(given(edits=byte_edits)(lambda edits: fuzz_mask(tmp, edits))),
        long(given(text=obj_texts)(lambda text: fuzz_mesh(tmp, text))),
    ]  # fmt: skip
    tmp = tmp_path_factory.mktemp("fuzz-long-files")
    deadline = time.monotonic() + 60 * minutes
    rounds = 0
    while time.monotonic() < deadline:
        for prop in properties:
            prop()
            shutil.copy(sample_case / "cam_K.txt", case / "cam_K.txt")
            if time.monotonic() >= deadline:
                break
        rounds += 1
    print(f"fuzz: {rounds} round(s) of {len(properties)} properties x 200 examples in {minutes:g} min")
