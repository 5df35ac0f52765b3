"""The floor plane and its obstacles (world frame W, metres)."""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class CircleObstacle(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["circle"] = "circle"
    x: float
    y: float
    radius: float = Field(gt=0.0)

    def distance(self, x: float, y: float) -> float:
        """Signed distance (m) from a point to the obstacle's boundary (negative inside)."""
        return math.hypot(x - self.x, y - self.y) - self.radius


class PolygonObstacle(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["polygon"] = "polygon"
    points: list[tuple[float, float]] = Field(min_length=3)

    def distance(self, x: float, y: float) -> float:
        pts = np.asarray(self.points, dtype=np.float64)
        a, b = pts, np.roll(pts, -1, axis=0)
        ab = b - a
        ap = np.array([x, y]) - a
        t = np.clip((ap * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-12), 0.0, 1.0)
        d = float(np.min(np.hypot(*(ap - t[:, None] * ab).T)))
        # even-odd rule for inside
        inside = False
        for (x1, y1), (x2, y2) in zip(a, b, strict=True):
            if (y1 > y) != (y2 > y) and x < (x2 - x1) * (y - y1) / (y2 - y1) + x1:
                inside = not inside
        return -d if inside else d


Obstacle = Annotated[CircleObstacle | PolygonObstacle, Field(discriminator="kind")]


class World(BaseModel):
    """Obstacles on the floor; robots are discs of a given radius."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    obstacles: list[Obstacle] = Field(default_factory=list, description=(
        "world m: { kind = \"circle\", x, y, radius } or { kind = \"polygon\", points }"))

    def clearance(self, x: float, y: float) -> float:
        """Distance (m) from (x, y) to the nearest obstacle boundary (inf without obstacles)."""
        return min((o.distance(x, y) for o in self.obstacles), default=math.inf)

    def collides(self, x: float, y: float, radius: float) -> bool:
        return self.clearance(x, y) < radius
