"""The README's picture: a simulated camera frame with the detected rhombus drawn on it, beside
the floor plan of a run of the default mission (the monitor's ``floor_plan.png``).

``shepherd docs --picture`` runs the default deployment (``shepherd run``, about a minute) in a
temporary folder and writes ``docs/img/front.png``, with the run's Fig. 9 and floor plan beside
it for the manual; ``--picture-run DIR`` takes an existing run folder instead.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from services.data import DEFAULT_DEPLOYMENT

GREEN = (60, 200, 60)


def annotated_frame(deployment: Path = DEFAULT_DEPLOYMENT) -> np.ndarray:
    """The deployment's simulated first frame, the extractor's rhombus and vertices on it."""
    from services.runtime.config import load_deployment
    from services.sim.service import Settings, build_world
    from services.vertex_extractor.extractor import RhombusExtractor
    dep = load_deployment(deployment)
    config = dep.settings.get("sim") or Settings()
    image = build_world(config, dep.geometry, dep.world).render().image
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    det = RhombusExtractor().extract(np.ascontiguousarray(image))
    out = image.copy()
    if det.found and det.vertices_px is not None:
        pts = np.round(det.vertices_px * 16).astype(np.int32)  # 4 fractional bits
        cv2.polylines(out, [pts], True, GREEN, 2, cv2.LINE_AA, shift=4)
        for p in pts:
            cv2.circle(out, (int(p[0]), int(p[1])), 5 * 16, GREEN, 2, cv2.LINE_AA, shift=4)
        text = f"rhombus found, line-fit residual {det.residual_px:.2f} px"
    else:
        text = f"no marker: {det.reason}"
    band = out[:40]
    band[:] = (0.35 * band).astype(np.uint8)  # a dark band under the caption
    cv2.putText(out, text, (12, 27), cv2.FONT_HERSHEY_SIMPLEX, 0.65, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out


def side_by_side(frame: np.ndarray, plan: np.ndarray) -> np.ndarray:
    """The two images at the frame's height, a white gap between them."""
    h = frame.shape[0]
    plan = cv2.resize(plan, (round(plan.shape[1] * h / plan.shape[0]), h),
                      interpolation=cv2.INTER_AREA)
    gap = np.full((h, 12, 3), 255, np.uint8)
    return np.hstack([frame, gap, plan])


def run_default_mission(folder: Path) -> Path:
    """Run ``shepherd run`` (the default mission) in ``folder``; its run folder."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    subprocess.run([sys.executable, "-m", "services.tools.cli", "run", "--listen",
                    f"tcp/127.0.0.1:{port}"], cwd=folder, check=True)
    runs = sorted((folder / "runs").iterdir())
    return runs[-1]


#: the run's figures the manual shows beside the picture (copied into its folder)
RUN_FIGURES = ("fig9_distance.png", "floor_plan.png")


def make_picture(out: Path, run_dir: Path | None = None) -> list[Path]:
    """Write the picture to ``out`` and copy the run's figures beside it; the default mission
    is run when no run folder is given. The files written."""
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = run_dir or run_default_mission(Path(tmp))
        plan = cv2.imread(str(run_dir / "floor_plan.png"))
        if plan is None:
            raise FileNotFoundError(f"{run_dir / 'floor_plan.png'}: no floor plan in the run")
        picture = side_by_side(annotated_frame(), plan)
        out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out), picture, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        written = [out]
        for name in RUN_FIGURES:
            image = cv2.imread(str(run_dir / name))
            if image is not None:
                cv2.imwrite(str(out.parent / name), image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
                written.append(out.parent / name)
    return written
