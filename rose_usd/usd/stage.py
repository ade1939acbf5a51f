"""The root stage, its layers, and atomic authoring of one stage's layer.

``<out>/rose.usda`` holds the stage metadata and sublayers the layers that exist, strongest first in
the contract's order. A pipeline stage writes its layer through :class:`LayerWriter`: it authors into
a fresh in-memory layer through an edit target, composed with the other layers exactly as the root
will compose it, and the file on disk is replaced only when the stage finished (write temp, then
``os.replace``). A failure leaves the previous layer and its side files untouched.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import tempfile
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from pxr import Sdf, Tf, Usd, UsdGeom, UsdPhysics

from rose_usd.core.lifetime import interrupt_noted
from rose_usd.errors import ConfigError, InputError, StageError
from rose_usd.usd import paths


@dataclass(frozen=True)
class TimeInfo:
    """The video's timing: frame t is time code t."""

    fps: float
    """Frames per second of the video [1/s]; also the stage's timeCodesPerSecond."""
    n_frames: int
    """Number of frames; time codes run from 0 to n_frames - 1."""


USD_SUFFIXES = (".usda", ".usd", ".usdc", ".usdz")


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
    if path.is_dir():
        raise StageError(
            "is a folder, not a stage file", path=path, hint=f"give the stage file, e.g. {path / paths.ROOT_FILE}"
        )
    if not path.is_file():
        raise StageError("stage file not found", path=path, hint="run `rose-usd reconstruct CASE -o OUT` first")
    if path.suffix.lower() not in USD_SUFFIXES:
        raise StageError(
            f"not a USD file (its suffix is {path.suffix or 'none'})",
            path=path,
            hint=f"give a stage file ({', '.join(USD_SUFFIXES)}), e.g. OUT/rose.usda",
        )
    # a layer this process already loaded is not re-read by Stage.Open: reload the ones of this
    # output folder that a stage has rewritten since (the root lists new layers as stages run)
    here = {path.parent.resolve(), (path.parent / "layers").resolve()}
    for layer in Sdf.Layer.GetLoadedLayers():
        real = layer.realPath
        if real and Path(real).parent in here and not layer.dirty:
            layer.Reload()
    try:
        root = Sdf.Layer.FindOrOpen(str(path))
        # plain relative files only (an output folder's layers/): a .usdz's sublayers are inside it,
        # and an absolute path, a search path or a URI is USD's to resolve
        plain = path.suffix.lower() != ".usdz" and root is not None
        relative = [sub for sub in (root.subLayerPaths if plain else []) if sub.startswith(("./", "../"))]
        gone = [sub for sub in relative if not (path.parent / sub).is_file()]
        if gone:  # before USD warns of each on stderr
            raise StageError(
                f"{gone[0]} is missing" + (f" (and {len(gone) - 1} more layer(s))" if len(gone) > 1 else ""),
                path=path,
                hint=f"`rose-usd reconstruct CASE -o {path.parent}` runs again what is missing",
            )
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        reason = usd_error_reason(str(exc))
        raise StageError(
            "not a USD stage that can be opened" + (f" ({reason})" if reason else ""),
            path=path,
            hint="give a stage file written by rose-usd (OUT/rose.usda) or another valid USD file",
        ) from None
    if stage is None:
        raise StageError("cannot open the stage", path=path, hint="check that it is a valid USD file")
    for name in muted:
        stage.MuteLayer(str(layer_file(path.parent, name).resolve()))
    raise_on_composition_errors(stage, path)
    return stage


def usd_error_reason(text: str, limit: int = 200) -> str:
    """The first message of a Tf.ErrorException's text ("Error in 'function' at line N in file
    F : 'message'"): the message alone, USD's namespace prefix left out (a usda file's own
    file:line:column stays)."""
    for chunk in text.split("Error in ")[1:]:
        _, sep, message = chunk.partition(" : '")
        if sep:
            message = re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", message.strip().removesuffix("'").strip())
            return message[:limit]
    return text.strip().splitlines()[0][:limit] if text.strip() else ""


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


def shown_backend(provenance: dict | None, planned: str) -> str:
    """The backend a layer names for people: the planned one, ``planned->built`` where it built
    another's layer (``StageContext.built_as``)."""
    built = (provenance or {}).get("built_as")
    return f"{planned}->{built}" if built and built != planned else planned


