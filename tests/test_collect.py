"""The collect stage on the sample's oracle reconstruction: a box too wide for the gripper says
so; the same box at 3/4 size is grasped and carried along its path by simulated rollouts whose
layer validates and whose datasets read back as the rollouts were logged; bad inputs give a
layer that says what is wrong."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from conftest import oracle_options
from pxr import Gf, Sdf, Usd, UsdPhysics, Vt

from rose_usd.io import lerobot, robomimic
from rose_usd.layers.robot import read_collect
from rose_usd.pipeline import Options, Pipeline
from rose_usd.usd import paths, tokens
from rose_usd.usd.stage import layer_file, open_stage
from rose_usd.usd.validate import validate

FAST = {"grasps": 1, "perturbations": 2}


def _collect(case, out, **settings):
    options = oracle_options()
    Pipeline(case, out, Options(backends=options.backends, settings={"collect": {**FAST, **settings}})).run("collect")
    return read_collect(open_stage(out / "rose.usda"))


def _shrink_object(out, factor: float) -> None:
    """Scale the oracle box's meshes, centre of mass, mass and inertia in its layer (it stands on z = 0)."""
    layer = Sdf.Layer.FindOrOpen(str(layer_file(out, "object")))
    stage = Usd.Stage.Open(layer)
    for path in (paths.object_visual("Box"), paths.object_collision("Box")):
        attr = stage.GetPrimAtPath(path).GetAttribute("points")
        attr.Set(Vt.Vec3fArray.FromNumpy(np.asarray(attr.Get(), dtype=np.float32) * factor))
        extent = stage.GetPrimAtPath(path).GetAttribute("extent")
        extent.Set(Vt.Vec3fArray.FromNumpy(np.asarray(extent.Get(), dtype=np.float32) * factor))
    mass = UsdPhysics.MassAPI(stage.GetPrimAtPath(paths.object_path("Box")))
    mass.GetMassAttr().Set(mass.GetMassAttr().Get() * factor**3)
    mass.GetCenterOfMassAttr().Set(Gf.Vec3f(*(np.asarray(mass.GetCenterOfMassAttr().Get()) * factor).tolist()))
    mass.GetDiagonalInertiaAttr().Set(Gf.Vec3f(*(np.asarray(mass.GetDiagonalInertiaAttr().Get()) * factor**5).tolist()))
    layer.Save()


@pytest.fixture(scope="module")
def small_box_out(tmp_path_factory, oracle_out, sample_case):
    """The oracle reconstruction with the box at 3/4 size (6.6 x 6.1 x 5.9 cm), collected."""
    out = tmp_path_factory.mktemp("collect") / "out"
    shutil.copytree(oracle_out, out)
    _shrink_object(out, 0.75)
    _collect(sample_case, out)
    return out


def test_a_box_wider_than_the_gripper_gets_a_layer_that_says_so(oracle_out):
    """The sample's box is 7.9 cm across its narrowest faces: no rollout, status no-grasp, a
    message with the widths, and a valid stage."""
    result = read_collect(open_stage(oracle_out / "rose.usda"))
    assert result.status == "no-grasp" and result.rollouts == 0
    assert "too large for the gripper" in result.message and "7.9 cm" in result.message
    assert not (oracle_out / "dataset" / "lerobot").exists()


def test_a_failed_gate_gets_a_layer_that_says_so_and_no_rollout(tmp_path, oracle_out, sample_case):
    """sam2-cups' gate failed (the path left the cup for 2 s) and collect still made a dataset of
    that path: collect needs the gate, and where it failed writes status gate-failed, naming why,
    unless collect.after_failed_gate lets it go on."""
    out = tmp_path / "out"
    shutil.copytree(oracle_out, out)
    layer = Sdf.Layer.FindOrOpen(str(layer_file(out, "gate")))
    stage = Usd.Stage.Open(layer)
    gate = stage.GetPrimAtPath(paths.GATE)
    gate.GetAttribute(tokens.GATE_PASSED).Set(False)
    gate.GetAttribute(tokens.GATE_SSIM_MEAN).Set(0.512)
    layer.Save()
    result = _collect(sample_case, out)
    assert result.status == "gate-failed" and result.rollouts == 0
    assert result.message.startswith("the gate failed (SSIM 0.512 under 0.75)"), result.message
    assert "collect.after_failed_gate = true" in result.message
    assert not (out / "dataset" / "lerobot").exists()
    assert validate(out / "rose.usda", with_newton=False).ok
    from rose_usd.usd.inspect import dump, to_text

    shown = to_text(dump(out / "rose.usda"))
    assert "collect: Panda moves nothing: status gate-failed\n  the gate failed (SSIM 0.512" in shown, shown
    assert "rollouts: 0/0" not in shown
    result = _collect(sample_case, out, after_failed_gate=True)  # the true box: too wide to grasp
    assert result.status == "no-grasp", result.message


