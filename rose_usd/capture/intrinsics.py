"""Which intrinsics a capture backend uses: cam_K.txt, the imported tool's, or a field-of-view guess."""

from __future__ import annotations

import numpy as np

from rose_usd.case.layout import Case
from rose_usd.usd.camera import check_K


def guess_K(width: int, height: int, fov_deg: float) -> np.ndarray:
    """Square pixels, principal point at the image center, horizontal field of view ``fov_deg``."""
    f = width / (2.0 * np.tan(np.radians(fov_deg) / 2.0))
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def where_K_goes(case: Case) -> str:
    """How to give a case its intrinsics: cam_K.txt in its folder; a video given as a file reads
    none (nor one beside it), so it goes into a case folder of its own first."""
    if case.root.is_file():
        beside = " (the cam_K.txt beside it is not read)" if (case.folder / "cam_K.txt").is_file() else ""
        return f"a video given as a file reads no cam_K.txt{beside}: {case.as_folder('cam_K.txt', 'rose.toml')}"
    return f"write cam_K.txt in {case.folder}"


def resolve_K(
    case: Case, *, imported: np.ndarray | None = None, fov_guess_deg: float = 60.0
) -> tuple[np.ndarray, str, str | None]:
    """(K, rose:camera:intrinsicsSource token, warning or None), in that order of preference:
    the case's cam_K.txt, the imported tool's K (already in pixels of the case's frames), a guess."""
    if case.K_path is not None:
        return case.K(), "file", None
    if imported is not None:
        return check_K(imported, case.width, case.height, path="imported intrinsics"), "imported", None
    warning = (
        f"no intrinsics (cam_K.txt) and none imported: guessed a {fov_guess_deg:g} deg horizontal field of view; "
        f"metric results are unreliable, {where_K_goes(case)}"
    )
    return guess_K(case.width, case.height, fov_guess_deg), "fov-guess", warning
