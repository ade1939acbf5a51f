"""Load the rose_usd-written LeRobot v3.0 dataset with the real lerobot package and compare values.

Run from the repo root on the device:  python .lerobot-check/check.py
"""

import json
import os
import sys
import time
import traceback

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "dataset")
REPO_ID = "rose/check"
EXP = json.load(open(os.path.join(HERE, "expected.json")))
CAM = "observation.images.camera"

import numpy as np  # noqa: E402

REF = dict(np.load(os.path.join(HERE, "ref_frames.npz")))  # local PyAV rgb24 CHW uint8 frames 0, 97, 100


def step(name):
    print(f"\n===== {name} =====", flush=True)


def tb(name):
    print(f"!!!!! FAILED: {name}", flush=True)
    traceback.print_exc(file=sys.stdout)
    sys.stdout.flush()


def describe(v):
    try:
        import torch

        if isinstance(v, torch.Tensor):
            return f"Tensor{tuple(v.shape)} {v.dtype}"
    except Exception:
        pass
    return f"{type(v).__name__}: {v!r}"[:120]


def img_report(label, t, ref_key=None, expected_mean=None):
    a = t.detach().cpu().float().numpy()
    print(f"{label}: shape={a.shape} dtype={t.dtype} min={a.min():.4f} max={a.max():.4f}")
    mean255 = (a.reshape(a.shape[0], -1).mean(1) * 255).tolist()
    print(f"{label}: per-channel mean*255 = {mean255}")
    if expected_mean is not None:
        print(
            f"{label}: expected mean_rgb = {expected_mean}  max|diff| = "
            f"{max(abs(x - y) for x, y in zip(mean255, expected_mean)):.6f}"
        )
    if ref_key is not None:
        ref = REF[ref_key].astype(np.float32)
        diff = np.abs(a * 255 - ref)
        print(f"{label}: vs local PyAV {ref_key}: max|diff|={diff.max():.4f} mean|diff|={diff.mean():.6f}")
        for k, r in REF.items():
            print(f"   (mean|diff| vs {k} = {np.abs(a * 255 - r.astype(np.float32)).mean():.4f})")


def compare_vec(label, t, expected):
    a = t.detach().cpu().numpy().astype(np.float64)
    e = np.asarray(expected, dtype=np.float64)
    print(f"{label}: got={a.tolist()}")
    print(f"{label}: exp={e.tolist()}")
    print(f"{label}: shape={a.shape} max|diff|={np.abs(a - e).max():.3e}")


step("environment")
import importlib.metadata as md  # noqa: E402

print("python", sys.version)
for p in [
    "torch",
    "torchvision",
    "lerobot",
    "datasets",
    "huggingface_hub",
    "av",
    "torchcodec",
    "pyarrow",
    "pandas",
    "numpy",
    "fsspec",
    "draccus",
    "gymnasium",
]:
    try:
        print(f"  {p}=={md.version(p)}")
    except Exception as e:  # noqa: BLE001
        print(f"  {p}: not installed ({e})")

step("import lerobot")
try:
    t0 = time.time()
    import lerobot
    from lerobot.datasets.dataset_metadata import CODEBASE_VERSION, LeRobotDatasetMetadata
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    print("lerobot", lerobot.__version__, "CODEBASE_VERSION", CODEBASE_VERSION, f"import {time.time() - t0:.1f}s")
except Exception:
    tb("import lerobot")
    sys.exit(1)

step("LeRobotDatasetMetadata")
try:
    meta = LeRobotDatasetMetadata(REPO_ID, root=ROOT)
    print(
        "fps",
        meta.fps,
        "total_episodes",
        meta.total_episodes,
        "total_frames",
        meta.total_frames,
        "total_tasks",
        meta.total_tasks,
        "robot_type",
        meta.robot_type,
    )
    print("features", list(meta.features))
    print("video_keys", meta.video_keys, "camera_keys", meta.camera_keys)
    print("tasks\n", meta.tasks)
    ep = meta.episodes[0]
    print("episode 0:", {k: v for k, v in ep.items() if not k.startswith("stats/")})
    print(
        "video path ep0:",
        meta.get_video_file_path(0, CAM),
        os.path.exists(os.path.join(ROOT, str(meta.get_video_file_path(0, CAM)))),
    )
    print("data path ep0:", meta.get_data_file_path(0))
    print("stats keys", list(meta.stats))
    print("stats camera mean", np.asarray(meta.stats[CAM]["mean"]).tolist())