def test_rollouts_succeed_on_a_box_that_fits(small_box_out):
    """Both rollouts (as reconstructed, perturbed) carry the box along its path within the limits."""
    result = read_collect(open_stage(small_box_out / "rose.usda"))
    assert result.status == "ok", result.message
    assert result.rollouts == 2 and result.successes == 2 and result.success_rate == 1.0
    assert np.all(result.mean_error_m < 0.03) and np.all(result.final_error_m < 0.03)
    assert np.all(result.drift_m < 0.02) and np.all(result.penetration_m < 0.01)
    assert result.joint_names[0] == "panda_joint1" and len(result.joint_names) == 9


def test_robot_layer_is_valid_owned_and_animated(small_box_out):
    """robot.usda holds only /World/Robots specs, the stage validates with 0 errors, and the links
    move over the video's time codes."""
    layer = Sdf.Layer.FindOrOpen(str(layer_file(small_box_out, "robot")))
    assert paths.ownership_violations(layer, "robot") == []
    report = validate(small_box_out / "rose.usda", with_newton=False)
    assert report.errors == []
    stage = open_stage(small_box_out / "rose.usda")
    hand = stage.GetPrimAtPath(paths.robot_link("Panda", "panda_hand"))
    xf = hand.GetAttribute("xformOp:transform")
    assert xf.GetNumTimeSamples() == 48
    assert np.linalg.norm(np.array(xf.Get(47))[3, :3] - np.array(xf.Get(0))[3, :3]) > 0.1  # the box moves 20 cm
    names = [p.rsplit("/", 1)[-1].split(".")[0] for p in stage.GetRootLayer().subLayerPaths]
    assert names == [n for n in paths.LAYER_ORDER if n in names] and "robot" in names


def test_datasets_read_back_as_the_rollouts(small_box_out):
    """LeRobot frames, robomimic demos and the layer's joint samples agree on every successful rollout."""
    stage = open_stage(small_box_out / "rose.usda")
    result = read_collect(stage)
    assert result.dataset is not None and result.dataset.endswith("lerobot/meta/info.json")
    info, frames, episodes, tasks = lerobot.read_dataset(small_box_out / "dataset" / "lerobot")
    assert result.robomimic == str((small_box_out / "dataset" / "robomimic.hdf5").resolve())
    demos, env_args = robomimic.read_hdf5(result.robomimic)
    from rose_usd.usd.inspect import dump, to_text

    assert "datasets: dataset/lerobot/meta/info.json (LeRobot v3) and dataset/robomimic.hdf5" in to_text(
        dump(small_box_out / "rose.usda")
    )
    assert info["total_episodes"] == len(demos) == result.successes == len(episodes)
    assert tasks == ["move the box along its demonstrated path"]
    assert info["fps"] == 30 and info["features"]["observation.state"]["names"][7] == "panda_finger_joint1"
    for e, demo in enumerate(demos):
        rows = frames["episode_index"] == e
        np.testing.assert_allclose(frames["observation.state"][rows], demo.obs["robot0_joint_pos"], rtol=1e-6)
        np.testing.assert_allclose(frames["action"][rows], demo.actions, rtol=1e-6)
        assert episodes[e]["length"] == demo.attrs["num_samples"] == rows.sum()
    best = result.best_rollout
    # the layer's joint states are the best rollout's follow ticks: video frame t = tick follow_start + t
    demo = demos[[i for i, ok in enumerate(result.rollout_success) if ok].index(best)]
    start = demo.attrs["follow_start"]
    layer_q = result.joint_positions(stage, 48)
    np.testing.assert_allclose(layer_q, demo.obs["robot0_joint_pos"][start : start + 48], atol=1e-5)
    # the object's pose in the dataset follows the reconstructed path (base frame, lifted 1 cm)
    base = result.base_pose
    obj = frames["observation.environment_state"][frames["episode_index"] == 0][start : start + 48, :3]
    world = obj @ base[:3, :3].T + base[:3, 3]
    from rose_usd.layers.trajectory import object_poses

    path = object_poses(stage, "Box", 48)[:, :3, 3]
    assert np.linalg.norm(world - path, axis=1).mean() < 0.03
    assert env_args["env_kwargs"]["object"] == "Box"