def read_provenance(path: Path) -> dict[str, Any] | None:
    """The ``rose`` entry of a layer's customLayerData, or None if the file has none."""
    if not Path(path).is_file():
        return None
    layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    data = dict(layer.customLayerData).get("rose")
    if data is None:
        return None
    return json.loads(data) if isinstance(data, str) else dict(data)


def _temp_name(target: Path) -> Path:
    return target.with_name(f".tmp-{target.stem}-{os.getpid()}-{uuid.uuid4().hex[:8]}{target.suffix}")


def _export(layer: Sdf.Layer, path: Path) -> None:
    """``layer.Export`` with its failure as a StageError (USD raises rather than return False)."""
    try:
        ok = layer.Export(str(path))
    except Tf.ErrorException as exc:
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unknown"
        raise StageError(
            f"could not write the layer ({reason})", path=path, hint="check free disk space and permissions"
        ) from None
    if not ok:
        raise StageError("could not write the layer", path=path, hint="check free disk space and permissions")


def _atomic_export(layer: Sdf.Layer, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(target)
    try:
        _export(layer, tmp)
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(path: Path, text: str) -> None:
    """``path`` holds ``text`` whole or keeps what it held: written to a temporary file beside it,
    synced, renamed over it, and the folder synced."""
    tmp = _temp_name(path)
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _write_json_atomic(path: Path, data: dict) -> None:
    write_text_atomic(path, json.dumps(data, sort_keys=True))


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# ----------------------------------------------------------------------------- output folder
def check_out_dir(out_dir: str | os.PathLike) -> Path:
    """The output folder, checked before any work: not empty, not a file or under one, writable,
    its ``layers`` a folder and its root a file where they exist. Writes nothing (a probe file is
    made and removed in the nearest existing folder)."""
    text = os.fspath(out_dir)
    if not str(text).strip():
        raise ConfigError("the output folder is empty", path="-o", hint="give a folder, e.g. -o out/my_case")
    path = Path(text)
    hint = "give a folder (it is made if missing), e.g. -o out/my_case"
    if path.exists() and not path.is_dir():
        raise InputError("the output folder is a file, not a folder", path=path, hint=hint)
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise InputError("the output folder would lie under a file", path=existing, hint=hint)
    try:
        fd, probe = tempfile.mkstemp(prefix=".tmp-probe-", dir=existing)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        where = "" if existing == path else f" in {existing}"
        raise InputError(
            f"cannot make or write the output folder ({exc.strerror or exc}{where})",
            path=path,
            hint="give a folder you can write to",
        ) from None
    if path.is_dir():
        layers = path / paths.LAYERS_DIR
        if layers.exists() and not layers.is_dir():
            raise InputError(
                "is a file, where the output's layers go", path=layers, hint="remove it or give -o another folder"
            )
        root = root_file(path)
        if root.exists() and not root.is_file():
            raise InputError(
                "is not a file, where the output's root layer goes",
                path=root,
                hint="remove it or give -o another folder",
            )
    return path


@contextlib.contextmanager
def output_lock(out_dir: Path):
    """This process alone writes ``out_dir`` meanwhile (created if missing): an exclusive lock on
    the folder itself (``flock``), which the kernel drops when the process ends, however it ends.
    While another run holds it, a StageError naming the folder: two runs into one folder (a batch
    re-run while the killed one's worker still ran) removed each other's layers as stale."""
    try:
        import fcntl
    except ImportError:  # no flock here (Windows): unguarded, as before
        yield
        return
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise StageError(
                "another rose-usd run is writing this output folder",
                path=out_dir,
                hint="wait for it to end (or stop it), or give another output folder (-o)",
            ) from None
        yield
    finally:
        os.close(fd)


def check_out_case(out_dir: Path, case_root: Path, case_hash: Callable[[], str]) -> None:
    """An output folder holds one case's stages: refused where it cannot be written (the folder, or
    the nearest one that exists above it, has no write bit: a read-only dataset, even for root),
    when it is the case folder itself or lies
    in one of its folders of inputs (the stages would write among them; ``CASE/out`` is fine), or
    when a layer in it was made from another case, one at another path whose inputs differed too
    (its provenance's ``case`` and ``inputs.case`` against ``case_root`` and ``case_hash()``,
    called only for a layer made at another path: it reads every input file): a run would remove
    that case's layers as stale. The same case edited in place, or copied elsewhere unchanged, may
    use it."""
    from rose_usd.case.layout import CASE_DIRS

    root, out = Path(case_root).resolve(), Path(out_dir).resolve()
    if out == root:
        raise InputError(
            "is the case folder itself: the stages would write among its inputs",
            path=out_dir,
            hint=f"give -o another folder, e.g. -o out/{root.stem}",
        )
    held = next(p for p in (out, *out.parents) if p.exists())  # the folder that will hold it
    if held.is_dir() and not (os.access(held, os.W_OK) and held.stat().st_mode & 0o222):  # no write bit: root too
        raise InputError(
            f"cannot be written: {held} is read-only",
            path=out_dir,
            hint=f"give -o a folder of your own, e.g. -o out/{root.stem}",
        )
    inputs = next((root / d for d in CASE_DIRS if out.is_relative_to(root / d)), None) if root.is_dir() else None
    if inputs is not None:
        raise InputError(
            f"is inside the case's {inputs.name}/: the stages would write among its inputs",
            path=out_dir,
            hint=f"give -o a folder outside {inputs}, e.g. -o {root / 'out'}",
        )
    for name in existing_layers(out_dir):
        prov = read_provenance(layer_file(out_dir, name)) or {}
        made_from = prov.get("case")
        if made_from and Path(made_from) != root and (prov.get("inputs") or {}).get("case") != case_hash():
            raise InputError(
                f"holds the stages of another case ({made_from}); a run would replace them",
                path=out_dir,
                hint="give -o another folder, or delete this one's layers/ to reuse it",
            )


def dir_hash(folder: Path) -> str:
    """sha256 of a folder's files (relative names and contents), first 16 hex characters."""
    h = hashlib.sha256()
    for f in sorted(p for p in Path(folder).rglob("*") if p.is_file()):
        h.update(f.relative_to(folder).as_posix().encode())
        h.update(file_hash(f).encode())
    return h.hexdigest()[:16]


# ----------------------------------------------------------------------------- commit journal
_JOURNAL = ".commit-{}.json"


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _litter_pid(name: str) -> int | None:
    """The writing process's id in a staging or temp name (None when it has none)."""
    for part in name.split("-"):
        if part.isdigit():
            return int(part)
    return None


def _apply(out_dir: Path, journal: dict) -> None:
    """Make the moves a commit's journal lists; every step may already have been made (a commit
    killed halfway is finished by running this again)."""
    staging = out_dir / journal["staging"]
    for side in journal.get("sides", []):
        staged, final, old = staging / side, out_dir / side, staging / f"old-{side}"
        if staged.exists():
            if final.exists():
                if old.exists():
                    shutil.rmtree(final)
                else:
                    os.replace(final, old)
            os.replace(staged, final)
    staged_layer = staging / "layer.usda"
    if staged_layer.exists():
        target = layer_file(out_dir, journal["layer"])
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staged_layer, target)
    for name in journal.get("remove", []):
        layer_file(out_dir, name).unlink(missing_ok=True)
    for side in journal.get("remove_sides", []):
        if (out_dir / side).exists() and not (staging / f"old-{side}").exists():
            os.replace(out_dir / side, staging / f"old-{side}")
    write_root(out_dir, TimeInfo(fps=float(journal["fps"]), n_frames=int(journal["n_frames"])))


