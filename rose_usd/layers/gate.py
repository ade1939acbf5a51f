"""The gate layer's results (``/World/Gate``, ``RoseGateAPI``), read into a :class:`GateResult`."""

from __future__ import annotations

from dataclasses import dataclass

from pxr import Usd

from rose_usd.usd import paths, tokens


@dataclass(frozen=True)
class GateResult:
    """The quality gate of a stage: re-render SSIM against the video, the physics rest check, the
    track check (each object's re-render against its masks) and the collider check."""

    passed: bool
    ssim_mean: float
    ssim_min: float
    ssim_threshold: float
    rest_displacement_m: dict[str, float]
    """Per object: how far it moved in the rest check, the larger of its checks from its first and
    last resting frame (empty when the check did not run; without the objects resting in no frame)."""
    rest_frames: dict[str, list[int]]
    """Per object: the frames its rest checks started from."""
    not_resting: list[str]
    """Objects resting in no frame of the video (moved or touched in every one): not checked."""
    rest_threshold_m: float
    physics_passed: bool
    geometry_passed: bool
    geometry_report: str
    track_iou: dict[str, float]
    """Per object: mean IoU of its re-render with its masks (NaN without masked frames; empty when
    the check did not run)."""
    track_threshold: float
    track_window_iou: dict[str, float]
    """Per object: its lowest mean IoU over a window of the gate's ``track_window_s`` (NaN where
    no window held 3 rendered frames; empty in a gate layer without the window check)."""
    track_window_threshold: float

    def failures(self) -> list[str]:
        """What failed, one short phrase per check (empty when the gate passed)."""
        out = []
        if not self.ssim_mean >= self.ssim_threshold:
            out.append(f"SSIM {self.ssim_mean:.3f} under {self.ssim_threshold:.2f}")
        moved = {k: d for k, d in self.rest_displacement_m.items() if not d < self.rest_threshold_m}
        out += [f"{name} moved {_length(d)} in the rest check" for name, d in moved.items()]
        for name, iou in self.track_iou.items():
            window = self.track_window_iou.get(name, float("nan"))
            if iou < self.track_threshold:
                out.append(f"{name}'s re-render overlaps its masks by IoU {iou:.2f}")
            elif window < self.track_window_threshold:
                out.append(f"{name}'s re-render overlaps its masks by IoU {window:.2f} in its worst window")
        if not self.geometry_passed:
            out.append(f"colliders: {self.geometry_report}")
        return out

    def summary(self) -> str:
        rest = ", ".join(
            [
                f"{name} {1e3 * d:.2f} mm (frames {', '.join(map(str, self.rest_frames.get(name, [])))})"
                for name, d in self.rest_displacement_m.items()
            ]
            + [f"{name} rests in no frame" for name in self.not_resting]
        )
        low = {k: v for k, v in self.track_window_iou.items() if v < self.track_window_threshold}  # NaN: not low
        track = ", ".join(
            f"{name} {iou:.2f}" + (f" (worst window {low[name]:.2f})" if name in low else "")
            for name, iou in self.track_iou.items()
        )
        return (
            f"gate {'PASS' if self.passed else 'FAIL'}: SSIM {self.ssim_mean:.4f} (min {self.ssim_min:.4f}, "
            f"threshold {self.ssim_threshold:.2f}); rest {rest or 'not run'}; "
            f"track IoU {track or 'not run'}{f' (threshold {self.track_threshold:.2f})' if track else ''}; "
            f"colliders {'ok' if self.geometry_passed else self.geometry_report}"
        )


def read_gate(stage: Usd.Stage) -> GateResult | None:
    """The gate's results on a composed stage, None when the gate has not run."""
    prim = stage.GetPrimAtPath(paths.GATE)
    if not prim:
        return None

    def get(name: str):
        return prim.GetAttribute(name).Get()

    def per_object(name: str) -> dict[str, float]:
        """A float array of the track check, by the object names of rose:gate:track:objects."""
        return dict(zip(list(get(tokens.GATE_TRACK_OBJECTS) or []), [float(v) for v in get(name) or []]))

    ssim = prim.GetAttribute(tokens.GATE_SSIM)
    samples = [ssim.Get(t) for t in ssim.GetTimeSamples()]
    return GateResult(
        passed=bool(get(tokens.GATE_PASSED)),
        ssim_mean=float(get(tokens.GATE_SSIM_MEAN)),
        ssim_min=float(min(samples)) if samples else float("nan"),
        ssim_threshold=float(get(tokens.GATE_SSIM_THRESHOLD)),
        **_rest_checks(
            list(get(tokens.GATE_PHYSICS_OBJECTS) or []),
            [int(v) for v in get(tokens.GATE_PHYSICS_FRAMES) or []],
            [float(v) for v in get(tokens.GATE_PHYSICS_DISPLACEMENT) or []],
        ),
        not_resting=list(get(tokens.GATE_PHYSICS_NOT_RESTING) or []),
        rest_threshold_m=float(get(tokens.GATE_PHYSICS_THRESHOLD)),
        physics_passed=bool(get(tokens.GATE_PHYSICS_PASSED)),
        geometry_passed=bool(get(tokens.GATE_GEOMETRY_PASSED)),
        geometry_report=str(get(tokens.GATE_GEOMETRY_REPORT) or ""),
        track_iou=per_object(tokens.GATE_TRACK_IOU),
        track_threshold=float(get(tokens.GATE_TRACK_THRESHOLD) or 0.0),
        track_window_iou=per_object(tokens.GATE_TRACK_WINDOW_IOU),
        track_window_threshold=float(get(tokens.GATE_TRACK_WINDOW_THRESHOLD) or 0.0),
    )


def _length(metres: float) -> str:
    return (
        f"{metres:.2f} m" if metres >= 1 else f"{1e3 * metres:.0f} mm" if metres >= 0.01 else f"{1e3 * metres:.1f} mm"
    )


def _rest_checks(names: list[str], frames: list[int], displacement: list[float]) -> dict:
    """``rest_displacement_m`` (per object, its largest) and ``rest_frames`` from the gate's arrays
    (one entry per check; a gate layer without frames checked each object once, at frame 0)."""
    frames = frames if len(frames) == len(names) else [0] * len(names)
    worst: dict[str, float] = {}
    starts: dict[str, list[int]] = {}
    for name, t, d in zip(names, frames, displacement):
        worst[name] = max(worst.get(name, 0.0), d)
        starts.setdefault(name, []).append(t)
    return {"rest_displacement_m": worst, "rest_frames": starts}
