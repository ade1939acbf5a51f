"""The OpenCV <-> USD camera conversion, both ways, checked against USD's own projection (GfFrustum)
and against a Mitsuba render; plus intrinsics validation."""

import numpy as np
import pytest
from pxr import Usd, UsdGeom
from scipy.spatial.transform import Rotation

from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.usd import camera as cam

W, H = 320, 240
K_OFFCENTER = np.array([[300.0, 0.0, 171.3], [0.0, 290.0, 112.6], [0.0, 0.0, 1.0]])


def project_cv(K, world_from_cv, points):
    """OpenCV pinhole projection of world points to pixel coordinates (centers at integers)."""
    p = se3.transform_points(se3.invert(world_from_cv), points)
    uvw = p @ K.T
    return uvw[:, :2] / uvw[:, 2:3], p[:, 2]


def test_pose_conversion_round_trip_both_ways():
    """cv -> usd -> cv and usd -> cv -> usd are identities, and the axes flip as documented."""
    rng = np.random.default_rng(0)
    poses = se3.make_pose(Rotation.random(10, random_state=0).as_matrix(), rng.normal(size=(10, 3)))
    np.testing.assert_allclose(cam.cv_camera_from_usd(cam.usd_camera_from_cv(poses)), poses, atol=1e-12)
    np.testing.assert_allclose(cam.usd_camera_from_cv(cam.cv_camera_from_usd(poses)), poses, atol=1e-12)
    usd = cam.usd_camera_from_cv(np.eye(4))
    np.testing.assert_allclose(usd[:3, 0], [1, 0, 0])  # x right in both
    np.testing.assert_allclose(usd[:3, 1], [0, -1, 0])  # USD +Y up = OpenCV -Y
    np.testing.assert_allclose(usd[:3, 2], [0, 0, -1])  # USD looks down -Z = OpenCV +Z


@pytest.mark.parametrize("K", [K_OFFCENTER, np.array([[250.0, 0, 159.5], [0, 250.0, 119.5], [0, 0, 1]])])
def test_intrinsics_round_trip(K):
    """K -> USD aperture/focal/offsets -> K is exact (fx != fy and an off-center principal point)."""
    back = cam.intrinsics_from_usd(cam.intrinsics_to_usd(K, W, H), W, H)
    np.testing.assert_allclose(back, K, atol=1e-9)


def test_usd_camera_projects_like_opencv(tmp_path):
    """Points projected by USD's own frustum (GfCamera) land where OpenCV puts them, to 1e-6 px."""
    stage = Usd.Stage.CreateInMemory()
    world_from_cv = se3.look_at([0.6, -0.5, 0.7], [0.02, 0.01, 0.05])
    cam.author_camera(stage, "/Cam", world_from_cv[None], K_OFFCENTER, W, H)
    gf_cam = UsdGeom.Camera(stage.GetPrimAtPath("/Cam")).GetCamera(Usd.TimeCode(0))
    frustum = gf_cam.frustum
    view_proj = np.array(frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix())
    points = np.random.default_rng(1).uniform(-0.1, 0.1, size=(50, 3))
    uv_cv, z = project_cv(K_OFFCENTER, world_from_cv, points)
    assert np.all(z > 0)
    homo = np.hstack([points, np.ones((50, 1))]) @ view_proj  # USD: row vectors
    ndc = homo[:, :2] / homo[:, 3:4]
    # NDC [-1, 1] spans the image's outer pixel edges; y up. Back to OpenCV pixel centers:
    u = (ndc[:, 0] + 1) / 2 * W - 0.5
    v = (1 - ndc[:, 1]) / 2 * H - 0.5
    np.testing.assert_allclose(np.stack([u, v], axis=1), uv_cv, atol=1e-6)


def test_read_camera_returns_what_was_authored():
    """author_camera then read_camera gives back the poses and the exact K of every frame."""
    stage = Usd.Stage.CreateInMemory()
    rng = np.random.default_rng(2)
    poses = se3.make_pose(Rotation.random(5, random_state=2).as_matrix(), rng.normal(size=(5, 3)))
    Ks = np.repeat(K_OFFCENTER[None], 5, axis=0)
    Ks[3, 0, 0] = 310.0  # one frame zooms: intrinsics become time-sampled
    cam.author_camera(stage, "/Cam", poses, Ks, W, H)
    track = cam.read_camera(stage, "/Cam", 5)
    np.testing.assert_allclose(track.world_from_cv, poses, atol=1e-9)
    np.testing.assert_allclose(track.K, Ks, atol=1e-9)
    assert (track.width, track.height) == (W, H)
    focal = UsdGeom.Camera(stage.GetPrimAtPath("/Cam")).GetFocalLengthAttr()
    assert focal.GetNumTimeSamples() == 5