except Exception:
    tb("LeRobotDatasetMetadata")


def check_dataset(backend):
    step(f"LeRobotDataset video_backend={backend!r}")
    try:
        t0 = time.time()
        kw = {} if backend is None else {"video_backend": backend}
        ds = LeRobotDataset(REPO_ID, root=ROOT, **kw)
        used = getattr(ds, "video_backend", getattr(ds, "_video_backend", "?"))
        print(f"constructed in {time.time() - t0:.1f}s; ds.video_backend={used}")
        print("len(ds)", len(ds), "num_episodes", ds.num_episodes, "num_frames", ds.num_frames, "fps", ds.fps)
        print("meta.fps", ds.meta.fps, "total_episodes", ds.meta.total_episodes, "total_frames", ds.meta.total_frames)
        print("features", list(ds.meta.features))
    except Exception:
        tb(f"construct backend={backend}")
        return None
    try:
        it0 = ds[0]
        print("ds[0] keys:", list(it0))
        for k, v in it0.items():
            print(f"   {k}: {describe(v)}")
        compare_vec("state[0]", it0["observation.state"], EXP["state_frame0"])
        print("task[0]", repr(it0.get("task")), "expected", EXP["tasks"])
        img_report("ds[0] camera", it0[CAM], ref_key="f0")
    except Exception:
        tb("ds[0]")
    try:
        it10 = ds[10]
        compare_vec("action[10]", it10["action"], EXP["action_frame10"])
    except Exception:
        tb("ds[10]")
    try:
        t0 = time.time()
        it100 = ds[100]
        print(f"ds[100] ({time.time() - t0:.2f}s) keys:", list(it100))
        print("ds[100] timestamp", it100["timestamp"], "frame_index", it100["frame_index"], "index", it100["index"])
        img_report("ds[100] camera", it100[CAM], ref_key="f100", expected_mean=EXP["video_frame100_mean_rgb"])
    except Exception:
        tb("ds[100]")
    try:
        last = ds[len(ds) - 1]
        print("ds[-1] timestamp", last["timestamp"], "camera", describe(last[CAM]))
    except Exception:
        tb("ds[last]")
    return ds


def check_delta(backend):
    step(f"delta_timestamps {{camera: [-0.1, 0.0]}} backend={backend!r}")
    try:
        kw = {} if backend is None else {"video_backend": backend}
        ds = LeRobotDataset(REPO_ID, root=ROOT, delta_timestamps={CAM: [-0.1, 0.0]}, **kw)
        it = ds[100]
        print("ds[100] keys:", list(it))
        v = it[CAM]
        print("camera", describe(v), "pad", it.get(f"{CAM}_is_pad"))
        img_report("delta ds[100][0] (t-0.1 -> frame 97)", v[0], ref_key="f97")
        img_report(
            "delta ds[100][1] (t -> frame 100)", v[1], ref_key="f100", expected_mean=EXP["video_frame100_mean_rgb"]
        )
        it0 = ds[0]
        print("ds[0] camera", describe(it0[CAM]), "pad", it0.get(f"{CAM}_is_pad"))
        img_report("delta ds[0][1] (frame 0)", it0[CAM][1], ref_key="f0")
    except Exception:
        tb(f"delta backend={backend}")


check_dataset("pyav")
check_delta("pyav")

step("torchcodec")
tc_ok = False
try:
    import torchcodec  # noqa: F401
    from torchcodec.decoders import VideoDecoder  # noqa: F401

    print("torchcodec import OK", torchcodec.__version__)
    tc_ok = True
except Exception:
    tb("import torchcodec")
if tc_ok:
    from lerobot.utils.import_utils import get_safe_default_video_backend

    print("default backend:", get_safe_default_video_backend())
    check_dataset(None)
    check_delta(None)
print("\nDONE", flush=True)
