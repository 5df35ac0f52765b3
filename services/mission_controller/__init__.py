"""The paper's heuristic humanoid control (section 5): ``controller`` (pure); ``service``
turns poses into ``ir/command``."""

from services.mission_controller.controller import ControlParams, Decision, HeuristicController

__all__ = ["ControlParams", "Decision", "HeuristicController"]
