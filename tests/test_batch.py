"""``rose-usd batch``: every case in its own process, failures recorded without stopping the others,
a summary in three formats, and a re-run (after kill -9 too) that redoes only what was not
finished, leaving finished cases untouched; Ray gives the same results."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rose_usd.batch import RECORD, batch, case_names
from rose_usd.cli import main
from rose_usd.errors import ConfigError

FAST = {"backends": {"capture": "oracle"}, "until": "capture"}


def _cases(tmp_path: Path, sample_case: Path, n: int) -> list[Path]:
    """n copies of the sample, and a case whose frames are missing."""
    out = []
    for i in range(n):
        dst = tmp_path / "cases" / f"push-{i}"
        shutil.copytree(sample_case, dst)
        out.append(dst)
    broken = tmp_path / "cases" / "broken"
    shutil.copytree(sample_case, broken)
    shutil.rmtree(broken / "rgb")
    return out + [broken]


def _mtimes(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


def test_names_are_unique_and_come_from_the_case():
    assert case_names(["a/x", "b/x", "c/y.mp4"]) == ["x", "x-2", "y"]


def test_each_case_runs_and_a_broken_one_is_recorded_not_fatal(tmp_path, sample_case):
    cases = _cases(tmp_path, sample_case, 2)
    out = tmp_path / "batch"
    result = batch(cases, out, workers=2, **FAST)
    status = {c.name: c.status for c in result.cases}
    assert status == {"push-0": "done", "push-1": "done", "broken": "failed"}
    broken = next(c for c in result.cases if c.name == "broken")
    assert "rgb" in broken.error and "\n" not in broken.error
    assert (out / "push-0" / "layers" / "world.usda").is_file() and (out / "push-0" / RECORD).is_file()
    assert "[capture] wrote" in (out / "push-0" / "batch.log").read_text()  # its stages' progress, logged
    assert not (out / "broken" / RECORD).exists()
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["name"] for r in rows] == ["push-0", "push-1", "broken"]
    assert float(rows[0]["capture_s"]) > 0 and rows[0]["collect_s"] == "" and rows[2]["capture_s"] == ""
    assert len(json.loads((out / "summary.json").read_text())) == 3
    assert "broken" in (out / "index.html").read_text()

    # again: the finished cases are taken from their records, nothing of them is rewritten
    before = _mtimes(out / "push-0")
    again = batch(cases, out, workers=1, **FAST)
    reused = {c.name: c.reused for c in again.cases}
    assert reused == {"push-0": True, "push-1": True, "broken": False}
    assert _mtimes(out / "push-0") == before

    # what a run interrupted since left behind (a staging folder of a dead process) is cleared
    litter = out / "push-0" / ".staging-gate-999999999-0badc0de"
    litter.mkdir()
    batch(cases, out, workers=1, **FAST)
    assert not litter.exists() and _mtimes(out / "push-0") == before

    # an edited case runs again (reconstruct redoes what the edit made stale); one touched, not
    # changed, goes through reconstruct too, which finds every layer current and rewrites none
    toml = cases[0] / "rose.toml"
    toml.write_text(toml.read_text().replace("fps = 30", "fps = 15"))
    edited = batch(cases, out, workers=1, **FAST)
    assert {c.name: c.reused for c in edited.cases} == {"push-0": False, "push-1": True, "broken": False}
    assert "framesPerSecond = 15" in (out / "push-0" / "layers" / "world.usda").read_text()
    os.utime(cases[1] / "rose.toml")
    before = _mtimes(out / "push-1" / "layers")
    touched = batch(cases, out, workers=1, **FAST)
    assert {c.name: c.reused for c in touched.cases}["push-1"] is False
    assert _mtimes(out / "push-1" / "layers") == before

    # a record that no longer matches its layers is not trusted: the case runs again
    (out / "push-1" / "layers" / "world.usda").write_text("#usda 1.0\n")
    third = batch(cases, out, workers=1, **FAST)
    assert {c.name: c.reused for c in third.cases}["push-1"] is False
    assert {c.name: c.status for c in third.cases}["push-1"] == "done"

    # a batch of one of the cases keeps the others finished in OUT in the summary (it listed
    # that case alone), as recorded; one whose layers no longer match its record is left out
    one = batch(cases[1:2], out, workers=1, **FAST)
    assert [c.name for c in one.cases] == ["push-1"]
    assert [r["name"] for r in csv.DictReader((out / "summary.csv").open())] == ["push-1", "push-0"]
    (out / "push-0" / "layers" / "world.usda").write_text("#usda 1.0\n")
    batch(cases[1:2], out, workers=1, **FAST)
    assert [r["name"] for r in csv.DictReader((out / "summary.csv").open())] == ["push-1"]


def test_a_resumed_case_reports_every_stage_time_and_a_refused_one_no_folder(
    tmp_path, sample_case, capsys, monkeypatch
):
    """A new user killed a batch and ran it again: the summary gave the resumed case the time of
    the stage that ran then alone (its earlier stages' columns empty), its progress counted 2 of
    the 3 cases given, and the refused case named an output folder that was never made."""
    cases = _cases(tmp_path, sample_case, 1)
    out = tmp_path / "batch"
    two = {"backends": {"capture": "oracle", "segment": "oracle"}, "until": "segment"}
    first = batch(cases, out, workers=1, **two)
    made = {c.name: c for c in first.cases}
    assert set(made["push-0"].stage_times_s) == {"capture", "segment"}
    assert made["broken"].out_dir == "" and not (out / "broken").exists()
    (out / "push-0" / RECORD).unlink()  # as if killed before the case was recorded, its masks lost
    (out / "push-0" / "layers" / "masks.usda").unlink()
    monkeypatch.delenv("ROSE_USD_QUIET")  # the batch's own lines (each case's go to its batch.log)
    again = batch(cases, out, workers=1, **two)
    resumed = next(c for c in again.cases if c.name == "push-0")
    assert resumed.stages_ran == ["segment"]
    assert resumed.stage_times_s["capture"] == made["push-0"].stage_times_s["capture"]
    row = next(r for r in csv.DictReader((out / "summary.csv").open()) if r["name"] == "push-0")
    assert float(row["capture_s"]) > 0 and float(row["segment_s"]) > 0
    assert "batch: 1 of 2 cases to run (1 refused, 0 recorded earlier)" in capsys.readouterr().err


def test_bad_batch_arguments_are_one_line_errors(tmp_path, sample_case):
    with pytest.raises(ConfigError, match="does not exist"):
        batch([tmp_path / "nowhere"], tmp_path / "out")
    with pytest.raises(ConfigError, match="no case"):
        batch([], tmp_path / "out")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="file"):
        batch([sample_case], tmp_path / "file")


def test_a_setting_typo_stops_the_batch_before_anything_and_a_case_typo_is_refused_up_front(tmp_path, sample_case):
    """A ``--set`` typo every case would refuse stops the batch at once, writing nothing; a typo in
    one case's rose.toml records that case as failed before the others run, and they run."""
    cases = _cases(tmp_path, sample_case, 1)[:1]
    out = tmp_path / "batch"
    with pytest.raises(ConfigError, match="frame_strid"):
        batch(cases, out, settings={"gate": {"frame_strid": 5}}, **FAST)
    assert not out.exists()
    typo = tmp_path / "cases" / "typo"
    shutil.copytree(sample_case, typo)
    toml = typo / "rose.toml"
    toml.write_text(toml.read_text().replace("category", "categroy", 1))
    result = batch([typo, *cases], out, **FAST)
    status = {c.name: (c.status, c.wall_time_s) for c in result.cases}
    assert status["push-0"][0] == "done" and status["typo"] == ("failed", 0.0)
    assert "refused before any case ran" in next(c.error for c in result.cases if c.name == "typo")
    assert "categroy" in next(c.error for c in result.cases if c.name == "typo")


def _children(pid: int) -> list[int]:
    """The pids whose parent is ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _started_batch(tmp_path: Path, sample_case: Path):
    """A batch of three copies of the sample (capture and segment from the oracle) once its first
    case is recorded: the cases, the output folder, the process, its command and environment."""
    cases = _cases(tmp_path, sample_case, 3)[:3]
    out = tmp_path / "batch"
    cmd = [sys.executable, "-m", "rose_usd.cli", "batch", *map(str, cases), "-o", str(out)]
    cmd += ["--until", "segment", "--backend", "capture=oracle", "--backend", "segment=oracle"]
    env = dict(os.environ, ROSE_USD_QUIET="1")
    proc = subprocess.Popen(
        cmd,
        env=env,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        # as from a terminal: a test runner's worker may ignore SIGINT, and its children inherit that
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.time() + 600
    while not (out / "push-0" / RECORD).exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    assert (out / "push-0" / RECORD).exists(), "the first case never finished"
    return cases, out, proc, cmd, env


def test_kill_9_halfway_then_the_same_command_finishes_what_was_not(tmp_path, sample_case):
    """The whole batch (its process group) is killed with SIGKILL once the first case is
    recorded; the same command then finishes every case, and the first one is not touched."""
    cases, out, proc, cmd, env = _started_batch(tmp_path, sample_case)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = {c.name for c in cases if (out / c.name / RECORD).exists()}
    assert len(finished) < 3, "killed too late: every case had finished"
    before = {name: _mtimes(out / name) for name in finished}
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    for c in cases:
        assert (out / c.name / RECORD).exists()
        assert (out / c.name / "layers" / "masks.usda").is_file()
    for name in finished:
        assert _mtimes(out / name) == before[name]
    assert len(list(csv.DictReader((out / "summary.csv").open()))) == 3


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_kill_9_of_the_batch_alone_leaves_no_worker_writing_on(tmp_path, sample_case):
    """SIGKILL to the batch's own process (not its group: a scheduler's kill) ends its worker and
    the worker's stage process too (a worker left running went on writing the folder a re-run
    then wrote as well)."""
    cases, out, proc, _, _ = _started_batch(tmp_path, sample_case)
    workers = _children(proc.pid)
    below = [pid for w in workers for pid in _children(w)]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.time() + 1.0  # a case takes seconds more: only a worker tied to the batch is gone by then
    while any(_alive(pid) for pid in workers + below) and time.time() < deadline:
        time.sleep(0.1)
    assert workers and not [pid for pid in workers + below if _alive(pid)]


def test_ctrl_c_stops_the_batch_at_once(tmp_path, sample_case):
    """A terminal's Ctrl-C (SIGINT to the process group) stops the whole batch: exit 130,
    "interrupted", the cases not started are not run (the first Ctrl-C used to end only the
    running case's stage, and the batch went on to the next case)."""
    cases, out, proc, _, _ = _started_batch(tmp_path, sample_case)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        code = proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    err = proc.stderr.read().decode()
    assert code == 130 and "interrupted" in err, err
    recorded = [c.name for c in cases if (out / c.name / RECORD).exists()]
    assert len(recorded) < 3, "every case ran"
    assert [row["name"] for row in csv.DictReader((out / "summary.csv").open())] == recorded


def test_ray_runs_the_same_cases_with_the_same_results(tmp_path, sample_case):
    pytest.importorskip("ray")
    cases = _cases(tmp_path, sample_case, 2)
    local = batch(cases, tmp_path / "local", workers=2, **FAST)
    on_ray = batch(cases, tmp_path / "ray", ray="local", **FAST)
    assert [(c.name, c.status) for c in on_ray.cases] == [(c.name, c.status) for c in local.cases]
    for c in local.cases:
        if c.status == "done":
            a = (tmp_path / "local" / c.name / "layers" / "world.usda").read_text()
            b = (tmp_path / "ray" / c.name / "layers" / "world.usda").read_text()
            strip = [line for line in a.splitlines() if "customLayerData" not in line and "rose =" not in line]
            assert strip == [line for line in b.splitlines() if "customLayerData" not in line and "rose =" not in line]


def test_a_case_no_ray_node_can_run_is_refused_not_waited_on(tmp_path, sample_case, capsys):
    """More CPUs a case than the local Ray cluster has: one line and exit 1 (Ray itself would wait
    for ever); on a cluster started elsewhere, which may grow, a warning."""
    pytest.importorskip("ray")
    from rose_usd.batch import _check_fits

    case = _cases(tmp_path, sample_case, 1)[0]
    code = main(["batch", str(case), "-o", str(tmp_path / "out"), "--ray", "local", "--cpus-per-case", "4096"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error")]  # Ray's own beside
    assert code == 1 and len(err) == 1 and "4096 CPUs" in err[0] and "--cpus-per-case" in err[0], err
    nodes = [{"Alive": True, "Resources": {"CPU": 8.0, "GPU": 1.0}}, {"Alive": False, "Resources": {"CPU": 64.0}}]
    _check_fits(nodes, 8, 1, "local")
    with pytest.raises(ConfigError, match="the largest: 8 CPUs, 1 GPUs"):
        _check_fits(nodes, 16, 0, "local")
    _check_fits(nodes, 16, 0, "ray://head:10001")
    assert "wait until such a node joins" in capsys.readouterr().err


def test_a_video_decoded_by_two_workers_keeps_the_first_workers_frames(tmp_path, sample_case, monkeypatch):
    """Two workers on one video decode it side by side: the one that finishes second leaves the
    first's frames cache (which it may be reading) in place and uses it."""
    import cv2

    from rose_usd.case import layout

    case = tmp_path / "case"
    shutil.copytree(sample_case, case)
    frames = sorted((case / "rgb").glob("*.png"))
    writer = cv2.VideoWriter(str(case / "video.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 30, (320, 240))
    for f in frames:
        writer.write(cv2.imread(str(f)))
    writer.release()
    shutil.rmtree(case / "rgb")
    monkeypatch.setenv("ROSE_USD_CACHE", str(tmp_path / "cache"))
    imwrite, other = cv2.imwrite, []

    def the_other_worker_finishes_first(path, image):
        if not other:  # the other worker's complete cache appears beside this one's staging folder
            folder = Path(path).parent.with_name(Path(path).parent.name.split("-")[0].lstrip("."))
            folder.mkdir(parents=True)
            for t in range(len(frames)):
                imwrite(str(folder / f"{t:06d}.png"), image)
            (folder / "reading").write_text("")
            (folder / ".complete").write_text(str(len(frames)))
            other.append(folder)
        return imwrite(path, image)

    monkeypatch.setattr(cv2, "imwrite", the_other_worker_finishes_first)
    decoded = layout.load_case(case)._video_frames
    assert other and (other[0] / "reading").is_file()
    assert decoded[0].parent == other[0] and len(decoded) == len(frames)
    assert not list(other[0].parent.glob(".*"))  # this worker's staging folder is gone
