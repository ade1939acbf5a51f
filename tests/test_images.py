"""Frames, depth maps and masks read from disk: the first read of a plain PNG takes Pillow's
pixels (its decode check), every other read OpenCV's; both must be the same arrays."""

import cv2
import numpy as np
import pytest
from PIL import Image

from rose_usd.io import images


def _opencv_rgb(path):
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


@pytest.mark.parametrize("dtype, channels", [(np.uint8, 3), (np.uint16, 3), (np.uint8, 1), (np.uint8, 4)])
def test_rgb_reads_as_opencv_reads_it_first_time_and_after(tmp_path, dtype, channels):
    """8-bit RGB (Pillow's pixels at the first read), 16-bit RGB, gray and RGBA (OpenCV's)."""
    rng = np.random.default_rng(channels)
    top = np.iinfo(dtype).max
    pixels = rng.integers(0, top, (37, 53, channels), endpoint=True).astype(dtype).squeeze()
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), pixels)
    assert images._png_kind(path) == (8 * np.dtype(dtype).itemsize, {1: 0, 3: 2, 4: 6}[channels])
    first, again = images.read_rgb(path), images.read_rgb(path)
    want = _opencv_rgb(path)
    for got in (first, again):
        assert got.dtype == np.uint8 and got.flags.writeable and np.array_equal(got, want)


def test_depth_and_masks_read_as_opencv_reads_them(tmp_path):
    """16-bit depth in millimeters (0 and 65535 invalid), an 8-bit mask and a paletted one."""
    depth = np.random.default_rng(0).uniform(0.2, 3.0, (40, 60)).astype(np.float32)
    depth[:3] = 0.0
    images.write_depth_mm(tmp_path / "depth.png", depth)
    raw = cv2.imread(str(tmp_path / "depth.png"), cv2.IMREAD_UNCHANGED)
    raw[5, 5] = 65535
    cv2.imwrite(str(tmp_path / "depth.png"), raw)
    want = np.where(raw == 65535, 0, raw).astype(np.float32) / 1000.0
    for got in (images.read_depth_m(tmp_path / "depth.png"), images.read_depth_m(tmp_path / "depth.png")):
        assert got.dtype == np.float32 and np.array_equal(got, want)
    mask = np.zeros((40, 60), bool)
    mask[10:20, 5:30] = True
    images.write_mask(tmp_path / "mask.png", mask)
    Image.fromarray(mask.astype(np.uint8), mode="L").convert("P").save(tmp_path / "paletted.png")
    assert images._png_kind(tmp_path / "paletted.png")[1] == 3
    for name in ("mask.png", "mask.png", "paletted.png"):
        got = images.read_mask(tmp_path / name)
        assert got.dtype == bool and np.array_equal(got, mask), name


def test_a_truncated_png_is_one_input_error_naming_it(tmp_path):
    """A plain PNG cut short: InputError naming the file, at the first read and after."""
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), np.full((30, 40, 3), 90, np.uint8))
    path.write_bytes(path.read_bytes()[:60])
    for _ in range(2):
        with pytest.raises(images.InputError, match="cannot read this image") as err:
            images.read_rgb(path)
        assert str(path) in str(err.value.path)
