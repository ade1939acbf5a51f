"""Hands on a real video: how often the hand detector finds a hand, its time per frame, and a
contact sheet of the hand masks (green) and landmarks (red) every ``--every`` frames.

    python benchmarks/hands_sheet.py CASE -o sheet.png [--every 20] [--rotate180]

CASE is a case folder or a video file (``rose_usd.case.layout.load_case``)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from rose_usd import registry
from rose_usd.case.layout import load_case
from rose_usd.geometry.hands import HandDetector, hand_mask


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("case", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--every", type=int, default=20)
    parser.add_argument("--rotate180", action="store_true", help="the camera was mounted upside down")
    args = parser.parse_args()
    case = load_case(args.case, registry.STAGE_NAMES)
    found, times, tiles = 0, [], []
    with HandDetector(case.fps or 30.0) as detector:
        for t in range(case.n_frames):
            rgb = case.rgb(t)
            rgb = np.ascontiguousarray(rgb[::-1, ::-1]) if args.rotate180 else rgb
            t0 = time.perf_counter()
            hands = detector.detect(rgb, t)
            times.append(time.perf_counter() - t0)
            found += bool(hands)
            if t % args.every == 0:
                tile = rgb.copy()
                mask = hand_mask(hands, rgb.shape[:2])
                tile[mask] = (0.5 * tile[mask] + 0.5 * np.array([0, 255, 0])).astype(np.uint8)
                for hand in hands:
                    for x, y in np.round(hand.landmarks_px).astype(int):
                        cv2.circle(tile, (int(x), int(y)), 2, (255, 0, 0), -1)
                cv2.putText(tile, f"{t} ({len(hands)})", (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 0), 2)
                tiles.append(cv2.resize(tile, (320, int(320 * rgb.shape[0] / rgb.shape[1]))))
    cols = 4
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    sheet = np.vstack([np.hstack(tiles[i : i + cols]) for i in range(0, len(tiles), cols)])
    args.output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.output), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    summary = {
        "case": str(args.case),
        "frames": case.n_frames,
        "frames_with_a_hand": found,
        "ms_per_frame_median": round(1000 * float(np.median(times)), 1),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
