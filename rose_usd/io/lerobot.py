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
videos/<key>/chunk-000/file-000.mp4          per camera stream: every episode's frames one after
                                             the other (AV1, ``rose_usd.io.video``); the episode
                                             rows hold videos/<key>/{chunk_index, file_index,
                                             from_timestamp, to_timestamp} and its image stats
```

A feature of shape (1,) is a plain column; a vector one a fixed-size list. Stats are over all
frames (lerobot aggregates per-episode stats; its quantiles are then weighted means of the
episodes', ours are exact). Load the result with
``LeRobotDataset(repo_id="rose/<name>", root="<out>/dataset/lerobot")``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rose_usd.io import video

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
    """One episode: per-frame arrays for every feature (T, n), its task text and, per camera
    stream, its T frames ((H, W, 3) uint8 sRGB; an iterable, so a renderer can hand them over one
    at a time)."""

    task: str
    data: dict[str, np.ndarray]
    videos: dict[str, Iterable[np.ndarray]] = field(default_factory=dict)

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


def _video_feature(height: int, width: int, fps: int) -> dict:
    """info.json's entry of a camera stream, as lerobot writes it for an encoded video."""
    return {
        "dtype": "video",
        "shape": [height, width, 3],
        "names": ["height", "width", "channels"],
        "info": {
            "video.height": height,
            "video.width": width,
            "video.codec": video.CODEC_NAME,
            "video.pix_fmt": video.PIX_FMT,
            "video.is_depth_map": False,
            "video.fps": int(fps),
            "video.channels": 3,
            "has_audio": False,
        },
    }


class _ImageStats:
    """Per-channel statistics of a stream's frames as lerobot keeps them for images: values in
    [0, 1], each of shape (3, 1, 1); exact, from 256-bin histograms."""

    def __init__(self):
        self.hist = np.zeros((3, 256), np.int64)
        self.frames = 0

    def add(self, rgb: np.ndarray) -> None:
        for c in range(3):
            self.hist[c] += np.bincount(rgb[..., c].ravel(), minlength=256)
        self.frames += 1

    def merged(self, other: _ImageStats) -> _ImageStats:
        out = _ImageStats()
        out.hist, out.frames = self.hist + other.hist, self.frames + other.frames
        return out

    def as_dict(self) -> dict[str, list]:
        levels = np.arange(256) / 255.0
        total = self.hist.sum(axis=1)
        mean = (self.hist * levels).sum(axis=1) / total
        std = np.sqrt(np.maximum((self.hist * levels**2).sum(axis=1) / total - mean**2, 0.0))
        cdf = np.cumsum(self.hist, axis=1) / total[:, None]
        shaped = lambda v: [[[float(x)]] for x in v]  # noqa: E731
        out = {
            "min": shaped([levels[np.flatnonzero(h)[0]] for h in self.hist]),
            "max": shaped([levels[np.flatnonzero(h)[-1]] for h in self.hist]),
            "mean": shaped(mean),
            "std": shaped(std),
            "count": [int(self.frames)],
        }
        for q in QUANTILES:
            out[f"q{int(round(q * 100)):02d}"] = shaped([levels[np.searchsorted(c, q)] for c in cdf])
        return out


def _write_videos(root: Path, episodes: list[Episode], videos: dict[str, tuple[int, int]], fps: int, rows: list[dict]):
    """Encode every stream's episodes one after the other into its file; add each episode's
    place in it and its image stats to its row. Returns the streams' stats over all frames."""
    totals = {}
    for key, (height, width) in videos.items():
        total = _ImageStats()
        path = root / VIDEO_PATH.format(video_key=key, chunk_index=0, file_index=0)
        with video.VideoWriter(path, fps, width, height) as writer:
            for e, (ep, row) in enumerate(zip(episodes, rows, strict=True)):
                first, stats = writer.frames, _ImageStats()
                for rgb in ep.videos[key]:
                    writer.write(rgb)
                    stats.add(rgb)
                if writer.frames - first != ep.length:
                    raise ValueError(f"episode {e}: {writer.frames - first} frames of {key}, not {ep.length}")
                row[f"videos/{key}/chunk_index"] = 0
                row[f"videos/{key}/file_index"] = 0
                row[f"videos/{key}/from_timestamp"] = first / fps
                row[f"videos/{key}/to_timestamp"] = writer.frames / fps
                for stat, value in stats.as_dict().items():
                    row[f"stats/{key}/{stat}"] = value
                total = total.merged(stats)
        totals[key] = total.as_dict()
    return totals


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
        "video_path": VIDEO_PATH if any(f["dtype"] == "video" for f in features.values()) else None,
        "features": features,
    }


def write_dataset(
    root: Path,
    episodes: list[Episode],
    features: dict[str, Feature],
    *,
    fps: int,
    robot_type: str,
    videos: dict[str, tuple[int, int]] | None = None,
) -> Path:
    """Write a LeRobot v3.0 dataset of ``episodes`` into ``root`` (one data and one episodes file,
    and one video file per camera stream of ``videos``: key -> (height, width)).

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

    video_stats = _write_videos(root, episodes, videos or {}, fps, episode_rows)
    for key, (height, width) in (videos or {}).items():
        all_features[key] = _video_feature(height, width, fps)

    episodes_file = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    episodes_file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), episodes_file, compression="snappy")
    _write_tasks(root / TASKS_PATH, tasks)

    total = int(start)
    info = _info(robot_type, len(episodes), total, len(tasks), fps, all_features)
    info_file = root / "meta" / "info.json"
    info_file.write_text(json.dumps(info, indent=4) + "\n")
    stats = {name: _stats(values) for name, values in merged.items()}
    stats.update(video_stats)
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
