"""LeRobot v3.0 datasets, written with pyarrow (the ``lerobot`` package needs torch and Python
>= 3.12). The layout and field names follow lerobot's ``datasets/utils.py`` and
``lerobot_dataset.py`` (v3.0, lerobot 0.4):

```
meta/info.json                               codebase_version "v3.0", fps, features, totals, paths
meta/stats.json                              per feature: min, max, mean, std, count, q01 q10 q50 q90 q99
meta/tasks.parquet                           index: the task text; column task_index
meta/episodes/chunk-000/file-000.parquet     one row per episode: episode_index, tasks, length,
                                             data/chunk_index, data/file_index, dataset_from_index,
                                             dataset_to_index, meta/episodes/chunk_index,
                                             meta/episodes/file_index, stats/<feature>/<stat>
data/chunk-000/file-000.parquet              one row per frame: the features, plus timestamp,
                                             frame_index, episode_index, index, task_index
```

A feature of shape (1,) is a plain column; a vector one a fixed-size list. Stats are over all
frames (lerobot aggregates per-episode stats; its quantiles are then weighted means of the
episodes', ours are exact). Load the result with
``LeRobotDataset(repo_id="rose/<name>", root="<out>/dataset/lerobot")``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
TASKS_PATH = "meta/tasks.parquet"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
DEFAULT_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}


@dataclass(frozen=True)
class Feature:
    """A per-frame feature: its dtype (``float32``, ``int64``, ``bool``) and element names."""

    dtype: str
    names: tuple[str, ...]

    @property
    def shape(self) -> list[int]:
        return [len(self.names)]


@dataclass(frozen=True)
class Episode:
    """One episode: per-frame arrays for every feature (T, n) and its task text."""

    task: str
    data: dict[str, np.ndarray]

    @property
    def length(self) -> int:
        return len(next(iter(self.data.values())))


def _stats(values: np.ndarray) -> dict[str, list]:
    values = np.asarray(values, dtype=float)
    out = {
        "min": values.min(axis=0).tolist(),
        "max": values.max(axis=0).tolist(),
        "mean": values.mean(axis=0).tolist(),
        "std": values.std(axis=0).tolist(),
        "count": [int(len(values))],
    }
    for q in QUANTILES:
        out[f"q{int(round(q * 100)):02d}"] = np.quantile(values, q, axis=0).tolist()
    return out


def _column(values: np.ndarray, dtype: str, width: int | None):
    import pyarrow as pa

    kind = {"float32": pa.float32(), "float64": pa.float64(), "int64": pa.int64(), "bool": pa.bool_()}[dtype]
    values = np.asarray(values)
    if width is None:
        return pa.array(values.reshape(-1).astype(kind.to_pandas_dtype()), type=kind)
    flat = pa.array(values.reshape(-1).astype(kind.to_pandas_dtype()), type=kind)
    return pa.FixedSizeListArray.from_arrays(flat, width)


def _episode_row(e: int, task: str, start: int, n: int, columns: dict[str, list]) -> dict:
    """The episodes-table row of episode ``e`` (frames ``start`` to ``start + n``), with the stats of
    each column's last part (that episode's frames)."""
    stats = {name: _stats(parts[-1]) for name, parts in columns.items()}
    row = {
        "episode_index": e,
        "tasks": [task],
        "length": n,
        "data/chunk_index": 0,
        "data/file_index": 0,
        "dataset_from_index": start,
        "dataset_to_index": start + n,
    }
    for name, st in stats.items():
        for key, value in st.items():
            row[f"stats/{name}/{key}"] = value
    row["meta/episodes/chunk_index"] = 0
    row["meta/episodes/file_index"] = 0
    return row


def _episode_columns(
    episodes: list[Episode], features: dict[str, Feature], tasks: list[str], fps: int
) -> tuple[dict[str, list], list[dict], int]:
    """The frame columns as one (T, n) array per episode and column, the episodes-table rows, and the
    number of frames."""
    columns: dict[str, list] = {name: [] for name in list(features) + list(DEFAULT_FEATURES)}
    episode_rows: list[dict] = []
    start = 0
    for e, ep in enumerate(episodes):
        n = ep.length
        for name in features:
            values = np.asarray(ep.data[name])
            if values.shape != (n, len(features[name].names)):
                raise ValueError(
                    f"episode {e}: feature {name} has shape {values.shape}, not {(n, len(features[name].names))}"
                )
            columns[name].append(values)
        extra = {
            "timestamp": (np.arange(n) / fps).astype(np.float32),
            "frame_index": np.arange(n),
            "episode_index": np.full(n, e),
            "index": start + np.arange(n),
            "task_index": np.full(n, tasks.index(ep.task)),
        }
        for name, values in extra.items():
            columns[name].append(values[:, None])
        episode_rows.append(_episode_row(e, ep.task, start, n, columns))
        start += n
    return columns, episode_rows, start


def _info(robot_type: str, episodes: int, frames: int, tasks: int, fps: int, features: dict) -> dict:
    """meta/info.json's content."""
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": episodes,
        "total_frames": frames,
        "total_tasks": tasks,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "fps": int(fps),
        "splits": {"train": f"0:{episodes}"},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": features,
    }


