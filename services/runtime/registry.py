"""Names of the services a deployment file may run, and where their code lives.

Each service module exposes ``Settings`` (a :class:`~services.runtime.config.ServiceSettings`) and
``async def main(ctx: ServiceContext, config: Settings)``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

SERVICES: dict[str, str] = {
    "sim": "services.sim.service",
    "frame_source": "services.frame_source.service",
    "vertex_extractor": "services.vertex_extractor.service",
    "pose_estimator": "services.pose_estimator.service",
    "mission_controller": "services.mission_controller.service",
    "camera_planner": "services.camera_planner.service",
    "ir_transmitter": "services.ir_transmitter.service",
    "calibration": "services.calibration.service",
    "monitor": "services.monitor.service",
    "viz": "services.viz.service",
    "ros2_bridge": "services.ros2_bridge.service",
}


def load_service(name: str) -> ModuleType:
    """Import a service's module; raises KeyError naming the unknown service."""
    if name not in SERVICES:
        raise KeyError(f"unknown service {name!r}; expected one of {', '.join(sorted(SERVICES))}")
    return importlib.import_module(SERVICES[name])
