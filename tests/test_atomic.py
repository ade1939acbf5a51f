"""Atomic layer writes: a stage that fails midway leaves the previous layer and side files intact."""

import subprocess
import sys

import pytest
from conftest import oracle_options
from pxr import UsdGeom

from rose_usd import registry
from rose_usd.errors import StageError
from rose_usd.pipeline import Pipeline
from rose_usd.usd import paths
from rose_usd.usd.stage import LayerWriter, TimeInfo, layer_file


def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_writer_failure_changes_nothing(tmp_path):
    """An exception inside LayerWriter leaves the old layer, its side folder and the root as they were."""
    ti = TimeInfo(fps=30.0, n_frames=3)
    with LayerWriter(tmp_path, "world", ti, {"stage": "capture"}) as w:
        UsdGeom.Xform.Define(w.stage, paths.WORLD)
    with LayerWriter(tmp_path, "masks", ti, {"stage": "segment"}) as w:
        UsdGeom.Scope.Define(w.stage, paths.MASKS)
        (w.side_dir("masks") / "a.png").write_bytes(b"old")
    before = _tree(tmp_path)
    with pytest.raises(RuntimeError, match="boom"):
        with LayerWriter(tmp_path, "masks", ti, {"stage": "segment"}) as w:
            UsdGeom.Scope.Define(w.stage, paths.OBJECT_MASKS)
            (w.side_dir("masks") / "b.png").write_bytes(b"new")
            raise RuntimeError("boom")
    assert _tree(tmp_path) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "staging or temp files left behind"


def test_no_layer_commits_after_an_interrupt_was_lost(tmp_path, monkeypatch):
    """Ctrl-C whose KeyboardInterrupt a callback from C swallowed: the stage then runs to its
    end, but its layer does not commit (the interrupt was noted) and the old one stays."""
    from rose_usd.core import lifetime

    ti = TimeInfo(fps=30.0, n_frames=3)
    with LayerWriter(tmp_path, "world", ti, {"stage": "capture"}) as w:
        UsdGeom.Xform.Define(w.stage, paths.WORLD)
    before = _tree(tmp_path)
    monkeypatch.setattr(lifetime, "_interrupted", False)
    lifetime.note_interrupt()
    with pytest.raises(KeyboardInterrupt):
        with LayerWriter(tmp_path, "world", ti, {"stage": "capture"}) as w:
            UsdGeom.Scope.Define(w.stage, paths.WORLD.AppendChild("Other"))
    assert _tree(tmp_path) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "staging or temp files left behind"


_LOST_IN_A_CALLBACK = """
import signal, sys, time, weakref
from rose_usd.core.lifetime import note_interrupt, redeliver_lost_interrupts

def on_sigint(signum, frame):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    note_interrupt()
    raise KeyboardInterrupt

signal.signal(signal.SIGINT, on_sigint)
if sys.argv[1] == "hook":
    redeliver_lost_interrupts()

class Held:
    pass

held = Held()
ref = weakref.ref(held, lambda _: signal.raise_signal(signal.SIGINT))  # the handler runs in the callback
try:
    del held
    for _ in range(200):
        time.sleep(0.01)
    print("went on")
except KeyboardInterrupt:
    print("raised")
"""


@pytest.mark.parametrize("mode", ["hook", "none"])
def test_an_interrupt_lost_in_a_callback_is_raised_again(mode):
    """The SIGINT handler's KeyboardInterrupt raised inside a weakref callback: Python prints it
    as "Exception ignored" and goes on; with ``redeliver_lost_interrupts`` it is raised again in
    the main thread, with nothing printed."""
    proc = subprocess.run(
        [sys.executable, "-c", _LOST_IN_A_CALLBACK, mode], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    if mode == "hook":
        assert (proc.stdout.strip(), proc.stderr) == ("raised", "")
    else:  # what the hook is for
        assert proc.stdout.strip() == "went on" and "KeyboardInterrupt" in proc.stderr


def test_a_side_folder_the_new_layer_does_not_write_goes_with_the_old(tmp_path):
    """A stage re-run that writes no side folder it wrote before (an object stage that had a mesh
    file's texture, now without it) leaves none of the old folder behind; folders the layer never
    wrote stay."""
    ti = TimeInfo(fps=30.0, n_frames=3)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "mine.txt").write_text("the user's")
    with LayerWriter(tmp_path, "world", ti, {"stage": "capture"}) as w:
        UsdGeom.Xform.Define(w.stage, paths.WORLD)
    with LayerWriter(tmp_path, "object", ti, {"stage": "object"}) as w:
        UsdGeom.Scope.Define(w.stage, paths.OBJECTS)
        (w.side_dir("object_textures") / "Cube.png").write_bytes(b"texture")
    assert (tmp_path / "object_textures" / "Cube.png").is_file()
    with LayerWriter(tmp_path, "object", ti, {"stage": "object"}) as w:
        UsdGeom.Scope.Define(w.stage, paths.OBJECTS)
    assert not (tmp_path / "object_textures").exists()
    assert (tmp_path / "notes" / "mine.txt").read_text() == "the user's"


def test_writer_rejects_foreign_specs(tmp_path):
    """A layer that authored outside its claim is not committed."""
    ti = TimeInfo(fps=30.0, n_frames=3)
    with pytest.raises(StageError, match="does not own|may not define"):
        with LayerWriter(tmp_path, "scene", ti, {"stage": "scene"}) as w:
            UsdGeom.Xform.Define(w.stage, "/World/Objects/Intruder")
    assert not layer_file(tmp_path, "scene").exists()


def test_failing_stage_midway_keeps_previous_layer(out_copy, sample_case, monkeypatch):
    """The trajectory stage crashing after authoring half its frames leaves trajectory.usda,
    trajectory/*.tum and rose.usda byte-identical."""
    import rose_usd.trajectory.author as author

    before = _tree(out_copy)
    real = author.set_pose_ops
    calls = {"n": 0}

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 20:
            raise OSError("disk vanished")
        return real(*args, **kwargs)

    monkeypatch.setattr(author, "set_pose_ops", flaky)
    with pytest.raises(OSError, match="disk vanished"):
        Pipeline(sample_case, out_copy, oracle_options()).run_stage(registry.get("trajectory"))
    assert calls["n"] > 20
    assert _tree(out_copy) == before