def recover(out_dir: str | os.PathLike) -> list[str]:
    """Finish the commits a killed process left a journal of and remove what any other left
    behind (staging folders, temp files): the folder is then either the old or the new result.
    Returns what was done, one line each."""
    out_dir = Path(out_dir)
    done: list[str] = []
    if not out_dir.is_dir():
        return done
    for path in sorted(out_dir.glob(".commit-*.json")):
        try:
            journal = json.loads(path.read_text())
            staging = journal["staging"]
        except (OSError, ValueError, KeyError, TypeError):
            raise StageError(
                "an unreadable commit journal", path=path, hint="remove it and re-run the stage it names"
            ) from None
        pid = _litter_pid(staging)
        if pid is not None and _pid_alive(pid):
            continue  # another process is committing right now
        _apply(out_dir, journal)
        path.unlink()
        shutil.rmtree(out_dir / staging, ignore_errors=True)
        done.append(f"finished the interrupted commit of layer {journal.get('layer')!r}")
    for folder in (out_dir, out_dir / paths.LAYERS_DIR):
        if not folder.is_dir():
            continue
        for path in folder.iterdir():
            if not path.name.startswith((".staging-", ".old-", ".tmp-")):
                continue
            pid = _litter_pid(path.name[1:])
            if pid is not None and _pid_alive(pid):
                continue
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
            done.append(f"removed {path.name}, left by an interrupted run")
    return done


