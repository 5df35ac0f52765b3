"""Bus messages -> Foxglove messages (pure functions; the foxglove-sdk is the ``viz`` extra).

Topics: ``/camera/image`` (JPEG), ``/camera/annotations`` (the detected rhombus, drawn over
the image), ``/floor`` (a 3-D scene: humanoid estimated and true, camera robot and its goal,
waypoints, obstacles; world frame, metres).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from foxglove import messages as fm

from schemas import CameraGoal, CameraPose, HumanoidPose, MarkerVertices, SimTruth
from services.core.world import CircleObstacle, World

GREEN = fm.Color(r=0.1, g=0.9, b=0.2, a=1.0)
RED = fm.Color(r=0.9, g=0.2, b=0.2, a=1.0)


def _ts(stamp_ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=stamp_ns // 1_000_000_000, nsec=stamp_ns % 1_000_000_000)


def image(bgr: np.ndarray, stamp_ns: int, quality: int = 80) -> fm.CompressedImage:
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return fm.CompressedImage(timestamp=_ts(stamp_ns), frame_id="camera", data=buf.tobytes(),
                              format="jpeg")


def image_annotations(v: MarkerVertices) -> fm.ImageAnnotations:
    """The rhombus as a closed line (Foxglove's pixel origin is the top-left pixel's corner;
    ours is its centre, hence + 0.5)."""
    if not v.found or v.vertices_px is None:
        text = fm.TextAnnotation(timestamp=_ts(v.stamp_ns), position=fm.Point2(x=10, y=20),
                                 text=f"no marker: {v.reason}", font_size=14, text_color=RED)
        return fm.ImageAnnotations(texts=[text])
    pts = [fm.Point2(x=u + 0.5, y=w + 0.5) for u, w in v.vertices_px]
    loop = fm.PointsAnnotation(timestamp=_ts(v.stamp_ns), type=fm.PointsAnnotationType.LineLoop,
                               points=pts, outline_color=GREEN, thickness=2.0)
    label = fm.TextAnnotation(timestamp=_ts(v.stamp_ns), position=fm.Point2(x=10, y=20),
                              text=f"r = {100 * v.area_ratio:.2f}%  residual "
                                   f"{v.residual_px:.3f} px", font_size=14, text_color=GREEN)
    return fm.ImageAnnotations(points=[loop], texts=[label])


def _pose(x: float, y: float, z: float, yaw: float) -> fm.Pose:
    return fm.Pose(position=fm.Vector3(x=x, y=y, z=z),
                   orientation=fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2),
                                             w=math.cos(yaw / 2)))


def _box(name: str, x: float, y: float, yaw: float, size: tuple[float, float, float],
         color: fm.Color, stamp_ns: int) -> fm.SceneEntity:
    cube = fm.CubePrimitive(pose=_pose(x, y, size[2] / 2, yaw),
                            size=fm.Vector3(x=size[0], y=size[1], z=size[2]), color=color)
    arrow = fm.ArrowPrimitive(pose=_pose(x, y, size[2] + 0.01, yaw), shaft_length=0.08,
                              shaft_diameter=0.01, head_length=0.03, head_diameter=0.025,
                              color=color)
    return fm.SceneEntity(timestamp=_ts(stamp_ns), frame_id="world", id=name,
                          cubes=[cube], arrows=[arrow])


def floor_scene(stamp_ns: int, pose: HumanoidPose | None, truth: SimTruth | None,
                odom: CameraPose | None, goal: CameraGoal | None,
                waypoints: list[tuple[float, float]], world: World) -> fm.SceneUpdate:
    entities = []
    if pose is not None and pose.x is not None:
        entities.append(_box("humanoid (estimated)", pose.x, pose.y, pose.yaw,  # type: ignore
                             (0.09, 0.16, 0.34), fm.Color(r=0.2, g=0.5, b=1.0, a=0.8),
                             stamp_ns))
    if truth is not None:
        h = truth.humanoid
        entities.append(_box("humanoid (truth)", h.x, h.y, h.yaw, (0.09, 0.16, 0.34),
                             fm.Color(r=0.6, g=0.6, b=0.6, a=0.35), stamp_ns))
    if odom is not None:
        entities.append(_box("camera robot", odom.x, odom.y, odom.yaw, (0.16, 0.14, 0.2),
                             fm.Color(r=0.95, g=0.6, b=0.1, a=0.9), stamp_ns))
    if goal is not None:
        entities.append(_box("camera goal", goal.x, goal.y, goal.yaw, (0.16, 0.14, 0.01),
                             fm.Color(r=0.95, g=0.6, b=0.1, a=0.3), stamp_ns))
    spheres = [fm.SpherePrimitive(pose=_pose(x, y, 0.01, 0.0),
                                  size=fm.Vector3(x=0.03, y=0.03, z=0.03), color=GREEN)
               for x, y in waypoints]
    if spheres:
        entities.append(fm.SceneEntity(timestamp=_ts(stamp_ns), frame_id="world",
                                       id="waypoints", spheres=spheres))
    cyl = [fm.CylinderPrimitive(pose=_pose(o.x, o.y, 0.1, 0.0),
                                size=fm.Vector3(x=2 * o.radius, y=2 * o.radius, z=0.2),
                                bottom_scale=1.0, top_scale=1.0, color=RED)
           for o in world.obstacles if isinstance(o, CircleObstacle)]
    lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineLoop, pose=_pose(0, 0, 0, 0),
                              thickness=0.01, scale_invariant=False,
                              points=[fm.Point3(x=px, y=py, z=0.0) for px, py in o.points],
                              color=RED)
             for o in world.obstacles if not isinstance(o, CircleObstacle)]
    if cyl or lines:
        entities.append(fm.SceneEntity(timestamp=_ts(stamp_ns), frame_id="world",
                                       id="obstacles", cylinders=cyl, lines=lines))
    return fm.SceneUpdate(entities=entities)
