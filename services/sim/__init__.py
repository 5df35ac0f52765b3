"""The simulator: the humanoid and the camera robot (``humanoid``, ``camera_robot``), the
renderer (``render``), scenes with known truth (``scenes``), the world state (``state``);
``service`` publishes what a real robot would."""

from services.sim.render import Rendered, RenderStyle, render_view
from services.sim.scenes import marker_pose, random_views
from services.sim.state import SimWorld

__all__ = ["RenderStyle", "Rendered", "SimWorld", "marker_pose", "random_views", "render_view"]