def test_an_object_without_a_collider_gets_a_layer_that_says_so(tmp_path, small_box_out, sample_case):
    """With the Collision prim's CollisionAPI removed, collect writes status no-collider, no rollout."""
    out = tmp_path / "out"
    shutil.copytree(small_box_out, out)
    layer = Sdf.Layer.FindOrOpen(str(layer_file(out, "object")))
    stage = Usd.Stage.Open(layer)
    stage.GetPrimAtPath(paths.object_collision("Box")).RemoveAPI(UsdPhysics.CollisionAPI)
    layer.Save()
    result = _collect(sample_case, out, after_failed_gate=True)  # the gate's collider check fails
    assert result.status == "no-collider" and "no collision mesh" in result.message and result.rollouts == 0


def test_an_object_held_in_every_frame_gets_a_layer_that_says_so(tmp_path, small_box_out, sample_case):
    """The box's path raised 5 cm and moved 1 cm every frame (held on a rod through the video, as
    deepac-cat-rgb's cat): it rests in no frame, so there is nothing to pick it up from: status
    not-resting, no rollout (before, 12 rollouts flung the falling cat kilometres away)."""
    out = tmp_path / "out"
    shutil.copytree(small_box_out, out)
    layer = Sdf.Layer.FindOrOpen(str(layer_file(out, "trajectory")))
    stage = Usd.Stage.Open(layer)
    translate = stage.GetPrimAtPath(paths.object_path("Box")).GetAttribute("xformOp:translate")
    for t in translate.GetTimeSamples():
        p = translate.Get(Usd.TimeCode(t))
        translate.Set(type(p)(p[0] + 0.01 * t, p[1], p[2] + 0.05), Usd.TimeCode(t))
    layer.Save()
    result = _collect(sample_case, out, after_failed_gate=True)  # the gate's track check fails
    assert result.status == "not-resting" and result.rollouts == 0
    assert "'Box' rests in no frame" in result.message


def test_a_path_out_of_reach_gets_a_layer_that_says_so(tmp_path, small_box_out, sample_case):
    """A base placed 2 m away (rose.toml / --set collect.base) reaches nothing: status unreachable."""
    out = tmp_path / "out"
    shutil.copytree(small_box_out, out)
    result = _collect(sample_case, out, base="2.0,2.0")
    assert result.status == "unreachable" and "reach" in result.message and result.rollouts == 0
    assert np.allclose(result.base_pose[:2, 3], [2.0, 2.0])