def pending_commits(out_dir: Path) -> list[Path]:
    return sorted(Path(out_dir).glob(".commit-*.json"))


# ----------------------------------------------------------------------------- consistency
def _inputs_stale(prov: dict, hashes: dict[str, str], case: str | None) -> str | None:
    """Why a layer with provenance ``prov`` does not belong with layers whose file hashes are
    ``hashes`` (layer name -> hash, "missing") and a case ``case``; None when it does."""
    inputs = prov.get("inputs") or {}
    mine = inputs.get("case")
    if case is not None and mine is not None and mine != case:
        return "another case"
    for key, recorded in inputs.items():
        if key.startswith("layer:"):
            upstream = key.split(":", 1)[1]
            now = hashes.get(upstream, "missing")
            if now != recorded:
                return f"{now if now in ('missing', 'stale') else 'changed'} {upstream}"
    return None


def stale_layers(
    out_dir: Path, provenances: dict[str, dict], hashes: dict[str, str], case: str | None
) -> list[tuple[str, str]]:
    """(layer, why) of every layer that does not belong with ``hashes`` and ``case``, removed
    transitively (a layer made from a stale one is stale too), in the pipeline's order."""
    hashes = dict(hashes)
    out = []
    for name in reversed(paths.LAYER_ORDER):  # world first
        prov = provenances.get(name)
        if prov is None:
            continue
        why = _inputs_stale(prov, hashes, case)
        if why is not None:
            out.append((name, why))
            hashes[name] = "stale"  # what was made from it is stale too
    return out


def _describe(name: str, why: str, first: str | None) -> str:
    layer = paths.layer_file(name)
    if why == "another case":
        return f"{layer} was made from another case than {paths.layer_file(first) if first else 'the others'}"
    kind, upstream = why.split(" ", 1)
    if kind == "missing":
        return f"{layer} was made from {paths.layer_file(upstream)}, which is missing"
    if kind == "stale":
        return f"{layer} depends on {paths.layer_file(upstream)}, which does not belong here (above)"
    return f"{layer} is stale: {paths.layer_file(upstream)} changed since it was made"


def consistency_problems(out_dir: str | os.PathLike) -> list[str]:
    """Where the layers of an output folder disagree, one line each (empty when they agree): an
    interrupted commit, a layer made from another case or from an upstream layer that has
    changed or gone, a side folder that is not the one its layer made, a root whose time range
    is not the layers'."""
    out_dir = Path(out_dir)
    problems = [
        f"{p}: an interrupted commit of layer {p.stem.removeprefix('.commit-')!r}; "
        "any `rose-usd run` or `reconstruct` into this folder finishes it"
        for p in pending_commits(out_dir)
    ]
    names = existing_layers(out_dir)
    provs = {n: read_provenance(layer_file(out_dir, n)) or {} for n in names}
    hashes = {n: file_hash(layer_file(out_dir, n)) for n in names}
    order = [n for n in reversed(paths.LAYER_ORDER) if n in names]
    first = next((n for n in order if (provs[n].get("inputs") or {}).get("case")), None)
    case = (provs[first].get("inputs") or {}).get("case") if first else None
    for name, why in stale_layers(out_dir, provs, hashes, case):
        problems.append(_describe(name, why, first))
    for name in order:
        for side, recorded in (provs[name].get("outputs") or {}).items():
            folder = out_dir / side
            if (dir_hash(folder) if folder.is_dir() else "missing") != recorded:
                problems.append(f"{side}/ is not the folder {paths.layer_file(name)} made (a mix of two runs)")
    root = read_time_info(out_dir) if root_file(out_dir).is_file() else None
    for name in order:
        made = provs[name].get("time")
        if root is not None and made and int(made.get("n_frames", -1)) != root.n_frames:
            problems.append(
                f"{paths.ROOT_FILE} spans {root.n_frames} frames, {paths.layer_file(name)} was made for "
                f"{made['n_frames']}"
            )
            break
    return problems


