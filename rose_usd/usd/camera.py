"""The one place where OpenCV cameras become USD cameras and back.

OpenCV cameras look down +Z with +Y down and +X right; pixel (u, v) integer coordinates are pixel
centers. USD cameras look down -Z with +Y up and +X right; the aperture spans the image's outer
pixel edges and its offsets shift the film window (GfCamera). Both conversions are exact; the K of
every frame is also kept verbatim in ``rose:camera:K``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

from rose_usd.errors import InputError, StageError
from rose_usd.usd import schema, tokens

# Camera-axis change between OpenCV and USD: x stays, y and z flip. Its own inverse.
_CV_USD_AXES = np.diag([1.0, -1.0, -1.0, 1.0])

# Width of the USD aperture [mm] we choose; focal length follows from fx. Any value gives the
# same projection; a full-frame sensor width keeps the numbers familiar in usdview.
HORIZONTAL_APERTURE_MM = 36.0


def usd_camera_from_cv(world_from_cv: np.ndarray) -> np.ndarray:
    """``world_from_usd_camera`` (..., 4, 4) of OpenCV camera poses ``world_from_cv`` (..., 4, 4)."""
    return np.asarray(world_from_cv, dtype=float) @ _CV_USD_AXES


def cv_camera_from_usd(world_from_usd: np.ndarray) -> np.ndarray:
    """``world_from_cv_camera`` (..., 4, 4) of USD camera poses ``world_from_usd`` (..., 4, 4)."""
    return np.asarray(world_from_usd, dtype=float) @ _CV_USD_AXES


@dataclass(frozen=True)
class UsdIntrinsics:
    """USD camera projection attributes [mm] (UsdGeomCamera)."""

    focal_length: float
    horizontal_aperture: float
    vertical_aperture: float
    horizontal_aperture_offset: float
    vertical_aperture_offset: float


def check_K(K: np.ndarray, width: int, height: int, *, path=None) -> np.ndarray:
    """Return K as a float (3, 3) array; raise InputError if it cannot be the intrinsics of a
    ``width`` x ``height`` image (non-finite, non-positive focal, principal point off the image,
    skew, last row not (0, 0, 1))."""
    K = np.asarray(K, dtype=float)
    hint = "write fx 0 cx / 0 fy cy / 0 0 1 in pixels of this image size"
    if K.shape != (3, 3):
        raise InputError(f"intrinsics have shape {K.shape}, expected 3x3", path=path, hint=hint)
    if not np.all(np.isfinite(K)):
        raise InputError("intrinsics contain NaN or infinite values", path=path, hint=hint)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if fx <= 0 or fy <= 0:
        raise InputError(f"focal lengths must be positive (fx={fx:g}, fy={fy:g})", path=path, hint=hint)
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or abs(K[1, 0]) > 1e-9:
        raise InputError("intrinsics' last row must be 0 0 1 and K[1,0] zero", path=path, hint=hint)
    if abs(K[0, 1]) > 1e-6 * fx:
        raise InputError(f"intrinsics have skew {K[0, 1]:g}; rose_usd supports zero skew only", path=path, hint=hint)
    if not (0.0 < cx < width and 0.0 < cy < height):
        raise InputError(
            f"principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image",
            path=path,
            hint="K must be in pixels of the frames as stored (rescale K if the frames were resized)",
        )
    if not (0.25 * width <= cx <= 0.75 * width and 0.25 * height <= cy <= 0.75 * height):
        raise InputError(
            f"principal point ({cx:g}, {cy:g}) lies far from the center of the {width}x{height} image "
            "(a camera's is within a quarter of the size of it)",
            path=path,
            hint="K's cx, cy are in pixels (about width/2, height/2), not normalized",
        )
    for name, f, size in (("fx", fx, width), ("fy", fy, height)):
        if not (0.1 * max(width, height) < f < 20 * max(width, height)):
            fov = float(np.degrees(2 * np.arctan(size / f / 2)))
            raise InputError(
                f"focal length {name}={f:g} px is implausible for a {width}x{height} image (field of view "
                f"{fov:.1f} deg)",
                path=path,
                hint="K must be in pixels of the frames as stored",
            )
    if not 0.8 <= fx / fy <= 1.25:
        raise InputError(
            f"fx={fx:g} and fy={fy:g} differ by a factor {max(fx / fy, fy / fx):.2f}: pixels this far from "
            "square are a mistake",
            path=path,
            hint="write fx 0 cx / 0 fy cy / 0 0 1 with fx and fy in pixels of this image size",
        )
    return K


def intrinsics_to_usd(K: np.ndarray, width: int, height: int) -> UsdIntrinsics:
    """USD aperture parameters reproducing OpenCV ``K`` for a ``width`` x ``height`` image."""
    K = np.asarray(K, dtype=float)
    fx, fy = K[0, 0], K[1, 1]
    cx_c, cy_c = K[0, 2] + 0.5, K[1, 2] + 0.5  # continuous image coordinates of the principal point
    h_ap = HORIZONTAL_APERTURE_MM
    focal = fx * h_ap / width
    v_ap = focal * height / fy
    return UsdIntrinsics(
        focal_length=focal,
        horizontal_aperture=h_ap,
        vertical_aperture=v_ap,
        horizontal_aperture_offset=(width / 2.0 - cx_c) * h_ap / width,
        vertical_aperture_offset=(cy_c - height / 2.0) * v_ap / height,
    )


def intrinsics_from_usd(intr: UsdIntrinsics, width: int, height: int) -> np.ndarray:
    """OpenCV K (3, 3) [px] of a USD camera rendered at ``width`` x ``height``."""
    fx = intr.focal_length * width / intr.horizontal_aperture
    fy = intr.focal_length * height / intr.vertical_aperture
    cx = width / 2.0 - intr.horizontal_aperture_offset * width / intr.horizontal_aperture - 0.5
    cy = height / 2.0 + intr.vertical_aperture_offset * height / intr.vertical_aperture - 0.5
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def gf_matrix(pose: np.ndarray) -> Gf.Matrix4d:
    """USD matrix of a column-vector 4x4 pose (USD matrices act on row vectors)."""
    return Gf.Matrix4d(np.asarray(pose, dtype=float).T.tolist())


def np_pose(matrix: Gf.Matrix4d) -> np.ndarray:
    """Column-vector 4x4 pose of a USD matrix."""
    return np.array(matrix, dtype=float).T


def author_camera(
    stage: Usd.Stage,
    path: Sdf.Path,
    world_from_cv: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    intrinsics_source: str = "file",
    clipping_range_m: tuple[float, float] = (0.01, 100.0),
) -> UsdGeom.Camera:
    """Define a camera whose pose at time code t is ``world_from_cv[t]``.

    Args:
        world_from_cv: OpenCV camera poses, shape (N, 4, 4) [m].
        K: intrinsics, (3, 3) for all frames or (N, 3, 3) per frame [px].
        width, height: image size [px].
        intrinsics_source: token for ``rose:camera:intrinsicsSource``.
    """
    world_from_cv = np.asarray(world_from_cv, dtype=float)
    K = np.asarray(K, dtype=float)
    n = len(world_from_cv)
    Ks = np.broadcast_to(K, (n, 3, 3)) if K.ndim == 2 else K
    if Ks.shape != (n, 3, 3):
        raise ValueError(f"author_camera: K shape {K.shape} does not fit {n} poses")
    cam = UsdGeom.Camera.Define(stage, path)
    op = cam.AddTransformOp(precision=UsdGeom.XformOp.PrecisionDouble)
    world_from_usd = usd_camera_from_cv(world_from_cv)
    for t in range(n):
        op.Set(gf_matrix(world_from_usd[t]), Usd.TimeCode(t))
    op.Set(gf_matrix(world_from_usd[0]))  # default: frame 0, for tools that ignore time

    varying = not np.allclose(Ks, Ks[0], rtol=0, atol=1e-9)
    attrs = {
        "focal_length": cam.CreateFocalLengthAttr(),
        "horizontal_aperture": cam.CreateHorizontalApertureAttr(),
        "vertical_aperture": cam.CreateVerticalApertureAttr(),
        "horizontal_aperture_offset": cam.CreateHorizontalApertureOffsetAttr(),
        "vertical_aperture_offset": cam.CreateVerticalApertureOffsetAttr(),
    }
    prim = cam.GetPrim()
    prim.ApplyAPI(schema.CAMERA_API)
    k_attr = prim.GetAttribute(tokens.CAMERA_K)
    for t in range(n) if varying else [None]:
        intr = intrinsics_to_usd(Ks[t or 0], width, height)
        code = Usd.TimeCode.Default() if t is None else Usd.TimeCode(t)
        for field, attr in attrs.items():
            attr.Set(float(getattr(intr, field)), code)
        k_attr.Set(Gf.Matrix3d(Ks[t or 0].tolist()), code)
    cam.CreateClippingRangeAttr(Gf.Vec2f(*clipping_range_m))
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    prim.GetAttribute(tokens.CAMERA_RESOLUTION).Set(Gf.Vec2i(int(width), int(height)))
    prim.GetAttribute(tokens.CAMERA_INTRINSICS_SOURCE).Set(intrinsics_source)
    return cam


@dataclass(frozen=True)
class CameraTrack:
    """A camera read back from a stage."""

    world_from_cv: np.ndarray
    """OpenCV camera poses per frame, shape (N, 4, 4) [m]."""
    K: np.ndarray
    """Intrinsics per frame, shape (N, 3, 3) [px]."""
    width: int
    height: int


def read_camera(stage: Usd.Stage, path: Sdf.Path, n_frames: int) -> CameraTrack:
    """Read a camera's poses and intrinsics at time codes 0..n_frames-1."""
    prim = stage.GetPrimAtPath(path)
    if not prim or not prim.IsA(UsdGeom.Camera):
        raise StageError(f"no camera at {path}", path=stage.GetRootLayer().identifier, hint="run the capture stage")
    cam = UsdGeom.Camera(prim)
    width, height = (int(v) for v in prim.GetAttribute(tokens.CAMERA_RESOLUTION).Get())
    poses = np.empty((n_frames, 4, 4))
    Ks = np.empty((n_frames, 3, 3))
    k_attr = prim.GetAttribute(tokens.CAMERA_K)
    for t in range(n_frames):
        code = Usd.TimeCode(t)
        poses[t] = np_pose(cam.ComputeLocalToWorldTransform(code))
        k = k_attr.Get(code) if k_attr and k_attr.HasAuthoredValue() else None
        if k is not None:
            Ks[t] = np.array(k, dtype=float)
        else:
            Ks[t] = intrinsics_from_usd(
                UsdIntrinsics(
                    cam.GetFocalLengthAttr().Get(code),
                    cam.GetHorizontalApertureAttr().Get(code),
                    cam.GetVerticalApertureAttr().Get(code),
                    cam.GetHorizontalApertureOffsetAttr().Get(code),
                    cam.GetVerticalApertureOffsetAttr().Get(code),
                ),
                width,
                height,
            )
    return CameraTrack(cv_camera_from_usd(poses), Ks, width, height)
