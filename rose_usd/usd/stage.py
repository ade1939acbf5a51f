"""The root stage, its layers, and atomic authoring of one stage's layer.

``<out>/rose.usda`` holds the stage metadata and sublayers the layers that exist, strongest first in
the contract's order. A pipeline stage writes its layer through :class:`LayerWriter`: it authors into
a fresh in-memory layer through an edit target, composed with the other layers exactly as the root
will compose it, and the file on disk is replaced only when the stage finished (write temp, then
``os.replace``). A failure leaves the previous layer and its side files untouched.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from pxr import Sdf, Usd, UsdGeom, UsdPhysics

from rose_usd.errors import StageError
from rose_usd.usd import paths


@dataclass(frozen=True)
class TimeInfo:
    """The video's timing: frame t is time code t."""

    fps: float
    """Frames per second of the video [1/s]; also the stage's timeCodesPerSecond."""
    n_frames: int
    """Number of frames; time codes run from 0 to n_frames - 1."""


def root_file(out_dir: Path) -> Path:
    return Path(out_dir) / paths.ROOT_FILE


def layer_file(out_dir: Path, layer: str) -> Path:
    return Path(out_dir) / paths.layer_file(layer)


def existing_layers(out_dir: Path) -> list[str]:
    """Layers present in ``out_dir``, strongest first."""
    return [name for name in paths.LAYER_ORDER if layer_file(out_dir, name).is_file()]


def _set_time_metadata(layer: Sdf.Layer, time_info: TimeInfo) -> None:
    # every layer carries the rate: a sublayer whose timeCodesPerSecond differs from the root's
    # (unauthored means 24) would have its time samples rescaled by USD
    layer.timeCodesPerSecond = time_info.fps
    layer.framesPerSecond = time_info.fps


def _set_root_metadata(layer: Sdf.Layer, time_info: TimeInfo) -> None:
    _set_time_metadata(layer, time_info)
    layer.startTimeCode = 0
    layer.endTimeCode = max(time_info.n_frames - 1, 0)
    layer.defaultPrim = paths.WORLD.name
    pseudo = layer.pseudoRoot
    pseudo.SetInfo(UsdGeom.Tokens.upAxis, UsdGeom.Tokens.z)
    pseudo.SetInfo(UsdGeom.Tokens.metersPerUnit, 1.0)
    pseudo.SetInfo(UsdPhysics.Tokens.kilogramsPerUnit, 1.0)
    layer.documentation = "rose_usd stage: gravity-aligned metric world, scene, objects, trajectories"


def write_root(out_dir: Path, time_info: TimeInfo) -> Path:
    """(Re)write ``<out>/rose.usda`` listing the layers that exist; atomic."""
    out_dir = Path(out_dir)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    _set_root_metadata(layer, time_info)
    layer.subLayerPaths = [f"./{paths.layer_file(name)}" for name in existing_layers(out_dir)]
    target = root_file(out_dir)
    _atomic_export(layer, target)
    return target


def read_time_info(out_dir: Path) -> TimeInfo | None:
    """The timing recorded in an existing root, or None if there is no root."""
    path = root_file(out_dir)
    if not path.is_file():
        return None
    layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    return TimeInfo(fps=layer.timeCodesPerSecond, n_frames=int(layer.endTimeCode) + 1)


def open_stage(path: str | os.PathLike, *, muted: tuple[str, ...] = ()) -> Usd.Stage:
    """Open a stage; composition errors raise StageError (never a silently partial stage).

    Args:
        path: a root layer file.
        muted: layer names (e.g. ``"trajectory"``) to mute, for inspecting one stage's contribution.
    """
    path = Path(path)
    if not path.is_file():
        raise StageError("stage file not found", path=path, hint="run `rose-usd reconstruct CASE -o OUT` first")
    # a layer this process already loaded is not re-read by Stage.Open: reload the ones of this
    # output folder that a stage has rewritten since (the root lists new layers as stages run)
    here = {path.parent.resolve(), (path.parent / "layers").resolve()}
    for layer in Sdf.Layer.GetLoadedLayers():
        real = layer.realPath
        if real and Path(real).parent in here and not layer.dirty:
            layer.Reload()
    stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    if stage is None:
        raise StageError("cannot open the stage", path=path, hint="check that it is a valid USD file")
    for name in muted:
        stage.MuteLayer(str(layer_file(path.parent, name).resolve()))
    raise_on_composition_errors(stage, path)
    return stage


def raise_on_composition_errors(stage: Usd.Stage, path: str | os.PathLike | None = None) -> None:
    errors = stage.GetCompositionErrors()
    if errors:
        raise StageError(
            f"{len(errors)} composition error(s), first: {errors[0]}",
            path=path or stage.GetRootLayer().identifier,
            hint="re-run the stage that wrote the broken layer",
        )