class LayerWriter:
    """Author one stage's layer atomically.

    Usage::

        with LayerWriter(out_dir, "world", time_info, provenance) as w:
            stage = w.stage                 # composed like rose.usda, edit target = the new layer
            ...author...
            masks_dir = w.side_dir("masks") # files that land in <out>/masks on commit

    On normal exit the layer, its side folders and the removal of the layers it makes stale are
    committed as one step (see the module docstring), and the root is rewritten. On an exception
    nothing in ``out_dir`` changes.

    Args:
        side_dirs: layer name -> the side folders its stage writes, to remove with a layer that
            this one makes stale (layers record their own in their provenance's ``outputs``).
    """

    def __init__(
        self,
        out_dir: Path,
        layer: str,
        time_info: TimeInfo,
        provenance: dict[str, Any],
        side_dirs: dict[str, tuple[str, ...]] | None = None,
    ):
        if layer not in paths.LAYER_ORDER:
            raise ValueError(f"unknown layer {layer!r}")
        self.out_dir = Path(out_dir)
        self.layer_name = layer
        self.time_info = time_info
        self.provenance = dict(provenance)
        self.side_dirs = dict(side_dirs or {})
        self._staging = self.out_dir / f".staging-{layer}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self._side: dict[str, Path] = {}
        self.layer: Sdf.Layer | None = None
        self.stage: Usd.Stage | None = None
        self._t0 = 0.0
        self.removed: list[str] = []
        """Layers the commit removed because it left them stale."""

    def __enter__(self) -> "LayerWriter":
        self._t0 = time.perf_counter()
        self.out_dir.mkdir(parents=True, exist_ok=True)
        recover(self.out_dir)
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

    def _stale_after(self, new_hash: str) -> list[str]:
        """The other layers this commit leaves without what they were made from."""
        names = [n for n in existing_layers(self.out_dir) if n != self.layer_name]
        provs = {n: read_provenance(layer_file(self.out_dir, n)) or {} for n in names}
        hashes = {n: file_hash(layer_file(self.out_dir, n)) for n in names}
        hashes[self.layer_name] = new_hash
        case = (self.provenance.get("inputs") or {}).get("case")
        return [name for name, _ in stale_layers(self.out_dir, provs, hashes, case)]

    def _commit(self) -> None:
        if interrupt_noted():  # Ctrl-C came, and what it raised was lost on the way: no commit
            raise KeyboardInterrupt
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
        self.provenance["time"] = {"fps": self.time_info.fps, "n_frames": self.time_info.n_frames}
        self.provenance["outputs"] = {name: dir_hash(staged) for name, staged in sorted(self._side.items())}
        data = dict(self.layer.customLayerData)
        data["rose"] = json.dumps(self.provenance, sort_keys=True, default=str)
        self.layer.customLayerData = data
        self._staging.mkdir(parents=True, exist_ok=True)
        staged_layer = self._staging / "layer.usda"
        _export(self.layer, staged_layer)
        remove = self._stale_after(file_hash(staged_layer))
        remove_sides = sorted(
            {
                side
                for name in remove
                for side in (
                    (read_provenance(layer_file(self.out_dir, name)) or {}).get("outputs")
                    or dict.fromkeys(self.side_dirs.get(name, ()))
                )
                if side not in self._side
            }
            # the folders this layer's earlier version wrote and this one does not (an object
            # stage re-run on a mesh file without a texture): they would show what no layer says
            | {
                side
                for side in (read_provenance(layer_file(self.out_dir, self.layer_name)) or {}).get("outputs") or {}
                if side not in self._side
            }
        )
        journal = {
            "layer": self.layer_name,
            "staging": self._staging.name,
            "sides": sorted(self._side),
            "remove": remove,
            "remove_sides": remove_sides,
            "fps": self.time_info.fps,
            "n_frames": self.time_info.n_frames,
        }
        journal_path = self.out_dir / _JOURNAL.format(self.layer_name)
        # the commit point: from here on the commit is finished, by this process or by recover()
        _write_json_atomic(journal_path, journal)
        _apply(self.out_dir, journal)
        journal_path.unlink()
        _fsync_dir(self.out_dir)
        self.removed = remove
