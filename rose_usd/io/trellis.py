"""TRELLIS meshes (formats.md): a ``.glb`` whose vertices lie in the normalized cube
[-0.5, 0.5]^3, rotated from Z-up to glTF's Y-up, with UVs and a baseColor texture. No metric scale:
scale and pose must be estimated (the paper's Eq. 1-3)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from rose_usd.errors import MeshError
from rose_usd.io.meshfile import check_vertices, quiet_load

# Z-up (x, y, z) -> glTF Y-up (x, z, -y): a rotation of -90 degrees about X
Y_UP_FROM_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def write_trellis_glb(
    path: str | os.PathLike, vertices_yup: np.ndarray, faces: np.ndarray, uv: np.ndarray, texture_rgb: np.ndarray
) -> None:
    """Write a textured GLB (vertices already normalized and Y-up)."""
    from PIL import Image

    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(np.asarray(texture_rgb, dtype=np.uint8)),
        metallicFactor=0.0,
        roughnessFactor=1.0,
    )
    mesh = trimesh.Trimesh(
        vertices=vertices_yup,
        faces=faces,
        visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
        process=False,
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path, file_type="glb")


def read_trellis_glb(path: str | os.PathLike) -> trimesh.Trimesh:
    """Load a TRELLIS GLB as one mesh (Y-up, normalized cube); MeshError if it does not look like one."""
    path = Path(path)
    try:
        loaded = quiet_load(path)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(
            f"cannot read the GLB ({type(exc).__name__}: {exc})", path=path, hint="export it again from TRELLIS"
        ) from None
    mesh = loaded.to_mesh() if isinstance(loaded, trimesh.Scene) else loaded
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError("the GLB holds no triangles", path=path, hint="export it again from TRELLIS")
    check_vertices(mesh, path)
    extent = np.abs(mesh.vertices).max()
    if extent > 0.5 + 1e-3:
        raise MeshError(
            f"vertices reach {extent:.3f}, outside TRELLIS's normalized cube [-0.5, 0.5]^3",
            path=path,
            hint="import it as a metric mesh instead",
        )
    return mesh