def test_mitsuba_render_lands_where_opencv_projects():
    """A small sphere rendered by Mitsuba from an OpenCV camera appears at its OpenCV projection."""
    from rose_usd.render.lighting import Lighting
    from rose_usd.render.scene import RenderItem, RenderScene
    from rose_usd.synth.shapes import sphere
    from rose_usd.usd.geom import MeshData

    world_from_cv = se3.look_at([0.5, -0.4, 0.5], [0.0, 0.0, 0.0])
    center = np.array([0.06, 0.03, 0.02])
    ball = sphere(0.01, center, subdivisions=4)
    scene = RenderScene(
        [RenderItem("ball", MeshData(ball.vertices, ball.faces, color=(1.0, 1.0, 1.0)), label=1)], Lighting.unlit()
    )
    uv, _ = project_cv(K_OFFCENTER, world_from_cv, center[None])
    u, v = uv[0]
    _, labels = scene.depth_and_labels(world_from_cv, K_OFFCENTER, W, H)
    ys, xs = np.nonzero(labels == 1)
    assert abs(xs.mean() - u) < 0.25 and abs(ys.mean() - v) < 0.25
    img = scene.render_linear(world_from_cv, K_OFFCENTER, W, H, spp=16)[..., 0]
    total = img.sum()
    yy, xx = np.mgrid[0:H, 0:W]
    # anti-aliased centroid: a half-pixel convention error would show as 0.5 px
    assert abs((img * xx).sum() / total - u) < 0.05 and abs((img * yy).sum() / total - v) < 0.05


def test_render_labels_match_center_rays():
    """The labels the gate takes from its own re-render's samples (an item where it covers half a
    pixel's samples) are the center rays' labels but at edge pixels, also where one item hides part
    of the other and the pixels are not square; the image is the plain render's to one level."""
    from rose_usd.render.lighting import Lighting
    from rose_usd.render.scene import RenderItem, RenderScene
    from rose_usd.synth.shapes import sphere
    from rose_usd.usd.geom import MeshData

    world_from_cv = se3.look_at([0.5, -0.4, 0.5], [0.0, 0.0, 0.0])
    near, far = sphere(0.03, (0.03, 0.0, 0.05), subdivisions=4), sphere(0.05, (-0.04, 0.0, 0.0), subdivisions=4)
    scene = RenderScene(
        [
            RenderItem("near", MeshData(near.vertices, near.faces, color=(0.9, 0.2, 0.2)), label=1),
            RenderItem("far", MeshData(far.vertices, far.faces, color=(0.2, 0.9, 0.2)), label=2),
        ],
        Lighting.unlit(),
    )
    img, labels = scene.render_srgb8_and_labels(world_from_cv, K_OFFCENTER, W, H, spp=16, seed=3)
    plain = scene.render_srgb8(world_from_cv, K_OFFCENTER, W, H, spp=16, seed=3)
    assert np.abs(img.astype(int) - plain).max() <= 1
    _, center = scene.depth_and_labels(world_from_cv, K_OFFCENTER, W, H)
    for label in (1, 2):
        a, b = labels == label, center == label
        assert b.sum() > 300 and (a & b).sum() / (a | b).sum() > 0.95
    assert set(np.unique(labels)) == {0, 1, 2}


def test_depth_is_z_depth():
    """Rendered depth is distance along the optical axis, not along the ray."""
    from rose_usd.render.lighting import Lighting
    from rose_usd.render.scene import RenderItem, RenderScene
    from rose_usd.synth.shapes import box
    from rose_usd.usd.geom import MeshData

    wall = box((10.0, 10.0, 0.01), center=(0.0, 0.0, -0.005))  # its top face is the plane z = 0
    world_from_cv = se3.make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 1.5])  # looks straight down
    scene = RenderScene(
        [RenderItem("wall", MeshData(wall.vertices, wall.faces, color=(0.5, 0.5, 0.5)))], Lighting.unlit()
    )
    depth, _ = scene.depth_and_labels(world_from_cv, K_OFFCENTER, W, H)
    np.testing.assert_allclose(depth, 1.5, atol=1e-5)
    # the pixel rays are kept per camera model: a new pose, and a new size and K, are followed
    higher = se3.make_pose(se3.rotation_about(np.array([1.0, 0.0, 0.0]), 0.2) @ world_from_cv[:3, :3], [0, 0, 2.0])
    depth, _ = scene.depth_and_labels(higher, K_OFFCENTER, W, H)
    u, v = (int(round(K_OFFCENTER[i, 2])) for i in (0, 1))  # the optical axis: z-depth 2 m / cos(tilt)
    assert abs(depth[v, u] - 2.0 / np.cos(0.2)) < 0.005
    K_small = np.array([[150.0, 0.0, 80.37], [0.0, 150.0, 59.71], [0.0, 0.0, 1.0]])  # no ray along a diagonal
    depth, labels = scene.depth_and_labels(world_from_cv, K_small, 160, 120)
    assert depth.shape == labels.shape == (120, 160)
    np.testing.assert_allclose(depth, 1.5, atol=1e-5)


