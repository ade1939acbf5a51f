"""Perception modes write files in each tool's exact format (formats.md), and what they hold agrees
with the ground truth within the simulated errors (read back here; importers come with later issues)."""

import json

import numpy as np
import pytest
from PIL import Image

from rose_usd.bench.modes import ModeOptions, PerceptionMode, make_mode_case, mode_stamp
from rose_usd.case import load_case
from rose_usd.case.gt import GroundTruth
from rose_usd.core import se3
from rose_usd.io import foundationpose, geocalib, megasam, sam2, trellis, unidepth
from rose_usd.io.images import read_depth_m, read_mask
from rose_usd.synth.generate import GenerateConfig, generate_case
from rose_usd.synth.motion import Task
from rose_usd.synth.shapes import ObjectShape


@pytest.fixture(scope="module")
def base_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("modes") / "base"
    return generate_case(
        GenerateConfig(task=Task.UNSTACK, shape=ObjectShape.CAN, seed=5, n_frames=12, width=128, height=96, spp=4), out
    )


@pytest.fixture(scope="module")
def mono(base_case):
    return make_mode_case(base_case, PerceptionMode.MONO_IMPORTED, base_case.parent / "mono", seed=5)


def test_mode_layouts(base_case, tmp_path):
    """rgbd keeps depth and K; rgb keeps frames only; every mode keeps gt/ and rose.toml."""
    rgbd = make_mode_case(base_case, PerceptionMode.RGBD, tmp_path / "rgbd", seed=5)
    rgb = make_mode_case(base_case, PerceptionMode.RGB, tmp_path / "rgb", seed=5)
    assert load_case(rgbd).has_depth and (rgbd / "cam_K.txt").is_file()
    assert not load_case(rgb).has_depth and not (rgb / "cam_K.txt").exists() and not (rgb / "perception").exists()
    for case in (rgbd, rgb):
        assert (case / "gt" / "scene.json").is_file() and (case / "rose.toml").is_file()


def test_rgb_mode_with_the_size_prior_gives_each_object_its_largest_true_extent(base_case, tmp_path):
    """--size-prior: rose.toml gives size_m per object (prompts kept); the generated case's file is untouched."""
    before = (base_case / "rose.toml").read_text()
    rgb = make_mode_case(
        base_case, PerceptionMode.RGB, tmp_path / "rgb-size", seed=5, options=ModeOptions(size_prior=True)
    )
    truth = {o["name"]: max(o["size_m"]) for o in json.loads((base_case / "gt" / "scene.json").read_text())["objects"]}
    objects = {o.name: o for o in load_case(rgb).config.objects}
    assert set(truth) <= set(objects)
    for name, size in truth.items():
        assert objects[name].overrides["size_m"] == pytest.approx(size, abs=1e-5)
        assert objects[name].prompt is not None
    assert (base_case / "rose.toml").read_text() == before


def test_rgb_mode_with_the_intrinsics_keeps_cam_K_and_nothing_else(base_case, tmp_path):
    """--intrinsics: the rgb case gets the generated case's cam_K.txt (no depth), in its own folder
    with its own stamp; rgbd, which keeps cam_K.txt anyway, is unchanged by it."""
    options = ModeOptions(intrinsics=True)
    rgb = make_mode_case(base_case, PerceptionMode.RGB, tmp_path / options.folder(PerceptionMode.RGB), 5, options)
    assert rgb.name == "rgb-K"
    assert (rgb / "cam_K.txt").read_text() == (base_case / "cam_K.txt").read_text()
    assert not load_case(rgb).has_depth
    assert (rgb / ".mode").read_text() == mode_stamp(PerceptionMode.RGB, options) != mode_stamp(PerceptionMode.RGB)
    assert options.folder(PerceptionMode.RGBD) == "rgbd"
    assert mode_stamp(PerceptionMode.RGBD, options) == mode_stamp(PerceptionMode.RGBD)


