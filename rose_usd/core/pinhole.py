"""The OpenCV pinhole camera's back-projection, in one place: pixel (u, v) at depth z -> camera point."""

from __future__ import annotations

import numpy as np


def backproject(u, v, z, K: np.ndarray) -> np.ndarray:
    """Camera points (..., 3) in OpenCV axes of pixels ``u``, ``v`` (pixel centers at integers)
    with depth ``z`` [m] along the optical axis; u, v and z broadcast together."""
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)
