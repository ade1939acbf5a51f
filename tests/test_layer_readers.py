"""rose_usd.layers reads each layer back: what later stages (and users) get from a stage."""

from __future__ import annotations

import numpy as np
import pytest

from rose_usd import registry
from rose_usd.case.gt import GroundTruth
from rose_usd.case.layout import load_case
from rose_usd.errors import InputError, StageError
from rose_usd.io.images import read_mask
from rose_usd.layers.gate import read_gate
from rose_usd.layers.masks import INTERACTOR, read_masks
from rose_usd.layers.objects import default_pose, object_paths, visual_mesh
from rose_usd.layers.scene import scene_collider, support_heights
from rose_usd.layers.trajectory import confidence, object_poses
from rose_usd.layers.world import depth_is_sensor, metric_depth_reader, read_cameras
from rose_usd.usd.stage import open_stage


def test_readers_on_the_oracle_reconstruction(oracle_out, sample_case):
    stage = open_stage(oracle_out / "rose.usda")
    gt = GroundTruth(sample_case / "gt")
    n = gt.n_frames
    cameras = read_cameras(stage, n)
    assert cameras.world_from_cv.shape == (n, 4, 4) and cameras.K.shape == (n, 3, 3)
    assert depth_is_sensor(stage)
    case = load_case(sample_case, registry.STAGE_NAMES)
    depth = metric_depth_reader(stage, case)(0)
    assert depth.shape == (case.height, case.width) and depth.max() > 0

    masks = read_masks(stage, n, (case.height, case.width))
    assert masks.names == ["Box"] and masks.has(INTERACTOR)
    masks.require("Box")
    with pytest.raises(InputError, match="no masks of object 'Ghost'"):
        masks.require("Ghost")  # an object added to rose.toml after the segment stage ran
    # the file is the masks layer's asset, the same mask the segment stage wrote
    assert masks.file("Box", 5) == (oracle_out / "masks" / "Box" / "000005.png").resolve()
    assert np.array_equal(masks.mask("Box", 5), read_mask(oracle_out / "masks" / "Box" / "000005.png"))
    assert int(masks.mask("Box", 5).sum()) == int(masks.visible_pixels("Box")[5])
    assert not masks.occluders("Box", 5, (case.height, case.width), grow_px=0)[masks.mask("Box", 5)].all()

    vertices, faces = scene_collider(stage)
    assert len(vertices) and len(faces)
    assert support_heights(stage) == {}  # the oracle scene lays no pads

    assert list(object_paths(stage)) == ["Box"]
    mesh = visual_mesh(stage, "Box")
    assert mesh.vertices.shape[1] == 3
    poses = object_poses(stage, "Box", n)
    assert np.allclose(poses[0], default_pose(stage, "Box"), atol=1e-6)
    conf = confidence(stage, "Box", n)
    assert conf is not None and conf.shape == (n,)
    assert read_gate(stage).passed


def test_depth_reader_applies_the_world_layers_depth_shift(oracle_out, sample_case):
    """A world layer that records rose:world:depthShiftPx makes every reader's depth shifted."""
    from pxr import Gf

    from rose_usd.usd import paths, tokens

    stage = open_stage(oracle_out / "rose.usda")
    case = load_case(sample_case, registry.STAGE_NAMES)
    raw = metric_depth_reader(stage, case)(3)
    stage.SetEditTarget(stage.GetSessionLayer())  # this stage only: the layers on disk stay as they are
    stage.GetPrimAtPath(paths.WORLD).GetAttribute(tokens.WORLD_DEPTH_SHIFT_PX).Set(Gf.Vec2i(-5, 2))
    shifted = metric_depth_reader(stage, case)(3)
    assert np.array_equal(shifted[2:, :-5], raw[:-2, 5:])
    assert not shifted[:2].any() and not shifted[:, -5:].any()


def test_readers_name_the_missing_layer(tmp_path, oracle_out):
    """A stage without the masks layer: the reader says which stage to run, in one line."""
    stage = open_stage(oracle_out / "layers" / "world.usda")
    with pytest.raises(StageError, match="segment"):
        read_masks(stage, 3)
    with pytest.raises(StageError, match="object stage"):
        visual_mesh(stage, "Box")
