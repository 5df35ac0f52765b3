"""Small line plots drawn with OpenCV (no plotting library needed), saved as PNG."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

COLOURS = [(200, 90, 30), (40, 40, 220), (60, 160, 60), (150, 60, 160), (0, 140, 230)]


def line_plot(series: Sequence[tuple[str, np.ndarray, np.ndarray]], *, title: str, xlabel: str,
              ylabel: str, size: tuple[int, int] = (800, 500),
              hlines: Sequence[tuple[str, float]] = ()) -> np.ndarray:
    """A BGR image plotting (label, x, y) series, with optional labelled horizontal lines."""
    W, H = size
    img = np.full((H, W, 3), 255, np.uint8)
    left, right, top, bottom = 80, 20, 40, 60
    xs = [s[1] for s in series if len(s[1])]
    ys = [s[2] for s in series if len(s[2])] + [np.array([v for _, v in hlines])]
    if not xs:
        return img
    x0, x1 = min(float(np.min(x)) for x in xs), max(float(np.max(x)) for x in xs)
    yc = np.concatenate([y for y in ys if len(y)])
    y0, y1 = float(np.min(yc)), float(np.max(yc))
    pad = 0.05 * (y1 - y0 or 1.0)
    y0, y1 = y0 - pad, y1 + pad
    x1 = x1 if x1 > x0 else x0 + 1

    def to_px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        px = left + (x - x0) / (x1 - x0) * (W - left - right)
        py = H - bottom - (y - y0) / (y1 - y0) * (H - top - bottom)
        return np.column_stack([px, py]).round().astype(np.int32)

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.rectangle(img, (left, top), (W - right, H - bottom), (0, 0, 0), 1)
    for i in range(6):
        fx = x0 + i * (x1 - x0) / 5
        fy = y0 + i * (y1 - y0) / 5
        px = to_px(np.array([fx]), np.array([y0]))[0]
        py = to_px(np.array([x0]), np.array([fy]))[0]
        cv2.putText(img, f"{fx:.3g}", (px[0] - 15, H - bottom + 20), font, 0.45, (0, 0, 0), 1)
        cv2.putText(img, f"{fy:.3g}", (5, py[1] + 5), font, 0.45, (0, 0, 0), 1)
        cv2.line(img, (left, py[1]), (W - right, py[1]), (225, 225, 225), 1)
    for j, (label, value) in enumerate(hlines):
        p = to_px(np.array([x0, x1]), np.array([value, value]))
        cv2.line(img, tuple(p[0]), tuple(p[1]), (120, 120, 120), 1, cv2.LINE_AA)
        cv2.putText(img, label, (p[1][0] - 160, p[1][1] - 6 - 14 * j), font, 0.45,
                    (90, 90, 90), 1)
    for i, (label, x, y) in enumerate(series):
        if len(x) < 1:
            continue
        colour = COLOURS[i % len(COLOURS)]
        cv2.polylines(img, [to_px(np.asarray(x), np.asarray(y))], False, colour, 2, cv2.LINE_AA)
        cv2.putText(img, label, (left + 10, top + 20 + 20 * i), font, 0.5, colour, 1,
                    cv2.LINE_AA)
    cv2.putText(img, title, (left, 25), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, xlabel, (W // 2 - 40, H - 15), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, ylabel, (5, top - 10), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img
