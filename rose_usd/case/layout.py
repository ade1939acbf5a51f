"""Finding and validating a case's inputs before any stage authors anything.

A case is a folder (``rgb/`` with frames or one video, or ``video.mp4``, optional ``depth/``,
``cam_K.txt``, ``rose.toml``, ``perception/``, ``gt/``) or a video file. Every check here raises
an InputError naming the file and the fix, so a bad case fails before a single layer is written.
"""

from __future__ import annotations

import difflib
import functools
import hashlib
import math
import os
import re
import shutil
import warnings
from pathlib import Path

import numpy as np

from rose_usd.case.config import CASE_CONFIG_FILE, ObjectSpec, load_case_config
from rose_usd.core.cache import cache_dir
from rose_usd.errors import InputError
from rose_usd.io import images
from rose_usd.usd.camera import check_K

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm")
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl")
MEGASAM_PATTERNS = ("*_sgd_cvd_hr.npz", "*_droid.npz")
DEFAULT_FPS = 30.0
_NUMBER = re.compile(r"(\d+)")


def _publish(staging: Path, cache: Path) -> None:
    """Rename the complete folder ``staging`` to ``cache``. Another process (a batch worker on
    the same video) may have put its own there first: its frames are these frames and it may be
    reading them, so it stays and ``staging`` is dropped. A folder there without ``.complete``
    (left by an older version) is replaced."""
    try:
        os.replace(staging, cache)
    except OSError:
        if (cache / ".complete").is_file():
            return
        if not cache.exists():
            raise
        shutil.rmtree(cache)
        os.replace(staging, cache)


def _frame_number(path: Path) -> int | None:
    nums = _NUMBER.findall(path.stem)
    return int(nums[-1]) if nums else None


def _sorted_frames(folder: Path, suffixes: tuple[str, ...], what: str, infix: str = "") -> list[Path]:
    files = [
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in suffixes and not p.name.startswith(".") and infix in p.name
    ]
    if not files:
        raise InputError(
            f"no {what} files ({'/'.join(suffixes)}) in the folder",
            path=folder,
            hint=f"put the {what} frames there, one file per frame"
            + (f", or one video ({'/'.join(VIDEO_SUFFIXES)})" if what == "RGB" and folder.name == "rgb" else ""),
        )
    numbers = [_frame_number(p) for p in files]
    if all(n is not None for n in numbers):
        order = sorted(range(len(files)), key=lambda i: (numbers[i], files[i].name))
        files = [files[i] for i in order]
        nums = [numbers[i] for i in order]
        if len(set(nums)) != len(nums):
            dup = next(n for n in nums if nums.count(n) > 1)
            raise InputError(f"two {what} files carry frame number {dup}", path=folder, hint="keep one file per frame")
        for prev, cur, prev_path in zip(nums, nums[1:], files):
            if cur != prev + 1:
                raise InputError(
                    f"{what} frame {prev + 1} missing after {prev_path.name}"
                    if cur == prev + 2
                    else f"{what} frames {prev + 1}..{cur - 1} missing after {prev_path.name}",
                    path=folder,
                    hint="frames must be numbered consecutively; restore the missing files or renumber",
                )
    else:
        files.sort(key=lambda p: p.name)
    return files


def _videos_only(folder: Path) -> list[Path]:
    """The videos in ``folder`` when it holds no image frames (real clips come as rgb/clip.mp4)."""
    names = sorted(p for p in folder.iterdir() if p.is_file())
    if any(p.suffix.lower() in images.IMAGE_SUFFIXES for p in names):
        return []
    return [p for p in names if p.suffix.lower() in VIDEO_SUFFIXES]


CASE_DIRS = ("rgb", "depth", "mesh", "perception", "gt", "imu")
"""A case folder's folders of inputs."""
CASE_ENTRIES = (*CASE_DIRS, "cam_K.txt", "camera-intrinsics.txt", "rose.toml")
"""What a case folder's layout reads (and ``video.<suffix>``)."""


def _check_links(folder: Path) -> None:
    """InputError for an entry the layout reads that is a link to nothing: left as it is, the case
    would run as if it were not there (a ``mesh`` link to a mistyped folder: no mesh, a guessed scale)."""
    for name in (*CASE_ENTRIES, *(f"video{s}" for s in VIDEO_SUFFIXES)):
        entry = folder / name
        if entry.is_symlink() and not entry.exists():
            raise InputError(
                f"{name} is a link to {os.readlink(entry)}, which does not exist",
                path=entry,
                hint="point the link at the file or folder, or remove it",
            )