def test_megasam_npz_format_and_scale(mono):
    """The npz has exactly MegaSaM's keys and dtypes; depth is the true depth at one unknown scale."""
    path = mono / "perception" / "scene_sgd_cvd_hr.npz"
    raw = np.load(path)
    assert sorted(raw.files) == ["cam_c2w", "depths", "images", "intrinsic"]
    assert raw["depths"].dtype == np.float16 and raw["images"].dtype == np.uint8
    assert raw["images"].shape[-1] == 3 and raw["depths"].shape == raw["images"].shape[:3]
    assert float(raw["depths"].min()) >= 1e-3 and float(raw["depths"].max()) <= 1e2
    out = megasam.read_megasam(path)
    truth = json.loads((mono / "perception" / "simulated.json").read_text())["megasam"]
    gt = GroundTruth(mono / "gt")
    h, w = out.depths.shape[1:]
    clean = read_depth_m(gt.depth_dir / "000000.png")
    import cv2

    clean = cv2.resize(clean, (w, h), interpolation=cv2.INTER_NEAREST)
    valid = clean > 0
    ratio = np.median(out.depths[0][valid].astype(float) / clean[valid])
    assert ratio == pytest.approx(truth["scale"], rel=0.08)
    np.testing.assert_allclose(out.cam_c2w[0], np.eye(4), atol=1e-3)  # MegaSaM's world is its first camera


def test_megasam_reader_names_missing_keys(tmp_path):
    """An npz without MegaSaM's keys is refused with the missing keys named."""
    np.savez(tmp_path / "x.npz", images=np.zeros((1, 4, 4, 3), np.uint8))
    from rose_usd.errors import InputError

    with pytest.raises(InputError, match="lacks key"):
        megasam.read_megasam(tmp_path / "x.npz")


def test_unidepth_frames(mono):
    """One npz per frame with metric depth (meters), fov in degrees, intrinsics and confidence."""
    files = sorted((mono / "perception" / "unidepth").glob("*.npz"))
    assert len(files) == 12
    frame = unidepth.read_unidepth(files[3])
    gt = GroundTruth(mono / "gt")
    clean = read_depth_m(gt.depth_dir / "000003.png")
    assert frame.depth_m.shape == clean.shape and frame.depth_m.dtype == np.float32
    assert np.median(frame.depth_m[clean > 0] / clean[clean > 0]) == pytest.approx(1.0, abs=0.12)
    assert frame.fov_deg == pytest.approx(np.degrees(2 * np.arctan(gt.width / (2 * gt.K[0, 0]))), abs=3.0)
    assert frame.intrinsics.shape == (3, 3) and frame.confidence.shape == clean.shape


def test_geocalib_up_vector_convention(mono):
    """gravity is the UP vector in OpenCV camera axes of frame 0, consistent with rp by GeoCalib's
    formula, within the simulated error of the true up."""
    raw = json.loads((mono / "perception" / "geocalib.json").read_text())
    calib = geocalib.read_geocalib(mono / "perception" / "geocalib.json")
    np.testing.assert_allclose(geocalib.up_from_rp(*raw["rp"]), raw["gravity"], atol=1e-9)
    gt = GroundTruth(mono / "gt")
    true_up = gt.camera_poses()[0][:3, :3].T @ np.array([0.0, 0.0, 1.0])
    err = np.degrees(np.arccos(np.clip(calib.up_cam @ true_up, -1, 1)))
    assert err < 3.0
    assert calib.up_cam[1] < -0.3  # a camera looking down at a table: up points to image -y


def test_sam2_masks_are_davis_paletted(mono):
    """Masks are mode-P PNGs named by integer frame index, ids 1..K in rose.toml order, close to the true masks."""
    files = sorted((mono / "perception" / "masks").glob("*.png"))
    assert [f.name for f in files[:2]] == ["00000.png", "00001.png"]
    with Image.open(files[4]) as img:
        assert img.mode == "P"
        assert img.getpalette()[:9] == [0, 0, 0, 128, 0, 0, 0, 128, 0]
    index = sam2.read_masks(mono / "perception" / "masks")
    names = [o.name for o in load_case(mono).config.objects]
    gt = GroundTruth(mono / "gt")
    for obj_id, name in enumerate(names, start=1):
        mask = sam2.read_object_mask(index[4], obj_id)
        truth = read_mask(gt.mask_dir(name) / "000004.png")
        if truth.sum() > 50:
            iou = (mask & truth).sum() / (mask | truth).sum()
            assert iou > 0.6


