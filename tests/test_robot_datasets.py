"""LeRobot v3.0 and robomimic HDF5 writers: what is written reads back, in the fields the formats'
own loaders expect."""

import json

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