class Case:
    """A validated input case. Frames are read lazily; sizes and counts are checked up front."""

    def __init__(self, root: Path, stage_names: tuple[str, ...] = ()):
        self.root = Path(root)
        if not self.root.exists():
            raise InputError("case not found", path=self.root, hint="give a case folder or a video file")
        self.video: Path | None = None
        self.frame_paths: list[Path] = []
        self.flat = False
        if self.root.is_file():
            if self.root.suffix.lower() not in VIDEO_SUFFIXES:
                raise InputError(
                    "not a video file or a case folder",
                    path=self.root,
                    hint=f"give a folder or one of {VIDEO_SUFFIXES}",
                )
            self.video = self.root
            self.folder = self.root.parent
            self.settings_file = _video_settings_file(self.root)
            self.config = load_case_config(self.folder, stage_names, file=self.settings_file)
        else:
            self.folder = self.root
            _check_links(self.root)
            self.settings_file = self.root / CASE_CONFIG_FILE
            self.config = load_case_config(self.root, stage_names)
            rgb_dir = self.root / "rgb"
            videos = [self.root / f"video{s}" for s in VIDEO_SUFFIXES if (self.root / f"video{s}").is_file()]
            inside = _videos_only(rgb_dir) if rgb_dir.is_dir() else []
            if len(inside) > 1:
                raise InputError(
                    f"rgb/ holds two or more videos and no frames: {', '.join(v.name for v in inside)}",
                    path=rgb_dir,
                    hint="keep one video there, or give the video file itself as the case",
                )
            if inside:
                self.video = inside[0]
            elif rgb_dir.is_dir():
                self.frame_paths = _sorted_frames(rgb_dir, images.IMAGE_SUFFIXES, "RGB")
            elif videos:
                self.video = videos[0]
            elif any(self.root.glob("*.color.*")):
                # 7-Scenes / TUM-style flat folder: frame-NNNNNN.color.jpg beside frame-NNNNNN.depth.png
                self.flat = True
                self.frame_paths = _sorted_frames(self.root, images.IMAGE_SUFFIXES, "RGB", infix=".color.")
            else:
                raise InputError(
                    "case has neither rgb/ nor video.mp4 (nor *.color.jpg frames)",
                    path=self.root,
                    hint="put frames in rgb/ (PNG/JPEG, sorted by name) or the video as video.mp4",
                )
        if self.video is not None:
            self._probe_video()
            _ = self._video_frames  # decoded now: a truncated video fails before anything is written
        else:
            self.width, self.height = images.image_size(self.frame_paths[0])
            for p in self.frame_paths:
                images.check_complete(p)  # a frame cut short fails now, before anything is written
                size = images.image_size(p)
                if size != (self.width, self.height):
                    raise InputError(
                        f"frame is {size[0]}x{size[1]}, the first frame is {self.width}x{self.height}",
                        path=p,
                        hint="all frames of a case must have one size",
                    )
        self._depth_valid: np.ndarray | None = None
        self.depth_paths = self._find_depth()
        self.K_path = next(
            (
                self.root / n
                for n in ("cam_K.txt", "camera-intrinsics.txt")
                if self.root.is_dir() and (self.root / n).is_file()
            ),
            None,
        )
        if self.K_path is not None:
            self.K()  # validate now: a bad K fails before anything is written

    # ------------------------------------------------------------------ frames
    def _probe_video(self) -> None:
        import cv2

        cap = cv2.VideoCapture(str(self.video))
        ok, frame = cap.read() if cap.isOpened() else (False, None)
        if not ok:
            raise InputError(
                "cannot decode this video (corrupt or unsupported codec)",
                path=self.video,
                hint="re-encode it as H.264 MP4 or extract PNG frames into rgb/",
            )
        self.height, self.width = frame.shape[:2]
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        self._video_fps = fps if math.isfinite(fps) and 0 < fps <= 1000 else None
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        self._video_count = count if count > 0 else None

    @functools.cached_property
    def _video_frames(self) -> list[Path]:
        """Decode the video once into a cache folder of PNGs keyed by the video's content hash
        (under ``$ROSE_USD_CACHE``, else ``$XDG_CACHE_HOME/rose_usd``, else ``~/.cache/rose_usd``).
        A video that ends before the frame count its header announces is refused."""
        h = hashlib.sha256()
        with open(self.video, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        cache = cache_dir() / "frames" / h.hexdigest()[:16]
        done = cache / ".complete"
        if not done.is_file():
            staging = cache.with_name(f".{cache.name}-{os.getpid()}")
            try:
                staging.mkdir(parents=True, exist_ok=True)
                count = self._decode_into(staging)
                self._check_whole(count)  # a refused video leaves nothing in the cache
                (staging / ".complete").write_text(str(count))
                _publish(staging, cache)
            except OSError as exc:
                raise InputError(
                    f"cannot write the decoded frames' cache ({getattr(exc, 'strerror', None) or exc})",
                    path=cache_dir(),
                    hint="set ROSE_USD_CACHE to a folder you can write to",
                ) from None
            finally:
                shutil.rmtree(staging, ignore_errors=True)
        n = int(done.read_text())
        self._check_whole(n)
        return [cache / f"{i:06d}.png" for i in range(n)]

    def _decode_into(self, folder: Path) -> int:
        """Every frame of the video as PNGs in ``folder``; how many."""
        import cv2

        cap = cv2.VideoCapture(str(self.video))
        i = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if not cv2.imwrite(str(folder / f"{i:06d}.png"), frame):
                raise OSError(f"cannot write {folder / f'{i:06d}.png'}")
            i += 1
        cap.release()
        if i == 0:
            raise InputError("the video holds no decodable frames", path=self.video, hint="re-encode it as H.264 MP4")
        return i

    def _check_whole(self, n: int) -> None:
        """Refuse a video that ends (``n`` frames) before the frame count its header announces."""
        if self._video_count is not None and n < self._video_count - max(1, self._video_count // 100):
            raise InputError(
                f"the video ends after {n} of the {self._video_count} frames its header announces (truncated?)",
                path=self.video,
                hint="copy the whole file again, or re-encode it (ffmpeg -i in.mp4 -c:v libx264 video.mp4)",
            )

    @property
    def frames(self) -> list[Path]:
        return self._video_frames if self.video is not None else self.frame_paths

    @property
    def n_frames(self) -> int:
        if self.video is not None:
            return len(self._video_frames)
        return len(self.frame_paths)

    @property
    def fps(self) -> float:
        if self.config.fps is not None:
            return self.config.fps
        if self.video is not None and self._video_fps:
            return self._video_fps
        return DEFAULT_FPS

    @property
    def fps_assumed(self) -> bool:
        """Whether ``fps`` is DEFAULT_FPS for want of rose.toml's fps or a video file's rate."""
        return self.config.fps is None and not (self.video is not None and self._video_fps)

    def frame_name(self, t: int) -> str:
        return self.frames[t].stem

    def rgb(self, t: int) -> np.ndarray:
        """Frame t as 8-bit RGB (H, W, 3)."""
        img = images.read_rgb(self.frames[t])
        if img.shape[1] != self.width or img.shape[0] != self.height:
            raise InputError(
                f"frame is {img.shape[1]}x{img.shape[0]}, expected {self.width}x{self.height}",
                path=self.frames[t],
                hint="all frames of a case must have one size",
            )
        return img

    # ------------------------------------------------------------------ depth
    def _find_depth(self) -> list[Path] | None:
        if self.flat:
            depth_dir = self.folder
            if not any(depth_dir.glob("*.depth.*")):
                return None
            paths = _sorted_frames(depth_dir, images.DEPTH_SUFFIXES, "depth", infix=".depth.")
        else:
            depth_dir = self.folder / "depth" if self.root.is_dir() else None
            if depth_dir is None or not depth_dir.is_dir():
                return None
            paths = _sorted_frames(depth_dir, images.DEPTH_SUFFIXES, "depth")
        if self.video is not None and len(paths) != self.n_frames:
            raise InputError(
                f"depth/ has {len(paths)} frames but {self.video.name} has {self.n_frames}",
                path=depth_dir,
                hint="give one depth map per video frame, or remove depth/",
            )
        if self.video is None:
            if len(paths) != len(self.frame_paths):
                raise InputError(
                    f"depth/ has {len(paths)} frames but rgb/ has {len(self.frame_paths)}",
                    path=depth_dir,
                    hint="give one depth map per RGB frame, or remove depth/",
                )
            for rgb_path, depth_path in zip(self.frame_paths, paths):
                if _frame_number(rgb_path) != _frame_number(depth_path):
                    raise InputError(
                        f"depth frame {depth_path.name} pairs with RGB frame {rgb_path.name}",
                        path=depth_path,
                        hint="name depth and RGB files with the same frame numbers",
                    )
        return paths

    @property
    def has_depth(self) -> bool:
        return self.depth_paths is not None

    def depth_m(self, t: int) -> np.ndarray:
        """Metric depth of frame t [m] (H, W), 0 where invalid."""
        if self.depth_paths is None:
            raise InputError(
                "case has no depth/ folder",
                path=self.folder,
                hint="this backend needs depth; add depth/ or choose a monocular backend",
            )
        depth = images.read_depth_m(self.depth_paths[t])
        if depth.shape != (self.height, self.width):
            raise InputError(
                f"depth is {depth.shape[1]}x{depth.shape[0]}, RGB is {self.width}x{self.height}",
                path=self.depth_paths[t],
                hint="register and resize depth to the RGB frames",
            )
        return depth

    MIN_VALID_DEPTH_FRACTION = 0.01
    """A depth frame with valid depth on fewer of its pixels than this is a sensor dropout."""

    def depth_valid(self) -> np.ndarray:
        """Per frame, whether its depth map holds valid depth (at least 1 % of its pixels; an
        all-zero, all-NaN or saturated frame is a dropout). Reads every depth map once, so a
        broken one fails here, before anything is written."""
        if self._depth_valid is None:
            if self.depth_paths is None:
                raise InputError("case has no depth/ folder", path=self.folder, hint="add depth/")
            self._depth_valid = np.array(
                [
                    np.count_nonzero(self.depth_m(t)) >= self.MIN_VALID_DEPTH_FRACTION * self.width * self.height
                    for t in range(len(self.depth_paths))
                ]
            )
        return self._depth_valid

    def check_depth(self) -> None:
        """Refuse a depth video with too few valid frames (fewer than half, or than 2); a few
        dropouts are skipped by the stages, with a warning."""
        valid = self.depth_valid()
        n_valid = int(valid.sum())
        if n_valid < max(2, (len(valid) + 1) // 2):
            folder = self.depth_paths[0].parent
            raise InputError(
                f"only {n_valid} of {len(valid)} depth frames hold valid depth (the others are empty, NaN or "
                "saturated)",
                path=folder,
                hint="check the depth sensor's recording (or remove depth/ to run without depth)",
            )

    # ------------------------------------------------------------------ intrinsics
    def K(self) -> np.ndarray:
        """The case's 3x3 intrinsics [px] from cam_K.txt, validated against the frame size."""
        if self.K_path is None:
            raise InputError(
                "case has no cam_K.txt",
                path=self.folder,
                hint="write the 3x3 intrinsics (fx 0 cx / 0 fy cy / 0 0 1) to cam_K.txt",
            )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # an empty file: check_K says what it holds
                K = np.loadtxt(self.K_path, dtype=float)
        except ValueError as exc:
            why = str(exc).split(";")[0]  # numpy's advice after it (usecols) is not for this file
            raise InputError(
                f"not a numeric 3x3 matrix ({why})", path=self.K_path, hint="write three rows of three numbers"
            ) from None
        return check_K(K.reshape(3, 3) if K.size == 9 else K, self.width, self.height, path=self.K_path)

    # ------------------------------------------------------------------ ground truth
    @functools.cached_property
    def gt(self):
        """The case's ground truth (benchmark cases only); InputError if absent."""
        from rose_usd.case.gt import GroundTruth

        gt = GroundTruth(self.folder / "gt")
        if gt.n_frames != self.n_frames:
            raise InputError(
                f"ground truth has {gt.n_frames} frames, the case {self.n_frames}",
                path=self.folder / "gt" / "scene.json",
                hint="regenerate the case",
            )
        return gt

    # ------------------------------------------------------------------ what other tools left
    @property
    def perception_dir(self) -> Path:
        """``perception/``: what other tools (MegaSaM, SAM 2, TRELLIS, FoundationPose) wrote."""
        return self.folder / "perception"

    @property
    def has_gt(self) -> bool:
        """Whether the case carries ground truth (benchmark cases only)."""
        return (self.folder / "gt" / "scene.json").is_file()

    def megasam_file(self) -> Path | None:
        """MegaSaM's npz (its final ``*_sgd_cvd_hr.npz``, else the tracking step's ``*_droid.npz``)."""
        for pattern in MEGASAM_PATTERNS:
            found = sorted(self.perception_dir.glob(pattern))
            if found:
                return found[0]
        return None

    @property
    def sam2_dir(self) -> Path:
        return self.perception_dir / "masks"

    def has_sam2_masks(self) -> bool:
        """Whether ``perception/masks/`` holds SAM 2 PNGs (paletted frames or per-id folders)."""
        return self.sam2_dir.is_dir() and any(self.sam2_dir.rglob("*.png"))

    def mesh_file(self, spec: ObjectSpec) -> Path | None:
        """The mesh another tool made of object ``spec``: rose.toml's ``mesh``, else
        ``perception/<Name>.<glb|gltf|obj|ply|stl>``, else, for a case with one object, the only mesh
        in ``perception/`` or in ``mesh/`` (FoundationPose's demo layout). A ``mesh`` that rose.toml
        names and that is missing, or is no mesh format's file, is an error, not a fallback; so is
        a ``perception/`` or ``mesh/`` with several meshes where rose.toml names none."""
        override = spec.overrides.get("mesh")
        if override is not None:
            path = (self.folder / override).resolve()
            if not path.is_file():
                named = self.folder / override
                near = sorted(p.name for p in named.parent.glob("*") if p.suffix.lower() in MESH_SUFFIXES)
                close = difflib.get_close_matches(named.name, near, n=1, cutoff=0.5)
                there = f"; {named.parent} holds {close[0]!r}" if close else ""
                raise InputError(
                    f"object {spec.name!r}: its mesh = {override!r} does not exist ({named}){there}",
                    path=self.settings_file,
                    hint="fix mesh = ..." + ("" if Path(override).is_absolute() else " (relative to the case folder)"),
                )
            if path.suffix.lower() not in MESH_SUFFIXES:
                raise InputError(
                    f"object {spec.name!r}: its mesh = {override!r} is not a mesh file",
                    path=self.settings_file,
                    hint=f"give a {', '.join(MESH_SUFFIXES)} file",
                )
            return path
        for suffix in MESH_SUFFIXES:
            if (self.perception_dir / f"{spec.name}{suffix}").is_file():
                return self.perception_dir / f"{spec.name}{suffix}"
        if len(self.config.objects) == 1:
            several = None
            for folder in (self.perception_dir, self.folder / "mesh"):
                found = (
                    sorted(p for p in folder.glob("*") if p.suffix.lower() in MESH_SUFFIXES) if folder.is_dir() else []
                )
                if len(found) == 1:
                    return found[0]
                if len(found) > 1 and several is None:
                    several = (folder, found)
            if several is not None:  # deepac-cat-rgb's mesh/ holds Cat_m.obj and Cat_mm.obj
                folder, found = several
                raise InputError(
                    f"object {self.config.objects[0].name!r}: {folder.name}/ holds {len(found)} meshes"
                    f" ({', '.join(p.name for p in found)}) and rose.toml names none",
                    path=self.settings_file,
                    hint=f'name the one to use: mesh = "{folder.name}/{found[0].name}" under [[objects]]',
                )
        return None

    def pose_dir(self, name: str) -> Path:
        """Where FoundationPose's poses of object ``name`` go: ``perception/ob_in_cam/<name>/`` when
        there are several objects or that folder exists, else ``perception/ob_in_cam/``."""
        root = self.perception_dir / "ob_in_cam"
        return root / name if len(self.config.objects) > 1 or (root / name).is_dir() else root

    def has_poses(self, name: str) -> bool:
        """Whether FoundationPose's pose files of object ``name`` are there."""
        folder = self.pose_dir(name)
        return folder.is_dir() and any(folder.glob("*.txt"))

    def as_folder(self, *entries: str) -> str:
        """How a video given as a file gets what only a case folder reads (cam_K.txt, depth/):
        "make a case folder holding rgb/<the video>, <entries>, and give that folder"."""
        held = [f"rgb/{self.root.name}", *entries]
        listed = f"{', '.join(held[:-1])} and {held[-1]}" if len(held) > 1 else held[0]
        return f"make a case folder holding {listed}, and give that folder"

    def input_files(self) -> list[Path]:
        """Every input file a stage may read (for provenance hashes), ground truth excluded."""
        files = list(self.frame_paths) if self.video is None else [self.video]
        files += list(self.depth_paths or [])
        if self.root.is_dir():
            files += [self.folder / n for n in ("cam_K.txt", "camera-intrinsics.txt") if (self.folder / n).is_file()]
        if self.config.path is not None:
            files.append(self.config.path)
        for sub in ("perception", "imu"):
            if (self.folder / sub).is_dir():
                files += sorted(p for p in (self.folder / sub).rglob("*") if p.is_file() and p.name != "simulated.json")
        return files


def load_case(path: str | Path, stage_names: tuple[str, ...] = ()) -> Case:
    return Case(Path(path), stage_names)


def _video_settings_file(video: Path) -> Path:
    """A video's own settings (objects, categories, sizes, fps): <video stem>.toml beside it, or
    <video name>.toml (cups.mp4.toml), not both."""
    stem, full = video.with_suffix(".toml"), video.with_name(video.name + ".toml")
    if stem.is_file() and full.is_file():
        raise InputError(
            f"two settings files beside the video: {stem.name} and {full.name}",
            path=video.parent,
            hint=f"keep one ({stem.name})",
        )
    return full if full.is_file() else stem