def test_rendered_video_shows_the_robot_from_the_reconstructed_camera(tmp_path, small_box_out, sample_case):
    """collect.render: the LeRobot dataset gets an AV1 camera stream with a frame per tick, at
    half the video's size, and the robot is in it: against the stage rendered without the robot
    at the same frame, the pixels around the hand's projection differ."""
    from rose_usd.collect.video import even_size
    from rose_usd.io.video import read_frames, video_info
    from rose_usd.layers.world import read_cameras
    from rose_usd.render.from_usd import StageRenderer
    from rose_usd.sim import panda

    out = tmp_path / "out"
    shutil.copytree(small_box_out, out)
    result = _collect(sample_case, out, render=True, perturbations=1)
    assert result.successes == 1, result.message
    root = out / "dataset" / "lerobot"
    info, frames, rows, _ = lerobot.read_dataset(root)
    stage = open_stage(out / "rose.usda")
    cameras = read_cameras(stage, 48)
    width, height = even_size(cameras.width, cameras.height, 0.5)
    assert info["features"]["observation.images.camera"]["shape"] == [height, width, 3]
    path = root / info["video_path"].format(video_key="observation.images.camera", chunk_index=0, file_index=0)
    meta = video_info(path)
    assert (meta["frames"], meta["width"], meta["height"]) == (info["total_frames"], width, height)
    demos, _ = robomimic.read_hdf5(out / "dataset" / "robomimic.hdf5")
    t = 24  # the video frame half way through the follow; episode 0 starts the file
    tick = demos[0].attrs["follow_start"] + t
    video = next(f for i, f in enumerate(read_frames(path)) if i == tick)
    K = np.diag([width / cameras.width, height / cameras.height, 1.0]) @ cameras.K[t]
    renderer = StageRenderer(stage)
    renderer.pose_at(t)
    without = renderer.scene.render_srgb8(cameras.world_from_cv[t], K, width, height, spp=4, seed=t)
    q = frames["observation.state"][tick]
    hand = read_collect(stage).base_pose @ panda.chain().forward(q[None])[0, panda.chain().links.index("panda_hand")]
    cv = np.linalg.inv(cameras.world_from_cv[t]) @ hand[:, 3]
    u, v = (K @ (cv[:3] / cv[2]))[:2].round().astype(int)
    differs = np.abs(video.astype(int) - without.astype(int)).max(axis=2) > 20
    assert 0 <= u < width and 0 <= v < height
    assert differs[max(v - 4, 0) : v + 5, max(u - 4, 0) : u + 5].mean() > 0.5


def _add_to_scene_collider(out, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Append a closed mesh (world frame; the scene prim has no transform) to the scene's collider."""
    from pxr import UsdGeom

    layer = Sdf.Layer.FindOrOpen(str(layer_file(out, "scene")))
    stage = Usd.Stage.Open(layer)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(paths.SCENE_COLLISION))
    points = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float32)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), dtype=np.int32)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int32)
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.concatenate([points, vertices.astype(np.float32)])))
    mesh.GetFaceVertexCountsAttr().Set(
        Vt.IntArray.FromNumpy(np.concatenate([counts, np.full(len(faces), 3, np.int32)]))
    )
    indices = np.concatenate([indices, (faces + len(points)).ravel().astype(np.int32)])
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(indices))
    everything = np.concatenate([points, vertices])
    mesh.GetExtentAttr().Set(
        Vt.Vec3fArray.FromNumpy(np.stack([everything.min(0), everything.max(0)]).astype(np.float32))
    )
    layer.Save()


def test_an_obstacle_on_the_straight_approach_is_gone_around(tmp_path, small_box_out, sample_case):
    """A 4.5 cm cube put into the scene where the wrist passed on its way from home to the pre-grasp
    (the base kept where it stood): the approach is planned around it (OMPL), the arm's logged
    joint positions keep it clear, and the rollouts still carry the box."""
    import trimesh

    from rose_usd.collect import planning
    from rose_usd.sim import panda
    from rose_usd.usd.stage import read_provenance

    before = read_collect(open_stage(small_box_out / "rose.usda"))
    demos, _ = robomimic.read_hdf5(small_box_out / "dataset" / "robomimic.hdf5")
    q = demos[0].obs["robot0_joint_pos"]
    approach = np.arange(int(round(0.2 * 30)), int(round((0.2 + 1.5) * 30)))  # home 0.2 s, approach 1.5 s at 30 fps

    def cube_at(tick):
        wrist = before.base_pose @ panda.chain().forward(q[tick])[panda.chain().index("panda_link7")]
        cube = trimesh.creation.box(extents=[0.045, 0.045, 0.045])
        cube.apply_translation(wrist[:3, 3])
        vf = (np.asarray(cube.vertices), np.asarray(cube.faces))
        return vf, planning.ArmChecker(before.base_pose, [vf])

    # the cube where the wrist passed, as far from the arm at home and at the pre-grasp as can be
    ends = q[[0, approach[-1]]]
    tick = max(approach[::3], key=lambda t: cube_at(t)[1].clearance(ends).min())
    cube, obstacle = cube_at(tick)
    assert obstacle.clearance(q[approach]).min() < 0  # the old approach went through it
    assert obstacle.clearance(ends).min() > 0.02  # home and the pre-grasp are clear

    out = tmp_path / "out"
    shutil.copytree(small_box_out, out)
    _add_to_scene_collider(out, *cube)
    options = oracle_options()
    Pipeline(sample_case, out, Options(backends=options.backends)).run("object")  # the scene changed
    _shrink_object(out, 0.75)
    x, y = before.base_pose[:2, 3]
    yaw = np.degrees(np.arctan2(before.base_pose[1, 0], before.base_pose[0, 0]))
    result = _collect(sample_case, out, base=f"{x},{y},{yaw}")
    assert result.status == "ok" and result.successes >= 1, result.message
    assert set(read_provenance(layer_file(out, "robot"))["results"]["rollout_approach"]) == {"planned"}
    demos, _ = robomimic.read_hdf5(out / "dataset" / "robomimic.hdf5")
    for demo in demos:  # from home to the start of the follow, the arm kept clear of the cube
        assert obstacle.clearance(demo.obs["robot0_joint_pos"][: demo.attrs["follow_start"]]).min() > 0


