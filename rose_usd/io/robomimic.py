"""robomimic-style HDF5 demonstrations (h5py), as robomimic's dataset loader reads them:

```
data                      attrs: total (frames), env_args (JSON: env_name, type, env_kwargs)
data/demo_<i>             attrs: num_samples
data/demo_<i>/actions     (T, A) float32
data/demo_<i>/obs/<key>   (T, ...) float32, one dataset per observation key
data/demo_<i>/states      (T, S) float64, the simulator state to reset to
data/demo_<i>/rewards     (T,) float32
data/demo_<i>/dones       (T,) uint8
mask/train, mask/valid    names of the demos in each split (bytes)
```
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Demo:
    """One demonstration: per-frame arrays."""

    actions: np.ndarray
    obs: dict[str, np.ndarray]
    states: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    attrs: dict = field(default_factory=dict)


def write_hdf5(path: Path, demos: list[Demo], env_args: dict, *, valid_every: int = 10) -> Path:
    """Write ``demos`` to ``path``; every ``valid_every``-th demo goes to the valid split (none when
    there are fewer)."""
    import h5py

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = [f"demo_{i}" for i in range(len(demos))]
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        total = 0
        for name, demo in zip(names, demos, strict=True):
            g = data.create_group(name)
            g.create_dataset("actions", data=np.asarray(demo.actions, np.float32))
            g.create_dataset("states", data=np.asarray(demo.states, np.float64))
            g.create_dataset("rewards", data=np.asarray(demo.rewards, np.float32))
            g.create_dataset("dones", data=np.asarray(demo.dones, np.uint8))
            obs = g.create_group("obs")
            for key, values in demo.obs.items():
                obs.create_dataset(key, data=np.asarray(values, np.float32))
            g.attrs["num_samples"] = len(demo.actions)
            for key, value in demo.attrs.items():
                g.attrs[key] = value
            total += len(demo.actions)
        data.attrs["total"] = total
        data.attrs["env_args"] = json.dumps(env_args)
        valid = [n for i, n in enumerate(names) if len(names) >= valid_every and i % valid_every == valid_every - 1]
        train = [n for n in names if n not in valid]
        mask = f.create_group("mask")
        mask.create_dataset("train", data=np.array(train, dtype="S"))
        mask.create_dataset("valid", data=np.array(valid, dtype="S"))
    return path


def read_hdf5(path: Path) -> tuple[list[Demo], dict]:
    """Read demonstrations back (in demo order) and the env_args."""
    import h5py

    with h5py.File(path, "r") as f:
        data = f["data"]
        names = sorted(data.keys(), key=lambda n: int(n.split("_")[1]))
        demos = []
        for name in names:
            g = data[name]
            demos.append(
                Demo(
                    actions=g["actions"][()],
                    obs={k: g["obs"][k][()] for k in g["obs"]},
                    states=g["states"][()],
                    rewards=g["rewards"][()],
                    dones=g["dones"][()],
                    attrs=dict(g.attrs),
                )
            )
        return demos, json.loads(data.attrs["env_args"])
