"""Figures: matplotlib where installed (equal axes, a residual panel, every series visible),
and the OpenCV drawing when it is not."""

from __future__ import annotations

import builtins

import numpy as np
import pytest

from services.monitor import plot


def _series() -> list[plot.Series]:
    t = np.linspace(0, 8, 200)
    truth = 29 + 31 * np.clip(t / 6, 0, 1)
    return [("true (cm)", t, truth), ("estimated (cm)", t, truth + 0.2 * np.sin(9 * t))]


def test_matplotlib_figures_with_a_residual_panel_and_equal_axes():
    t = np.linspace(0, 8, 200)
    img = plot.line_plot(_series(), title="Fig. 9", xlabel="time (s)", ylabel="cm",
                         hlines=[("goal", 60.0)], residual=("error (mm)", t, np.sin(t)))
    assert img.shape == (500, 800, 3) and img.dtype == np.uint8
    red = (img[..., 2] > 150) & (img[..., 1] < 90) & (img[..., 0] < 90)  # the residual
    assert red[int(0.75 * 500):].sum() > 50 and red[:int(0.6 * 500)].sum() == 0
    plan = plot.line_plot([("path", np.array([0.0, 60.0]), np.array([0.0, 1.0]))],
                          title="plan", xlabel="x", ylabel="y", size=(700, 700),
                          equal_axes=True)
    blue = (plan[..., 0] > 150) & (plan[..., 2] < 120)
    blue[:100] = False  # the legend's sample line
    rows = np.nonzero(blue.any(axis=1))[0]
    assert rows.max() - rows.min() < 40  # 1 cm of y is as tall as 1 cm of x is wide


def test_without_matplotlib_the_figures_are_drawn_with_opencv(monkeypatch: pytest.MonkeyPatch):
    real_import = builtins.__import__

    def no_matplotlib(name: str, *args: object, **kwargs: object) -> object:
        if name.startswith("matplotlib"):
            raise ImportError("no matplotlib")
        return real_import(name, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    img = plot.line_plot(_series(), title="Fig. 9", xlabel="time (s)", ylabel="cm")
    assert img.shape == (500, 800, 3) and (img < 250).any()