@pytest.mark.parametrize(
    "K,message",
    [
        (np.array([[300, 0, 400], [0, 300, 120], [0, 0, 1.0]]), "outside"),
        (np.array([[-300, 0, 160], [0, 300, 120], [0, 0, 1.0]]), "positive"),
        (np.array([[np.nan, 0, 160], [0, 300, 120], [0, 0, 1.0]]), "NaN"),
        (np.array([[300, 0, 160], [0, 300, 120], [0, 1, 1.0]]), "last row"),
        (np.array([[3.0, 0, 160], [0, 3.0, 120], [0, 0, 1.0]]), "implausible"),
        (np.eye(2), "shape"),
    ],
)
def test_check_K_rejects_intrinsics_that_cannot_fit(K, message):
    """Intrinsics that cannot belong to a 320x240 image get a one-line error."""
    with pytest.raises(InputError, match=message):
        cam.check_K(K, W, H, path="cam_K.txt")


def test_view_counts_sort_points_in_front_on_and_behind_a_seen_wall():
    """A wall at 1 m filling a camera at the origin: a point 0.5 m away was seen through, one on
    the wall was seen, one behind it was hidden (neither); with a 3x3 window a point whose
    neighbour pixel saw something nearer is not seen through, and a one-pixel hole is filled."""
    from rose_usd.core.pinhole import view_counts

    K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    depth = np.full((48, 64), 1.0, np.float32)
    depth[0, 0] = 0.0  # a hole: no evidence there
    points = np.array([[0, 0, 0.5], [0, 0, 1.005], [0, 0, 1.5], [-0.16, -0.12, 0.5], [0.05, 0, 0.5], [0.5, 0, 0.5]])
    views = [(depth, K, np.eye(4))] * 3
    through, near, observed = view_counts(points, views, tol_m=0.01)
    assert through.tolist() == [3, 0, 0, 0, 3, 0]  # the 4th falls in the hole, the 6th outside
    assert near.tolist() == [0, 3, 0, 0, 0, 0]
    assert observed.tolist() == [3, 3, 3, 0, 3, 0]
    edge = depth.copy()
    edge[25, 43] = 0.4  # beside the 5th point's pixel (42, 24): u = 32 + 100 x 0.05 / 0.5
    assert view_counts(points, [(edge, K, np.eye(4))], tol_m=0.01)[0].tolist() == [1, 0, 0, 0, 1, 0]
    assert view_counts(points, [(edge, K, np.eye(4))], tol_m=0.01, window=3)[0].tolist() == [
        1,
        0,
        0,
        1,
        0,
        0,
    ]  # the hole takes its neighbours' depth


@pytest.mark.parametrize("fixed_ground", [False, True])
def test_moved_items_render_as_their_mesh(fixed_ground):
    """An item's vertex colors and silhouette at a new pose are those of its mesh moved there: the
    same image and labels as a scene made with the item at that pose, whether the items that stay
    are kept in a scene of their own (``RenderItem.moves``) or not; colors interpolate within the
    vertex colors' range."""
    from rose_usd.render.lighting import Lighting
    from rose_usd.render.scene import RenderItem, RenderScene
    from rose_usd.synth.shapes import box, sphere
    from rose_usd.usd.geom import MeshData

    ball = sphere(0.05, (0.0, 0.0, 0.0), subdivisions=4)
    colors = (np.asarray(ball.vertices) / 0.1 + 0.5).clip(0.0, 1.0)
    ground = box((1.0, 1.0, 0.02), (0.0, 0.0, -0.08))
    pose = se3.make_pose(se3.rotation_about(np.array([0.3, 0.2, 1.0]) / 1.08, 0.7), np.array([0.02, -0.01, 0.01]))
    world_from_cv = se3.look_at([0.0, -0.4, 0.3], [0.0, 0.0, 0.0])

    def scene(at):
        return RenderScene(
            [
                RenderItem(
                    "ground", MeshData(ground.vertices, ground.faces, color=(0.5, 0.5, 0.5)), moves=not fixed_ground
                ),
                RenderItem("ball", MeshData(ball.vertices, ball.faces, vertex_colors=colors), label=1, pose=at),
            ],
            Lighting.unlit(),
        )

    moved = scene(np.eye(4))
    moved.set_poses({"ball": pose})
    made = scene(pose)
    a, b = (
        moved.surface(world_from_cv, K_OFFCENTER, W, H, with_albedo=True),
        made.surface(world_from_cv, K_OFFCENTER, W, H, with_albedo=True),
    )
    on = b.labels == 1
    assert on.sum() > 500 and np.array_equal(a.labels, b.labels)
    np.testing.assert_allclose(a.albedo[on], b.albedo[on], atol=1e-5)
    assert a.albedo[on].min() >= colors.min() - 1e-4 and a.albedo[on].max() <= colors.max() + 1e-4
    img_a = moved.render_srgb8(world_from_cv, K_OFFCENTER, W, H, spp=4, seed=2)
    img_b = made.render_srgb8(world_from_cv, K_OFFCENTER, W, H, spp=4, seed=2)
    assert (np.abs(img_a.astype(int) - img_b).max(axis=-1) > 2).mean() < 0.002
    if fixed_ground:
        with pytest.raises(ValueError, match="moves=False"):
            moved.set_poses({"ground": pose})
