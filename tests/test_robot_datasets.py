"""LeRobot v3.0 and robomimic HDF5 writers: what is written reads back, in the fields the formats'
own loaders expect."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from rose_usd.io import lerobot, robomimic

FEATURES = {
    "observation.state": lerobot.Feature("float32", ("j1", "j2", "j3")),
    "action": lerobot.Feature("float32", ("j1", "j2", "j3")),
}


def _episodes():
    rng = np.random.default_rng(0)
    return [lerobot.Episode("move the box", {k: rng.normal(size=(n, 3)) for k in FEATURES}) for n in (5, 7)] + [
        lerobot.Episode("lift the can", {k: rng.normal(size=(4, 3)) for k in FEATURES})
    ]


def test_lerobot_round_trip(tmp_path):
    """Frames, indices, episodes, tasks, info and stats read back as written."""
    episodes = _episodes()
    info_file = lerobot.write_dataset(tmp_path, episodes, FEATURES, fps=30, robot_type="panda")
    info, frames, rows, tasks = lerobot.read_dataset(tmp_path)
    assert info_file == tmp_path / "meta" / "info.json"
    assert info["codebase_version"] == "v3.0" and info["fps"] == 30 and info["robot_type"] == "panda"
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (3, 16, 2)
    assert info["splits"] == {"train": "0:3"}
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert set(info["features"]) == set(FEATURES) | {"timestamp", "frame_index", "episode_index", "index", "task_index"}
    assert info["features"]["observation.state"] == {"dtype": "float32", "shape": [3], "names": ["j1", "j2", "j3"]}
    assert tasks == ["move the box", "lift the can"]
    for key in FEATURES:
        np.testing.assert_allclose(frames[key], np.concatenate([e.data[key] for e in episodes]), rtol=1e-6)
    np.testing.assert_array_equal(frames["index"], np.arange(16))
    np.testing.assert_array_equal(frames["episode_index"], [0] * 5 + [1] * 7 + [2] * 4)
    np.testing.assert_array_equal(frames["frame_index"][5:12], np.arange(7))
    np.testing.assert_array_equal(frames["task_index"], [0] * 12 + [1] * 4)
    np.testing.assert_allclose(frames["timestamp"][:5], np.arange(5) / 30, rtol=1e-6)
    assert [r["episode_index"] for r in rows] == [0, 1, 2]
    assert [(r["dataset_from_index"], r["dataset_to_index"], r["length"]) for r in rows] == [
        (0, 5, 5),
        (5, 12, 7),
        (12, 16, 4),
    ]
    assert rows[2]["tasks"] == ["lift the can"]
    assert rows[1]["data/chunk_index"] == 0 and rows[1]["meta/episodes/file_index"] == 0
    np.testing.assert_allclose(rows[1]["stats/action/mean"], episodes[1].data["action"].mean(axis=0), rtol=1e-6)
    stats = json.loads((tmp_path / "meta" / "stats.json").read_text())
    assert set(stats["action"]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
    assert stats["index"]["count"] == [16]
    np.testing.assert_allclose(stats["observation.state"]["max"], frames["observation.state"].max(axis=0), rtol=1e-6)


def test_lerobot_video_round_trip(tmp_path):
    """A camera stream: one AV1 file holding the episodes one after the other, each episode's
    place in it as lerobot seeks it (from/to timestamps), its image stats, and frames that decode
    to what was written (within the codec's loss)."""
    from rose_usd.io.video import read_frames, video_info

    episodes = _episodes()
    shades = [40, 140, 220]

    def frames(e, n):
        for i in range(n):
            rgb = np.zeros((48, 64, 3), np.uint8)
            rgb[..., e] = shades[e]
            rgb[20:28, 4 * i : 4 * i + 8] = 255  # a square moving right
            yield rgb

    for e, ep in enumerate(episodes):
        ep.videos["observation.images.camera"] = frames(e, ep.length)
    lerobot.write_dataset(
        tmp_path, episodes, FEATURES, fps=30, robot_type="panda", videos={"observation.images.camera": (48, 64)}
    )
    info, data, rows, _ = lerobot.read_dataset(tmp_path)
    feature = info["features"]["observation.images.camera"]
    assert feature["dtype"] == "video" and feature["shape"] == [48, 64, 3]
    assert feature["info"]["video.codec"] == "av1" and feature["info"]["video.fps"] == 30
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    assert "observation.images.camera" not in data  # video features live in the mp4 only
    path = tmp_path / info["video_path"].format(video_key="observation.images.camera", chunk_index=0, file_index=0)
    meta = video_info(path)
    assert (meta["codec"], meta["width"], meta["height"], meta["pix_fmt"], meta["frames"]) == (
        "av1",
        64,
        48,
        "yuv420p",
        16,
    )
    decoded = list(read_frames(path))
    for e, row in enumerate(rows):
        first = int(round(row["videos/observation.images.camera/from_timestamp"] * 30))
        last = int(round(row["videos/observation.images.camera/to_timestamp"] * 30))
        assert (first, last) == (row["dataset_from_index"], row["dataset_to_index"])
        assert abs(float(decoded[first][40, 40, e]) - shades[e]) < 8  # the episode's colour at its first frame
        mean = np.asarray(row["stats/observation.images.camera/mean"], dtype=float)
        assert (
            mean.shape == (3, 1, 1)
            and abs(mean[e, 0, 0] - (shades[e] * (1 - 64 / 3072) + 255 * 64 / 3072) / 255) < 0.01
        )
    square = [int(np.argmax(f[24, :, 1] > 200)) for f in decoded[5:12]]  # episode 1: the square moves 4 px a frame
    assert np.all(np.abs(np.diff(square) - 4) <= 1), square
    stats = json.loads((tmp_path / "meta" / "stats.json").read_text())
    assert stats["observation.images.camera"]["count"] == [16]
    assert np.asarray(stats["observation.images.camera"]["max"]).reshape(3).tolist() == [1.0, 1.0, 1.0]


_ENCODE = """
import os, subprocess, sys
import numpy as np
from rose_usd.io.video import VideoWriter

os.environ["SVT_LOG"] = "1"
path, how = sys.argv[1], sys.argv[2]
frames = [np.full((32, 32, 3), 20 * i, np.uint8) for i in range(6)]
if how == "bare":  # PyAV alone, as lerobot's encoder calls it
    import av

    with av.open(path, mode="w") as container:
        stream = container.add_stream("libsvtav1", rate=30)
        stream.width = stream.height = 32
        stream.pix_fmt = "yuv420p"
        for rgb in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                container.mux(packet)
            realtime_while = os.sched_getscheduler(0) != os.SCHED_OTHER
        for packet in stream.encode():
            container.mux(packet)
else:
    with VideoWriter(path, 30, 32, 32) as writer:
        for rgb in frames:
            writer.write(rgb)
            realtime_while = os.sched_getscheduler(0) != os.SCHED_OTHER
threads = {int(tid): os.sched_getscheduler(int(tid)) for tid in os.listdir("/proc/self/task")}
policy = "import os; print(os.sched_getscheduler(0))"
child = subprocess.run([sys.executable, "-c", policy], capture_output=True, text=True)
print(int(realtime_while), int(any(p != os.SCHED_OTHER for p in threads.values())), child.stdout.strip())
"""


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="SVT-AV1 asks for real-time only as root")
def test_encoding_leaves_no_thread_real_time(tmp_path):
    """SVT-AV1 run as root makes the thread that opens it real-time (SCHED_FIFO 99), and every
    process started from it afterwards; spinning real-time threads on two cores stalled CI for
    many minutes. The writer puts every thread back, so a process started after it is normal."""
    run = lambda how: subprocess.run(  # noqa: E731
        [sys.executable, "-c", _ENCODE, str(tmp_path / f"{how}.mp4"), how], capture_output=True, text=True, timeout=300
    )
    bare = run("bare")
    assert bare.returncode == 0, bare.stderr
    assert bare.stdout.split()[0] == "1" and bare.stdout.split()[2] == str(os.SCHED_FIFO), bare.stdout  # the cause
    ours = run("writer")
    assert ours.returncode == 0, ours.stderr
    assert ours.stdout.split() == ["0", "0", str(os.SCHED_OTHER)], ours.stdout


