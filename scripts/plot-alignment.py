"""A picture of a dataset's demonstrations before and after alignment by gripper events
(`cnfmp.core.alignment`, what `cnfmp train` does unless --no-time-alignment): the gripper
opening and the height of every demonstration against time, as recorded (left) and aligned
(right), the median event times marked.

    .venv/bin/python scripts/plot-alignment.py --dataset DIR --out alignment.png [--camera KEY]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from cnfmp.core.alignment import align_demonstrations
from cnfmp.core.data import RecordingOptions, load_demonstrations

PANEL_W, PANEL_H, MARGIN = 520, 180, 40
COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
           (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def panel(curves: list[np.ndarray], fps: float, duration: float, low: float, high: float, title: str,
          marks: list[float]) -> np.ndarray:
    """One white panel with each (T,) curve against time (s) over [0, duration], values in [low, high]."""
    image = np.full((PANEL_H + 2 * MARGIN, PANEL_W + 2 * MARGIN, 3), 255, np.uint8)
    cv2.rectangle(image, (MARGIN, MARGIN), (MARGIN + PANEL_W, MARGIN + PANEL_H), (0, 0, 0), 1)
    for mark in marks:
        x = MARGIN + int(mark / duration * PANEL_W)
        cv2.line(image, (x, MARGIN), (x, MARGIN + PANEL_H), (200, 200, 200), 1)
    for k, curve in enumerate(curves):
        t = np.arange(len(curve)) / fps
        x = MARGIN + t / duration * PANEL_W
        y = MARGIN + PANEL_H - (curve - low) / max(high - low, 1e-9) * PANEL_H
        points = np.stack([x, y], axis=1).round().astype(np.int32)
        cv2.polylines(image, [points], False, COLOURS[k % len(COLOURS)][::-1], 1, cv2.LINE_AA)
    cv2.putText(image, title, (MARGIN, MARGIN - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(image, f"0 .. {duration:.1f} s", (MARGIN, MARGIN + PANEL_H + 22), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (0, 0, 0), 1, cv2.LINE_AA)
    return image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", required=True, help="LeRobot dataset with coarse masks")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--camera", default=None)
    args = parser.parse_args()
    demos = load_demonstrations(args.dataset, RecordingOptions(camera=args.camera))
    aligned, report = align_demonstrations(demos.trajectories, demos.fps, poses=not demos.joint_names)
    duration = max(max(len(t) for t in demos.trajectories), max(len(t) for t in aligned)) / demos.fps
    # The second row: the height, or for a joint-space recording its second joint (a lift).
    second, label = (1, demos.joint_names[1 % len(demos.joint_names)]) if demos.joint_names else (2, "height z (m)")
    values = np.concatenate([t[:, second] for t in demos.trajectories])
    marks = report.groups[report.majority]["event_times_s"]
    rows = []
    for name, column, low, high in (("gripper", -1, -0.05, 1.05), (label, second, values.min(), values.max())):
        rows.append(np.concatenate([
            panel([t[:, column] for t in demos.trajectories], demos.fps, duration, low, high, f"{name}, as recorded", []),
            panel([t[:, column] for t in aligned], demos.fps, duration, low, high, f"{name}, aligned", marks)], axis=1))
    picture = np.concatenate(rows)
    caption = np.full((30, picture.shape[1], 3), 255, np.uint8)
    cv2.putText(caption, report.describe()[:150], (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.imwrite(args.out, np.concatenate([picture, caption]))
    print(report.describe())


if __name__ == "__main__":
    main()
