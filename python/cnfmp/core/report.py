"""Pictures for benchmark reports, drawn with OpenCV (no plotting library in the venv).

:func:`table_chart` draws the Table-I comparison: one panel of MED (cm) and one of success
rate, each with a group of bars per task and one bar per method. :func:`curve_chart` draws
the data-efficiency benchmark: success and MED against the number of demonstrations, one
line per task.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np

#: Bar colours (RGB) for up to 8 methods, distinguishable in print.
PALETTE = [(141, 160, 203), (102, 194, 165), (252, 141, 98), (231, 138, 195), (40, 90, 160),
           (166, 216, 84), (255, 217, 47), (179, 179, 179)]
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _text(canvas, text, origin, scale=0.45, colour=(30, 30, 30), thickness=1):
    cv2.putText(canvas, text, (int(origin[0]), int(origin[1])), FONT, scale, colour, thickness, cv2.LINE_AA)


def _panel(canvas, top, height, left, width, title, values, tasks, methods, top_value, fmt):
    """One bar panel: values[(method, task)] -> number (NaN/None = no bar)."""
    bottom = top + height
    _text(canvas, title, (left, top - 10), 0.55, thickness=1)
    for k in range(5):  # horizontal grid with labels
        y = bottom - k / 4 * height
        cv2.line(canvas, (left, int(y)), (left + width, int(y)), (225, 225, 225), 1)
        _text(canvas, fmt(top_value * k / 4), (left - 48, y + 4), 0.38)
    cv2.line(canvas, (left, bottom), (left + width, bottom), (60, 60, 60), 1)
    group = width / len(tasks)
    bar = group * 0.8 / len(methods)
    for t, task in enumerate(tasks):
        x0 = left + t * group + group * 0.1
        for m, method in enumerate(methods):
            value = values.get((method, task))
            x = x0 + m * bar
            if value is None or not math.isfinite(value):
                _text(canvas, "-", (x + bar / 2 - 3, bottom - 4), 0.35)
                continue
            h = max(2.0, min(value, top_value) / top_value * height)  # a zero still shows
            cv2.rectangle(canvas, (int(x), int(bottom - h)), (int(x + bar - 2), bottom), PALETTE[m % len(PALETTE)], -1)
            if value > top_value:  # clipped: say how far it goes
                _text(canvas, fmt(value), (x, bottom - h - 3), 0.3)
        _text(canvas, task.replace("_", " "), (x0, bottom + 16), 0.42)


def _med_axis_top(values) -> float:
    """Top of a MED axis (cm): up to 10, or less when every value is lower; taller marks are
    clipped."""
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return min(10.0, max(1.0, math.ceil(max(finite, default=1.0))))


def _legend_and_png(canvas, top, left, labels) -> bytes:
    """Draws a legend of `labels` in PALETTE order, three to a row from `top`, and encodes
    the canvas as PNG bytes."""
    for k, label in enumerate(labels):
        x, y = left + (k % 3) * 300, top + (k // 3) * 24
        cv2.rectangle(canvas, (x, y - 11), (x + 14, y + 1), PALETTE[k % len(PALETTE)], -1)
        _text(canvas, label, (x + 20, y))
    ok, png = cv2.imencode(".png", cv2.cvtColor(canvas, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("OpenCV could not encode the chart")
    return png.tobytes()


def table_chart(results_json: str, methods: list[str], tasks: list[str]) -> bytes:
    """PNG bytes of the chart; `results_json` is a list of ``{"method", "task", "med_cm",
    "success_rate"}``; `methods` and `tasks` fix the order of bars and groups."""
    results = json.loads(results_json)
    med = {(r["method"], r["task"]): r.get("med_cm") for r in results}
    success = {(r["method"], r["task"]): r.get("success_rate") for r in results}
    width, left, panel_w, panel_h = 1000, 70, 900, 220
    canvas = np.full((40 + 2 * (panel_h + 70) + 24 * math.ceil(len(methods) / 3), width, 3), 255, np.uint8)
    top_med = _med_axis_top(med.values())
    _panel(canvas, 40, panel_h, left, panel_w, "MED (cm), lower is better", med, tasks, methods, top_med, lambda v: f"{v:.1f}")
    _panel(canvas, 40 + panel_h + 70, panel_h, left, panel_w, "success rate, higher is better", success, tasks,
           methods, 1.0, lambda v: f"{v:.2f}")
    return _legend_and_png(canvas, 40 + 2 * (panel_h + 70) - 10, left, methods)


def _curve_panel(canvas, top, height, left, width, title, values, tasks, sizes, top_value, fmt):
    """One line panel: values[(task, size)] -> number (NaN/None = no point); x is the
    number of demonstrations on a linear axis from 0 to the largest size."""
    bottom = top + height
    _text(canvas, title, (left, top - 10), 0.55)
    for k in range(5):
        y = bottom - k / 4 * height
        cv2.line(canvas, (left, int(y)), (left + width, int(y)), (225, 225, 225), 1)
        _text(canvas, fmt(top_value * k / 4), (left - 48, y + 4), 0.38)
    cv2.line(canvas, (left, bottom), (left + width, bottom), (60, 60, 60), 1)
    largest = max(sizes)
    x_of = lambda size: left + size / largest * width  # noqa: E731
    for size in sizes:
        cv2.line(canvas, (int(x_of(size)), bottom), (int(x_of(size)), bottom + 4), (60, 60, 60), 1)
        _text(canvas, str(size), (x_of(size) - 6, bottom + 18), 0.4)
    _text(canvas, "demonstrations", (left + width - 110, bottom + 34), 0.4)
    for t, task in enumerate(tasks):
        shown = [(s, values[(task, s)]) for s in sizes
                 if values.get((task, s)) is not None and math.isfinite(values[(task, s)])]
        points = [(x_of(s), bottom - min(v, top_value) / top_value * height) for s, v in shown]
        colour = PALETTE[t % len(PALETTE)]
        for a, b in zip(points, points[1:]):
            cv2.line(canvas, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), colour, 2, cv2.LINE_AA)
        for (x, y), (_, value) in zip(points, shown):
            cv2.circle(canvas, (int(x), int(y)), 4, colour, -1, cv2.LINE_AA)
            if value > top_value:  # clipped at the axis top: say how far it goes
                _text(canvas, fmt(value), (x + 8, y + 5), 0.38, colour)


def curve_chart(results_json: str, tasks: list[str], sizes: list[int]) -> bytes:
    """PNG bytes of the data-efficiency chart: success rate and MED (cm) against the number
    of training demonstrations, one line per task. `results_json` is a list of ``{"task",
    "demos", "med_cm", "success_rate"}``; `tasks` fixes the colours, `sizes` the x ticks."""
    results = json.loads(results_json)
    med = {(r["task"], r["demos"]): r.get("med_cm") for r in results}
    success = {(r["task"], r["demos"]): r.get("success_rate") for r in results}
    width, left, panel_w, panel_h = 1000, 70, 880, 220
    canvas = np.full((40 + 2 * (panel_h + 80) + 24 * math.ceil(len(tasks) / 3), width, 3), 255, np.uint8)
    top_med = _med_axis_top(med.values())
    _curve_panel(canvas, 40, panel_h, left, panel_w, "success rate against demonstrations", success, tasks, sizes,
                 1.0, lambda v: f"{v:.2f}")
    _curve_panel(canvas, 40 + panel_h + 80, panel_h, left, panel_w, "MED (cm) against demonstrations", med, tasks,
                 sizes, top_med, lambda v: f"{v:.2f}")
    return _legend_and_png(canvas, 40 + 2 * (panel_h + 80) - 10, left, [t.replace("_", " ") for t in tasks])