def write_dataset(
    root: Path, episodes: list[Episode], features: dict[str, Feature], *, fps: int, robot_type: str
) -> Path:
    """Write a LeRobot v3.0 dataset of ``episodes`` into ``root`` (one data and one episodes file).

    Returns:
        The path of meta/info.json.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    root = Path(root)
    tasks: list[str] = []
    for ep in episodes:
        if ep.task not in tasks:
            tasks.append(ep.task)
    columns, episode_rows, start = _episode_columns(episodes, features, tasks, fps)

    merged = {name: np.concatenate(parts) for name, parts in columns.items()}
    all_features = {name: {"dtype": f.dtype, "shape": f.shape, "names": list(f.names)} for name, f in features.items()}
    all_features.update(DEFAULT_FEATURES)
    arrays, names = [], []
    for name, spec in all_features.items():
        width = None if spec["shape"] == [1] else spec["shape"][0]
        arrays.append(_column(merged[name], spec["dtype"], width))
        names.append(name)
    data_file = root / DATA_PATH.format(chunk_index=0, file_index=0)
    data_file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_arrays(arrays, names=names), data_file, compression="snappy")

    episodes_file = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    episodes_file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), episodes_file, compression="snappy")
    _write_tasks(root / TASKS_PATH, tasks)

    total = int(start)
    info = _info(robot_type, len(episodes), total, len(tasks), fps, all_features)
    info_file = root / "meta" / "info.json"
    info_file.write_text(json.dumps(info, indent=4) + "\n")
    stats = {name: _stats(values) for name, values in merged.items()}
    (root / "meta" / "stats.json").write_text(json.dumps(stats, indent=4) + "\n")
    return info_file


def _write_tasks(path: Path, tasks: list[str]) -> None:
    """meta/tasks.parquet as ``pandas.DataFrame({"task_index": ...}, index=tasks).to_parquet()``
    writes it (pandas is not needed to write it): the index column carries pandas' metadata so
    ``pd.read_parquet`` gives the task texts as the index."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()), "__index_level_0__": pa.array(tasks)})
    pandas_meta = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [
            {"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object", "metadata": None}
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": None,
                "field_name": "__index_level_0__",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.0.0",
    }
    table = table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)


def read_dataset(root: Path) -> tuple[dict, dict[str, np.ndarray], list[dict], list[str]]:
    """Read a dataset back: info, the frame columns as arrays (N, ...) , the episode rows and the tasks."""
    import pyarrow.parquet as pq

    root = Path(root)
    info = json.loads((root / "meta" / "info.json").read_text())
    table = pq.read_table(root / DATA_PATH.format(chunk_index=0, file_index=0))
    frames = {}
    for name in table.column_names:
        column = table.column(name).combine_chunks()
        if hasattr(column, "flatten") and hasattr(column.type, "list_size"):
            frames[name] = np.asarray(column.flatten()).reshape(len(column), column.type.list_size)
        else:
            frames[name] = np.asarray(column)
    episodes = pq.read_table(root / EPISODES_PATH.format(chunk_index=0, file_index=0)).to_pylist()
    tasks_table = pq.read_table(root / TASKS_PATH)
    order = np.argsort(np.asarray(tasks_table.column("task_index")))
    tasks = [tasks_table.column("__index_level_0__")[int(i)].as_py() for i in order]
    return info, frames, episodes, tasks
