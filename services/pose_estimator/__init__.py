"""The marker's pose by analytic planar P4P (paper 2.2): IPPE (``p4p``), the MAP choice
and refinement and the floor pose (``estimate``), odometry at a frame's stamp
(``odometry``), evaluation against OpenCV (``evaluate``); ``service`` turns
``marker/vertices`` into ``humanoid/pose``."""

from services.pose_estimator.estimate import MarkerPose, estimate_marker_pose, humanoid_floor_pose
from services.pose_estimator.odometry import OdometryBuffer
from services.pose_estimator.p4p import PoseError, ippe

__all__ = ["MarkerPose", "OdometryBuffer", "PoseError", "estimate_marker_pose",
           "humanoid_floor_pose", "ippe"]
