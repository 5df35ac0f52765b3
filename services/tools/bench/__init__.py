"""``shepherd bench``: each measurement printed beside the reference it competes with.

Sections, one module each: ``bus`` (one Zenoh hop, ours vs raw zenoh-python), ``vertices``
(rhombus extraction vs OpenCV's contour route, ArUco and AprilTag on the same frames), ``pose``
(per-pose time and accuracy vs cv2.solvePnP), ``calibration`` (pattern detection and Zhang vs
cv2.calibrateCamera), ``e2e`` (frame to ``humanoid/pose`` through the services).
"""

from __future__ import annotations

import importlib
import platform
import sys

from services.tools.bench.common import machine_ms, progress

SECTIONS = ("bus", "vertices", "pose", "calibration", "e2e")


def run_bench(only: list[str], quick: bool = False) -> int:
    """Run the named sections (all when ``only`` is empty); 2 for an unknown name."""
    unknown = [o for o in only if o not in SECTIONS]
    if unknown:
        print(f"shepherd: unknown bench section(s) {unknown}; expected {', '.join(SECTIONS)}",
              file=sys.stderr)
        return 2
    print(f"# shepherd bench — {platform.processor() or platform.machine()}, "
          f"Python {platform.python_version()}, {'quick' if quick else 'full'} run; "
          f"this machine: {machine_ms():.0f} ms for 10^6 additions in a Python loop (about "
          "35-40 on a typical current machine; compiled code's speed differs between machines "
          "apart from it: each table's ratio to its reference is the figure to compare)")
    from services.tools.kernels import compile_kernels
    progress("compiling the kernels (cached after the first run)")
    compile_kernels(sys.stderr)
    for name in SECTIONS:
        if not only or name in only:
            importlib.import_module(f"services.tools.bench.{name}").run(quick)
    return 0


__all__ = ["SECTIONS", "run_bench"]
