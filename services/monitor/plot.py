"""Line plots saved as PNG: drawn with matplotlib (the ``plot`` extra) where it is installed,
else by hand with OpenCV, so a bare install still writes its figures.

Series are drawn in order, each thinner and on top of the one before, so an estimate drawn
after the truth stays visible where they overlap; a residual series (e.g. estimate minus
truth) gets a panel of its own; ``equal_axes`` keeps one unit the same length on both axes
(floor plans).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

COLOURS = [(200, 90, 30), (40, 40, 220), (60, 160, 60), (150, 60, 160), (0, 140, 230)]
Series = tuple[str, np.ndarray, np.ndarray]


def line_plot(series: Sequence[Series], *, title: str, xlabel: str, ylabel: str,
              size: tuple[int, int] = (800, 500), hlines: Sequence[tuple[str, float]] = (),
              equal_axes: bool = False, residual: Series | None = None) -> np.ndarray:
    """A BGR image plotting (label, x, y) series, with optional labelled horizontal lines and
    a residual panel below."""
    try:
        return _matplotlib_plot(series, title, xlabel, ylabel, size, hlines, equal_axes,
                                residual)
    except ImportError:
        return _opencv_plot(series, title, xlabel, ylabel, size, hlines)


def _matplotlib_plot(series: Sequence[Series], title: str, xlabel: str, ylabel: str,
                     size: tuple[int, int], hlines: Sequence[tuple[str, float]],
                     equal_axes: bool, residual: Series | None) -> np.ndarray:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    dpi = 100
    rows = 2 if residual is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi,
                             sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1][:rows]})
    ax = axes[0][0]
    n = max(1, len(series))
    for i, (label, x, y) in enumerate(series):
        if len(x):
            ax.plot(x, y, label=label, linewidth=1.2 + 2.5 * (n - 1 - i) / n,
                    alpha=0.55 if i < n - 1 else 1.0, zorder=2 + i)
    for label, value in hlines:
        ax.axhline(value, color="0.45", linestyle="--", linewidth=1)
        ax.annotate(label, (1.0, value), xycoords=("axes fraction", "data"), ha="right",
                    va="bottom", color="0.35", fontsize=8)
    ax.set_title(title, fontsize=10)
    ax.set_ylabel(ylabel)
    ax.grid(True, color="0.9")
    if equal_axes:
        ax.set_aspect("equal", adjustable="datalim")
    if any(len(s[1]) for s in series):
        ax.legend(fontsize=8, loc="best")
    if residual is not None:
        rax = axes[1][0]
        label, x, y = residual
        rax.plot(x, y, color="tab:red", linewidth=1)
        rax.axhline(0.0, color="0.5", linewidth=0.8)
        rax.set_ylabel(label, fontsize=8)
        rax.grid(True, color="0.9")
        rax.set_xlabel(xlabel)
    else:
        ax.set_xlabel(xlabel)
    fig.tight_layout()
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]
    plt.close(fig)
    return cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR)


def _opencv_plot(series: Sequence[Series], title: str, xlabel: str, ylabel: str,
                 size: tuple[int, int], hlines: Sequence[tuple[str, float]]) -> np.ndarray:
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
