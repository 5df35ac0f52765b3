"""Files that ship with the package: the default deployment and the paper's camera.

``deploy/sim.toml`` and ``deploy/paper-camera.toml`` in the source tree are links to these, so
the default ``shepherd run`` works the same from a clone and from an installed wheel.
"""

from __future__ import annotations

from pathlib import Path

DATA_DIR = Path(__file__).resolve().parent
#: The deployment ``shepherd run`` runs without a file: the paper's control experiment.
DEFAULT_DEPLOYMENT = DATA_DIR / "sim.toml"
#: The paper's 640 x 480 web camera (eq. 3): the simulator's true camera.
PAPER_CAMERA = DATA_DIR / "paper-camera.toml"
#: Our own calibration of that simulated camera (``services/tools/sim_calibration.py``).
SIM_CAMERA = DATA_DIR / "sim-camera.toml"

__all__ = ["DATA_DIR", "DEFAULT_DEPLOYMENT", "PAPER_CAMERA", "SIM_CAMERA"]