def test_lerobot_tasks_read_with_pandas_as_lerobot_does(tmp_path):
    """meta/tasks.parquet gives the task texts as pandas' index, as lerobot's load_tasks reads it."""
    pd = pytest.importorskip("pandas")
    lerobot.write_dataset(tmp_path, _episodes(), FEATURES, fps=30, robot_type="panda")
    tasks = pd.read_parquet(tmp_path / "meta" / "tasks.parquet")
    assert list(tasks.index) == ["move the box", "lift the can"]
    assert int(tasks.loc["lift the can"].task_index) == 1


def test_robomimic_round_trip(tmp_path):
    """Demos, observation keys, attributes, env_args and the split masks read back."""
    rng = np.random.default_rng(1)
    demos = [
        robomimic.Demo(
            actions=rng.normal(size=(n, 9)),
            obs={"robot0_joint_pos": rng.normal(size=(n, 9)), "object": rng.normal(size=(n, 7))},
            states=rng.normal(size=(n, 25)),
            rewards=np.eye(n)[-1],
            dones=np.eye(n, dtype=np.uint8)[-1],
            attrs={"grasp": i},
        )
        for i, n in enumerate((6, 9))
    ]
    path = robomimic.write_hdf5(tmp_path / "d.hdf5", demos, {"env_name": "x", "type": "newton", "env_kwargs": {}})
    back, env_args = robomimic.read_hdf5(path)
    assert env_args["env_name"] == "x"
    for a, b in zip(demos, back, strict=True):
        np.testing.assert_allclose(b.actions, a.actions, rtol=1e-6)
        np.testing.assert_allclose(b.states, a.states)
        np.testing.assert_allclose(b.obs["object"], a.obs["object"], rtol=1e-6)
        assert b.dones[-1] == 1 and b.rewards[-1] == 1 and b.attrs["num_samples"] == len(a.actions)
        assert b.attrs["grasp"] == a.attrs["grasp"]
    import h5py

    with h5py.File(path) as f:
        assert f["data"].attrs["total"] == 15
        assert [n.decode() for n in f["mask/train"][()]] == ["demo_0", "demo_1"]