def test_sam2_boundary_errors_at_full_resolution():
    """At 640 px wide, simulated SAM 2 boundaries move by about 1.5 px: an 80 px disk keeps a mean
    IoU of 0.9-0.99 with its truth over seeds (errors present, and small)."""
    from rose_usd.synth.perception import _perturb_mask

    yy, xx = np.mgrid[0:480, 0:640]
    disk = (xx - 320) ** 2 + (yy - 240) ** 2 < 40**2
    ious = []
    for seed in range(5):
        noisy = _perturb_mask(disk, np.random.default_rng(seed), 1.5)
        ious.append((noisy & disk).sum() / (noisy | disk).sum())
    assert 0.9 < np.mean(ious) < 0.99 and min(ious) > 0.85


def test_trellis_glb_and_foundationpose_agree_with_truth(mono):
    """The GLB lies in [-0.5, 0.5]^3, Y-up, textured; FoundationPose's T_cam<-object, applied to the
    GLB scaled to meters, puts the mesh where the true object is in the camera."""
    gt = GroundTruth(mono / "gt")
    info = json.loads((mono / "perception" / "simulated.json").read_text())["objects"]
    for obj in gt.objects:
        mesh = trellis.read_trellis_glb(mono / "perception" / f"{obj.name}.glb")
        assert np.abs(mesh.vertices).max() <= 0.5 + 1e-6
        assert mesh.visual.uv is not None and mesh.visual.material.baseColorTexture is not None
        extents = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
        assert extents.max() == pytest.approx(1.0, abs=1e-3)
        true_mesh = gt.object_mesh(obj.name)
        true_height = true_mesh.vertices[:, 2].max() - true_mesh.vertices[:, 2].min()
        assert extents[1] * info[obj.name]["scale_m_per_unit"] == pytest.approx(
            true_height, abs=0.004
        )  # Y is up; shape noise ~1 mm
        t = 6
        pose = foundationpose.read_pose(mono / "perception" / "ob_in_cam" / obj.name / f"{t:06d}.txt")
        in_cam = se3.transform_points(pose, mesh.vertices * info[obj.name]["scale_m_per_unit"])
        true_in_cam = se3.transform_points(
            se3.invert(gt.camera_poses()[t]) @ gt.object_poses(obj.name)[t], true_mesh.vertices
        )
        assert np.linalg.norm(in_cam.mean(axis=0) - true_in_cam.mean(axis=0)) < 0.015
        # the jitter of the mesh's center over the frames where the object is in full view is the
        # translation jitter (2 mm per axis), not the rotation jitter times the camera distance
        # (~7 mm per axis at 0.6 deg and 0.7 m); the constant offset of the two meshes' centers is
        # left out
        area = np.array([read_mask(gt.mask_dir(obj.name) / f"{u:06d}.png").sum() for u in range(gt.n_frames)])
        center = mesh.vertices.mean(axis=0) * info[obj.name]["scale_m_per_unit"]
        errs = []
        for u in np.flatnonzero(area > 0.8 * area.max()):
            pose = foundationpose.read_pose(mono / "perception" / "ob_in_cam" / obj.name / f"{u:06d}.txt")
            truth = se3.invert(gt.camera_poses()[u]) @ gt.object_poses(obj.name)[u]
            errs.append(
                se3.transform_points(pose, center[None])[0]
                - se3.transform_points(truth, true_mesh.vertices).mean(axis=0)
            )
        jitter = np.asarray(errs) - np.mean(errs, axis=0)
        assert np.sqrt(np.mean(np.sum(jitter**2, axis=1))) < 0.006, obj.name


def test_foundationpose_rejects_a_non_rotation(tmp_path):
    """A pose file whose rotation is not a rotation is refused with the file named."""
    from rose_usd.errors import InputError

    bad = np.eye(4)
    bad[0, 0] = 2.0
    np.savetxt(tmp_path / "000000.txt", bad)
    with pytest.raises(InputError, match="not a rotation"):
        foundationpose.read_pose(tmp_path / "000000.txt")
