"""The simulated camera calibrated as a user would calibrate a real one: the paper's grid
rendered in views through the simulated camera, found with our Hough detector, Zhang's
method. ``deploy/sim.toml``'s pose estimator uses the result (``sim-camera.toml``), never the
simulator's true intrinsics.

Regenerate with ``python -m services.tools.sim_calibration services/data/sim-camera.toml``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from services.calibration.detect import DetectionError, detect_grid
from services.calibration.pattern import GridSheet, PatternSpec
from services.calibration.synthetic import board_pose, render_plane
from services.calibration.zhang import Calibration, calibrate
from services.core.camera import CameraModel


def calibrate_simulated(camera: CameraModel, views: int = 12, seed: int = 7,
                        noise_sigma: float = 2.0) -> Calibration:
    """Zhang's calibration of ``camera`` from ``views`` rendered grid photos (noise, tilts
    up to 35°, the grid 35-55 cm away); views the detector refuses are left out."""
    sheet = GridSheet()
    texture = sheet.raster(10.0, page=False)
    origin = ((sheet.overhang_mm + 5) * 10.0,) * 2
    model = PatternSpec.parse("grid:9x9:0.02").model_points()
    rng = np.random.default_rng(seed)
    points = []
    for i in range(views):
        tilt_x, tilt_y = np.radians(rng.uniform(-35, 35, 2))
        T = board_pose(rng.uniform(0.35, 0.55), tilt_x, tilt_y, np.radians(rng.uniform(-20, 20)),
                       (0.08, 0.08), tuple(rng.uniform(-60, 60, 2)), camera)
        image = render_plane(camera, T, texture, 1e4, origin, noise_sigma=noise_sigma,
                             seed=seed * 100 + i)
        try:
            points.append(detect_grid(image))
        except DetectionError:
            continue  # as a user would drop a bad photo
    return calibrate([model] * len(points), points)


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else Path("sim-camera.toml")
    truth = CameraModel.paper()
    cal = calibrate_simulated(truth)
    camera = CameraModel(cal.K, cal.dist, truth.width, truth.height, cal.rms_px)
    out.write_text("# The simulated (paper's) camera as our own calibration measured it: 12 "
                   "rendered grid views,\n# Hough detection, Zhang's method "
                   "(services/tools/sim_calibration.py). Not the truth.\n"
                   + camera.to_toml())
    print(f"wrote {out}: fx {cal.K[0, 0]:.2f} fy {cal.K[1, 1]:.2f} (truth {truth.K[0, 0]:.2f}"
          f" {truth.K[1, 1]:.2f}), RMS {cal.rms_px:.3f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
