"""TUM trajectory files: exact format round trip and clear errors."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rose_usd.core import se3
from rose_usd.errors import InputError
from rose_usd.io.tum import read_tum, write_tum


def test_round_trip(tmp_path):
    """Poses written as TUM read back equal (quaternion scalar last, seconds)."""
    rng = np.random.default_rng(3)
    poses = se3.make_pose(Rotation.random(30, random_state=3).as_matrix(), rng.normal(size=(30, 3)))
    t = np.arange(30) / 30.0
    write_tum(tmp_path / "a.tum", t, poses)
    t2, poses2 = read_tum(tmp_path / "a.tum")
    np.testing.assert_allclose(t2, t, atol=1e-6)
    np.testing.assert_allclose(poses2, poses, atol=1e-8)


def test_reads_the_tum_convention(tmp_path):
    """A hand-written line 'ts tx ty tz qx qy qz qw' is world-from-sensor with w last."""
    (tmp_path / "b.tum").write_text("# comment\n1.5 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n")
    t, poses = read_tum(tmp_path / "b.tum")
    assert t[0] == 1.5
    np.testing.assert_allclose(poses[0, :3, 3], [1, 2, 3])
    np.testing.assert_allclose(poses[0, :3, :3], se3.rotation_about([0, 0, 1], np.pi / 2), atol=1e-12)


@pytest.mark.parametrize(
    "text,message",
    [
        ("0 1 2 3 0 0 0\n", "7 fields"),
        ("0 1 2 3 0 0 0 2\n", "norm"),
        ("0 1 2 x 0 0 0 1\n", "not numeric"),
        ("1 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", "increasing"),
        ("# nothing\n", "no poses"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, message):
    """Malformed TUM files raise one-line InputErrors naming the file."""
    path = tmp_path / "bad.tum"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        read_tum(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
