"""MP4 video with PyAV, encoded as lerobot's ``encode_video_frames`` does by default: AV1 by
SVT-AV1, yuv420p, a keyframe every 2 frames (cheap random access for training), crf 30, preset 12.
yuv420p needs an even width and height.

SVT-AV1 run as root makes the thread that opens the encoder, and its own threads, real-time
(``core.realtime``): after each encoder call every thread of the process that became real-time
goes back to the encoding thread's own scheduling."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from rose_usd.core.realtime import scheduling, undo_realtime

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
        self._scheduling = scheduling()
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        import av

        if rgb.shape != (self.height, self.width, 3):
            raise ValueError(f"frame of shape {rgb.shape}, the video is {self.height}x{self.width}x3")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb, dtype=np.uint8), format="rgb24")
        frame.pts = self.frames
        packets = self._stream.encode(frame)  # the first call opens the encoder
        undo_realtime(self._scheduling)
        for packet in packets:
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        packets = self._stream.encode()
        undo_realtime(self._scheduling)
        for packet in packets:
            self._container.mux(packet)
        self._container.close()

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


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
