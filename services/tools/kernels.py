"""``shepherd compile``: every numba kernel compiled (or loaded from its on-disk cache)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


def compile_kernels(out: TextIO | None = None) -> None:
    """Compile (or load) the kernels of both per-frame services, and of the vertex
    extractor's paper method (``method = "paper"``); each group's time on ``out`` (standard
    output by default)."""
    from services.pose_estimator.estimate import warm_up as warm_pose
    from services.vertex_extractor.extractor import ExtractorParams
    from services.vertex_extractor.extractor import warm_up as warm_vertices
    out = out or sys.stdout
    for name, warm in (("vertex extractor", warm_vertices), ("pose estimator", warm_pose),
                       ("paper method's", lambda: warm_vertices(ExtractorParams(method="paper")))):
        print(f"compiling the {name} kernels ...", end=" ", flush=True, file=out)
        t = time.perf_counter()
        warm()
        print(f"{time.perf_counter() - t:.1f} s", file=out)