def file_hash(path: Path) -> str:
    """sha256 of a file's bytes (hex, first 16 characters)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def package_versions() -> dict[str, str]:
    """Versions of the packages a stage's output depends on."""
    out = {}
    for pkg in (
        "rose-usd",
        "usd-core",
        "numpy",
        "mitsuba",
        "newton",
        "warp-lang",
        "trimesh",
        "open3d",
        "opencv-python-headless",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "absent"
    return out


def read_provenance(path: Path) -> dict[str, Any] | None:
    """The ``rose`` entry of a layer's customLayerData, or None if the file has none."""
    if not Path(path).is_file():
        return None
    layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    data = dict(layer.customLayerData).get("rose")
    if data is None:
        return None
    return json.loads(data) if isinstance(data, str) else dict(data)


def _atomic_export(layer: Sdf.Layer, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}{target.suffix}")
    try:
        if not layer.Export(str(tmp)):
            raise StageError("could not write the layer", path=tmp, hint="check free disk space and permissions")
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


class LayerWriter:
    """Author one stage's layer atomically.

    Usage::

        with LayerWriter(out_dir, "world", time_info, provenance) as w:
            stage = w.stage                 # composed like rose.usda, edit target = the new layer
            ...author...
            masks_dir = w.side_dir("masks") # files that land in <out>/masks on commit

    On normal exit the layer is exported to ``layers/<name>.usda`` via a temp file and
    ``os.replace``, side folders replace their previous versions, and the root is rewritten.
    On an exception nothing in ``out_dir`` changes.
    """

    def __init__(self, out_dir: Path, layer: str, time_info: TimeInfo, provenance: dict[str, Any]):
        if layer not in paths.LAYER_ORDER:
            raise ValueError(f"unknown layer {layer!r}")
        self.out_dir = Path(out_dir)
        self.layer_name = layer
        self.time_info = time_info
        self.provenance = dict(provenance)
        self._staging = self.out_dir / f".staging-{layer}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self._side: dict[str, Path] = {}
        self.layer: Sdf.Layer | None = None
        self.stage: Usd.Stage | None = None
        self._t0 = 0.0

    def __enter__(self) -> "LayerWriter":
        self._t0 = time.perf_counter()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.layer = Sdf.Layer.CreateAnonymous(f"{self.layer_name}.usda")
        _set_time_metadata(self.layer, self.time_info)
        root = Sdf.Layer.CreateAnonymous("root.usda")
        _set_root_metadata(root, self.time_info)
        sublayers = []
        for name in paths.LAYER_ORDER:
            if name == self.layer_name:
                sublayers.append(self.layer.identifier)
            elif layer_file(self.out_dir, name).is_file():
                sublayers.append(str(layer_file(self.out_dir, name).resolve()))
        root.subLayerPaths = sublayers
        self.stage = Usd.Stage.Open(root, Usd.Stage.LoadAll)
        raise_on_composition_errors(self.stage, root_file(self.out_dir))
        self.stage.SetEditTarget(Usd.EditTarget(self.layer))
        self._root = root  # keep the anonymous root alive as long as the stage
        return self

    def side_dir(self, name: str) -> Path:
        """A fresh folder whose contents replace ``<out>/<name>`` when the layer commits."""
        if name not in self._side:
            path = self._staging / name
            path.mkdir(parents=True)
            self._side[name] = path
        return self._side[name]

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self._commit()
        finally:
            self.stage = None
            shutil.rmtree(self._staging, ignore_errors=True)

    def _commit(self) -> None:
        violations = paths.ownership_violations(self.layer, self.layer_name)
        if violations:
            raise StageError(
                f"layer {self.layer_name!r} authored specs it does not own: {violations[0]}"
                + (f" (+{len(violations) - 1} more)" if len(violations) > 1 else ""),
                hint="this is a bug in the stage's code; report it",
            )
        self.provenance["wall_time_s"] = round(time.perf_counter() - self._t0, 3)
        self.provenance.setdefault("versions", package_versions())
        self.provenance["layer"] = self.layer_name
        data = dict(self.layer.customLayerData)
        data["rose"] = json.dumps(self.provenance, sort_keys=True, default=str)
        self.layer.customLayerData = data
        # side folders first: the layer refers to them, so they must exist when it appears
        for name, staged in self._side.items():
            final = self.out_dir / name
            old = None
            if final.exists():
                old = self.out_dir / f".old-{name}-{uuid.uuid4().hex[:8]}"
                os.replace(final, old)
            os.replace(staged, final)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        _atomic_export(self.layer, layer_file(self.out_dir, self.layer_name))
        write_root(self.out_dir, self.time_info)
