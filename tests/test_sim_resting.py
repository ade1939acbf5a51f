"""Where the gate's rest check starts from (``sim.resting``): the frames an object is seen,
untouched and still; each object's first and last of them."""

from __future__ import annotations

import numpy as np

from rose_usd.layers.masks import INTERACTOR
from rose_usd.sim.resting import rest_checks, resting_runs, still_frames, still_from_start, untouched_frames

CUBE = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (0.0, 0.1)])


def _poses(xs: np.ndarray, yaw_deg: np.ndarray | None = None) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(xs), 1, 1))
    poses[:, 0, 3] = xs
    if yaw_deg is not None:
        a = np.radians(yaw_deg)
        poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a)
    return poses


def test_still_frames_are_those_no_corner_leaves_by_3_mm_into_or_out_of():
    xs = np.zeros(20)
    xs[8:12] = np.cumsum(np.full(4, 0.01))  # carried 1 cm a frame over frames 8-11, then set down
    xs[12:] = xs[11]
    still = still_frames(_poses(xs), CUBE)
    assert still.tolist() == [True] * 7 + [False] * 5 + [True] * 8
    # a turn moves the corners: 3 deg about the centre moves a corner 0.0707 m * 0.052 = 3.7 mm
    yaw = np.zeros(10)
    yaw[5:] = 3.0
    turned = still_frames(_poses(np.zeros(10), yaw), CUBE)
    assert turned.tolist() == [True] * 4 + [False] * 2 + [True] * 4


def test_runs_shorter_than_the_minimum_do_not_count():
    resting = np.array([1, 1, 0, 1, 1, 1, 0, 0, 1, 1, 1, 1], bool)
    assert resting_runs(resting, 3) == [(3, 5), (8, 11)]
    assert resting_runs(resting, 2) == [(0, 1), (3, 5), (8, 11)]
    assert resting_runs(np.zeros(5, bool), 1) == []


def test_each_object_is_checked_at_its_first_and_last_resting_frame():
    """At 30 fps a run counts from 5 frames (0.15 s). The Base rests throughout (one run: checked
    at its start), the Top is lifted off it over frames 10-29 and set down from 30 (checked where
    it first rests and where it was left); the Held one never rests; the others are set aside at a
    frame where they do not rest."""
    n = 40
    base = np.ones(n, bool)
    top = np.ones(n, bool)
    top[10:30] = False
    top[2] = False  # one frame touched: the first run is 3-9, not 0-1
    checks = rest_checks({"Base": base, "Top": top, "Held": np.zeros(n, bool)}, fps=30.0)
    assert [(c.frame, c.names, c.resting) for c in checks] == [
        (0, ("Base",), ("Base",)),
        (3, ("Top",), ("Base", "Top")),
        (39, ("Top",), ("Base", "Top")),
    ]
    # a run under the minimum is not resting for the others either
    short = np.zeros(n, bool)
    short[0:3] = True
    checks = rest_checks({"Base": base, "Blip": short}, fps=30.0)
    assert [(c.frame, c.resting) for c in checks] == [(0, ("Base",))]


class _Masks:
    """The two methods of ``layers.masks.Masks`` that ``untouched_frames`` reads, over arrays."""

    def __init__(self, tracks: dict[str, list[np.ndarray | None]]):
        self.tracks = tracks

    def has(self, name: str) -> bool:
        return name in self.tracks

    def mask(self, name: str, t: int) -> np.ndarray | None:
        return self.tracks[name][t]


def test_a_hand_within_1_percent_of_the_width_touches_and_an_unseen_object_does_not_rest():
    h, w = 100, 300  # the hand's mask is grown by 3 px
    obj = np.zeros((h, w), bool)
    obj[40:60, 100:140] = True

    def hand_at(x0: int) -> np.ndarray:
        m = np.zeros((h, w), bool)
        m[40:60, x0 : x0 + 20] = True
        return m

    tracks = {
        "Cup": [obj, obj, obj, np.zeros((h, w), bool), None],
        INTERACTOR: [hand_at(143), hand_at(142), None, None, None],
    }
    out = untouched_frames(_Masks(tracks), "Cup", 5)
    assert out.tolist() == [True, False, True, False, False]
    # without an interactor track, every frame with the object's mask is untouched
    assert untouched_frames(_Masks({"Cup": tracks["Cup"]}), "Cup", 5).tolist() == [True, True, True, False, False]


def test_still_from_start_ends_where_the_object_has_left_its_first_place():
    """A slow push (1 mm a frame: still frame to frame) leaves frame 0's place by 3 mm at frame 3."""
    xs = np.array([0.0, 0.0005, 0.0015, 0.0025, 0.0035, 0.0045, 0.0055, 0.0065])
    assert still_frames(_poses(xs), CUBE).all()
    assert still_from_start(_poses(xs), CUBE).tolist() == [True] * 4 + [False] * 4
    assert still_from_start(_poses(np.zeros(3)), CUBE).tolist() == [True] * 3


def test_true_runs_are_the_spans_of_consecutive_frames():
    from rose_usd.core.runs import true_runs

    assert true_runs(np.array([1, 1, 0, 1, 0, 0, 1], bool)) == [(0, 1), (3, 3), (6, 6)]
    assert true_runs(np.zeros(3, bool)) == [] and true_runs(np.ones(2, bool)) == [(0, 1)]


def test_the_rest_simulation_stops_at_rest_or_a_steady_creep_never_while_speeding_up():
    """``sim.rest._settled`` on corner histories checked every 0.01 s (a window: 10 checks), 0.75 s
    of a 1 s check left: still, creeping 0.077 mm a window at a steady pace (XPBD's mug) or slowing
    down, it has settled; creeping as fast as 0.1 mm a window, speeding up (tipping, sliding from
    rest, starting to move from still), or creeping steadily with 4.75 s left (a 5 s check: 3.7 mm
    more), it has not."""
    from rose_usd.sim.rest import CREEP_TOL_M, _settled

    def history(x_at):  # the cube's corners moved along x by x_at(check) [m], 30 checks
        return [{"Box": CUBE + [x_at(k), 0.0, 0.0]} for k in range(30)]

    assert _settled(history(lambda k: 0.0), 10, 7.5)
    assert _settled(history(lambda k: 7.7e-6 * k), 10, 7.5)
    assert _settled(history(lambda k: 3e-4 * (1 - 0.97**k)), 10, 7.5)  # slowing: 60 then 44 um a window
    assert not _settled(history(lambda k: 7.7e-6 * k), 10, 47.5)
    assert not _settled(history(lambda k: 0.0), 15, 7.5)  # not two windows seen yet
    assert not _settled(history(lambda k: 1.05 * CREEP_TOL_M / 10 * k), 10, 7.5)
    assert not _settled(history(lambda k: 2e-5 * 2 ** (k / 10)), 10, 7.5)  # 37 then 75 um a window: tipping
    assert not _settled(history(lambda k: 1e-7 * k**2), 10, 7.5)  # sliding from rest: 28 then 48 um a window
    assert not _settled(history(lambda k: 5e-6 * max(0, k - 19)), 10, 7.5)  # still, then 50 um a window
    two = [{"Box": h["Box"], "Can": CUBE + [2e-6 * k**2, 0.0, 0.0]} for k, h in enumerate(history(lambda k: 0.0))]
    assert not _settled(two, 10, 7.5)  # one object still, the other speeding up
