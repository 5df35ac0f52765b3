"""Where the camera robot should stand (paper 6): ``planner`` (pure); ``service`` turns
humanoid poses and odometry into ``camera/goal`` and ``mission/hold``."""

from services.camera_planner.planner import CameraPlanner, Plan, PlannerParams

__all__ = ["CameraPlanner", "Plan", "PlannerParams"]
