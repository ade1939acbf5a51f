"""The batched collect path (every rollout its own world, stepped together; the GPU's): the
perturbation of an object's start pose, the choice of device, and, in the benchmark job, the same
grasps succeeding batched (mujoco_warp on the CPU) as one after another (MuJoCo's C backend)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from test_collect import _collect, _shrink_object

from rose_usd.collect import batch, newton_backend
from rose_usd.collect.config import CollectConfig, NewtonConfig, SimDevice
from rose_usd.collect.rollout import FLUNG_M, Perturbation, diverged, perturbed_pose, pose7_to_matrix
from rose_usd.core import se3
from rose_usd.errors import ConfigError
from rose_usd.layers.robot import read_collect
from rose_usd.usd.stage import open_stage


def test_a_perturbation_turns_the_object_about_up_and_shifts_it():
    """A start pose (x y z, quaternion xyzw) moved by (3, -2, 0) mm and turned 4 deg about world up
    keeps its tilt and height, and its yaw grows by 4 deg."""
    tilt = se3.make_pose(se3.rotation_about([1.0, 0.0, 0.0], np.radians(10.0)), [0.1, 0.2, 0.05])
    q7 = np.concatenate([tilt[:3, 3], se3.quat_xyzw_from_matrix(tilt[:3, :3])])
    moved = pose7_to_matrix(perturbed_pose(q7, Perturbation(np.array([0.003, -0.002, 0.0]), 4.0, 0.3, 0.5)))
    np.testing.assert_allclose(moved[:3, 3], [0.103, 0.198, 0.05], atol=1e-12)
    np.testing.assert_allclose(
        moved[:3, :3], se3.rotation_about([0, 0, 1.0], np.radians(4.0)) @ tilt[:3, :3], atol=1e-9
    )


def test_a_body_not_finite_or_flung_means_the_simulation_diverged():
    """Ticks (3) of worlds (2) of bodies (2): a NaN anywhere, or a body past FLUNG_M, is divergence;
    both the serial rollout and the batch judge by it."""
    q = np.zeros((3, 2, 2, 7))
    q[..., 6] = 1.0
    q[1, 0, 1, 3] = np.nan
    q[2, 1, 0, 0] = -1.5 * FLUNG_M
    np.testing.assert_array_equal(diverged(q), [[False, False], [True, False], [False, True]])


def test_the_device_is_the_cpu_without_a_gpu_and_cuda_asked_for_is_an_error():
    """auto runs one world after another where Warp sees no CUDA device; cuda asked for there is
    a one-line configuration error, not a crash."""
    if batch.cuda_available():
        pytest.skip("this machine has a CUDA device")
    assert newton_backend._device(CollectConfig()) == ("cpu", False)
    with pytest.raises(ConfigError, match="no CUDA device"):
        newton_backend._device(CollectConfig(newton=NewtonConfig(device=SimDevice.CUDA)))


@pytest.mark.slow
def test_batched_rollouts_carry_the_box_as_the_serial_ones_do(monkeypatch, tmp_path, oracle_out, sample_case):
    """The sample's box at 3/4 size, 2 grasps as reconstructed: every rollout succeeds one after
    another on MuJoCo's C backend and as two worlds stepped together on mujoco_warp (on the CPU
    here), and the batch's robot layer has the best rollout's links from forward kinematics."""
    out = tmp_path / "out"
    shutil.copytree(oracle_out, out)
    _shrink_object(out, 0.75)
    serial = _collect(sample_case, out, grasps=2, perturbations=1)
    monkeypatch.setattr(newton_backend, "_device", lambda cfg: ("cpu", True))
    batched = _collect(sample_case, out, grasps=2, perturbations=1, task="batched")
    assert serial.successes == serial.rollouts == 2
    assert batched.successes == batched.rollouts == 2
    stage = open_stage(out / "rose.usda")
    hand = next(p for p in stage.Traverse() if p.GetName() == "panda_hand")
    assert any(a.GetNumTimeSamples() > 0 for a in hand.GetAttributes() if a.GetName().startswith("xformOp"))
    assert read_collect(stage).best_rollout >= 0
