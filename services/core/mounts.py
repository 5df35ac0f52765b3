"""The fixed mounts of DESIGN.md: the camera on its robot base, the marker on the humanoid."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.geometry import T_base_camera, T_humanoid_marker


class Geometry(BaseModel):
    """The fixed mounts (DESIGN.md): camera on its robot base, marker on the humanoid. Metres."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    camera_height_m: float = Field(default=0.20, ge=0.0, description="optical centre above floor")
    camera_forward_m: float = Field(default=0.0, description="optical centre ahead of base origin")
    camera_pitch_rad: float = Field(default=0.0, ge=-1.2, le=1.2, description="down is positive")
    marker_centre_height_m: float = Field(default=0.20, gt=0.0,
                                          description="rhombus centre above the floor")
    marker_back_offset_m: float = Field(default=0.05, ge=0.0,
                                        description="marker centre behind the humanoid origin")
    marker_width_m: float = Field(default=0.050, gt=0.0, description="horizontal diagonal")
    marker_height_m: float = Field(default=0.066, gt=0.0, description="vertical diagonal")

    def marker_points(self) -> np.ndarray:
        """Vertices in the marker frame M, shape (4, 3), ordered left, top, right, bottom (m)."""
        w, h = self.marker_width_m / 2, self.marker_height_m / 2
        return np.array([[-w, 0, 0], [0, h, 0], [w, 0, 0], [0, -h, 0]], dtype=np.float64)

    def T_base_camera(self) -> np.ndarray:
        """4x4 transform camera optical frame -> camera robot base (REP-103 base)."""
        return T_base_camera(self.camera_forward_m, self.camera_height_m, self.camera_pitch_rad)

    def T_humanoid_marker(self) -> np.ndarray:
        """4x4 transform marker frame -> humanoid frame (marker on the humanoid's back)."""
        return T_humanoid_marker(self.marker_back_offset_m, self.marker_centre_height_m)