def test_an_object_the_gripper_cannot_take_is_passed_over_for_the_next(monkeypatch):
    """Objects are tried longest path first; one no grasp fits (visp-desk's 8.45 cm cube) is passed
    over, with a warning, for the next one that can be grasped (its dragon); when none can, the
    layer says why for the first and names the others' reasons."""
    from types import SimpleNamespace

    from rose_usd.collect import grasping
    from rose_usd.collect import newton_backend as nb

    path = np.repeat(np.eye(4)[None], 3, axis=0)
    warned, finished = [], []
    ctx = SimpleNamespace(warn=warned.append)

    def grasps(cfg, target, path, outcome, rng, clearance):
        if target == "Cube":
            raise grasping.NoGrasp("the object is too large for the gripper")
        return "candidates", "ranked", []

    monkeypatch.setattr(nb, "_pick_objects", lambda ctx, cfg: [("Cube", path), ("Dragon", path)])
    monkeypatch.setattr(nb, "_unmovable", lambda ctx, name: None)
    monkeypatch.setattr(nb, "_target", lambda ctx, name, path, rng: name)
    monkeypatch.setattr(nb, "_grasps_and_base", grasps)
    monkeypatch.setattr(nb, "_finish", lambda ctx, outcome: finished.append(outcome))
    name, _, target, outcome, plan = nb._planned(ctx, None, None, lambda name: None)
    assert (name, target, outcome.object_name, plan[1]) == ("Dragon", "Dragon", "Dragon", "ranked")
    assert warned == ["the robot moves 'Dragon', passing over 'Cube' (the object is too large for the gripper)"]
    assert not finished

    monkeypatch.setattr(nb, "_pick_objects", lambda ctx, cfg: [("Cube", path), ("Cube2", path)])
    monkeypatch.setattr(nb, "_unmovable", lambda ctx, name: nb.Outcome("not-resting", "held", object_name=name))
    assert nb._planned(ctx, None, None, lambda name: None) is None
    assert finished[0].status == "not-resting" and finished[0].object_name == "Cube"
    assert finished[0].message == "held (nor any other object: 'Cube2': held)"


def test_a_surface_with_no_opposing_points_is_not_called_too_large():
    """A mesh no two points of which face each other (one triangle) has no antipodal grasp at any
    width: the message says so, not that the object is too large for the gripper."""
    from rose_usd.collect import grasping

    vertices = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0]])
    with pytest.raises(grasping.NoGrasp) as err:
        grasping._antipodal_pairs(
            vertices,
            np.array([[0, 1, 2]]),
            friction=0.5,
            max_width_m=0.08,
            surface_points=200,
            max_pairs=100,
            rng=np.random.default_rng(0),
        )
    assert "face each other" in str(err.value) and "too large" not in str(err.value)
