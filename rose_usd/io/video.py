"""MP4 video with PyAV, encoded as lerobot's ``encode_video_frames`` does by default: AV1 by
SVT-AV1, yuv420p, a keyframe every 2 frames (cheap random access for training), crf 30, preset 12.
yuv420p needs an even width and height.

SVT-AV1 run as root makes the thread that opens the encoder, and the threads it starts, real-time
(SCHED_FIFO, priority 99), and every process started from that thread afterwards inherits it. On
two cores, a real-time thread that spins waiting for a lock (Dr.Jit's, nanothread's workers) keeps
the real-time holder of that lock off its core until the other core frees up: Mitsuba calls stood
still for 12-14 minutes in CI that way. So after each encoder call every thread of the process
that became real-time goes back to the encoding thread's own scheduling (``_undo_realtime``)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

CODEC = "libsvtav1"
CODEC_NAME = "av1"
"""What lerobot records as ``video.codec`` for it (the stream's codec name)."""
PIX_FMT = "yuv420p"
OPTIONS = {"g": "2", "crf": "30", "preset": "12"}


class VideoWriter:
    """Frames (H, W, 3) uint8 sRGB in, one MP4 video stream out at ``fps``; frame i is shown at
    i / fps seconds."""

    def __init__(self, path: Path, fps: int, width: int, height: int, *, codec: str = CODEC):
        import av

        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration otherwise

        if width % 2 or height % 2:
            raise ValueError(f"{PIX_FMT} video needs an even size, not {width}x{height}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.width, self.height = width, height
        self._container = av.open(str(self.path), mode="w")
        self._stream = self._container.add_stream(codec, rate=int(fps), options=dict(OPTIONS))
        self._stream.width, self._stream.height, self._stream.pix_fmt = width, height, PIX_FMT
        self._scheduling = _scheduling()
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        import av

        if rgb.shape != (self.height, self.width, 3):
            raise ValueError(f"frame of shape {rgb.shape}, the video is {self.height}x{self.width}x3")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb, dtype=np.uint8), format="rgb24")
        frame.pts = self.frames
        packets = self._stream.encode(frame)  # the first call opens the encoder
        _undo_realtime(self._scheduling)
        for packet in packets:
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        packets = self._stream.encode()
        _undo_realtime(self._scheduling)
        for packet in packets:
            self._container.mux(packet)
        self._container.close()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_REALTIME = {getattr(os, "SCHED_FIFO", -1), getattr(os, "SCHED_RR", -1)}


def _scheduling() -> tuple[int, int] | None:
    """The calling thread's scheduling policy and priority; None where they cannot be read."""
    if not hasattr(os, "sched_getscheduler"):
        return None
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


def _undo_realtime(original: tuple[int, int] | None) -> None:
    """Every thread of this process that runs real-time where ``original`` (the encoding thread's
    scheduling before the encoder) is not: back to ``original``. A process started real-time on
    purpose (``chrt``) is left as it is."""
    if original is None or original[0] in _REALTIME:
        return
    try:
        threads = [int(name) for name in os.listdir("/proc/self/task")]
    except OSError:
        return
    for tid in threads:
        try:
            if os.sched_getscheduler(tid) in _REALTIME:
                os.sched_setscheduler(tid, original[0], os.sched_param(original[1]))
        except OSError:  # the thread has ended
            pass


def read_frames(path: Path) -> Iterator[np.ndarray]:
    """The video's frames in order, (H, W, 3) uint8 sRGB."""
    import av

    with av.open(str(path)) as container:
        for frame in container.decode(video=0):
            yield frame.to_ndarray(format="rgb24")


def video_info(path: Path) -> dict:
    """The first video stream's codec name, size, pixel format, frame rate and frame count."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = sum(1 for _ in container.decode(video=0))
        return {
            "codec": stream.codec_context.codec.canonical_name,
            "width": stream.codec_context.width,
            "height": stream.codec_context.height,
            "pix_fmt": stream.codec_context.pix_fmt,
            "fps": float(stream.average_rate) if stream.average_rate else float("nan"),
            "frames": frames,
        }
