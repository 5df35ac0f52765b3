"""A steady humanoid pose: a constant-velocity Kalman filter on the floor pose (no bus inside).

State (x m, y m, yaw rad, vx m/s, vy m/s, yaw rate rad/s) in the world; each measurement is a
pose estimate with its own 3 x 3 covariance (what the pose estimator computes from the
Jacobian), so a far, blurred view counts less than a close one. The process noise is white
acceleration (``accel_sigma`` m/s², ``yaw_accel_sigma`` rad/s²): small values make a steadier
pose that lags a step change of speed more. A measurement more than ``gate_sigma`` away (a
marker lost and found elsewhere, a wrong IPPE branch), a gap over ``max_gap_s`` or a stamp
going backwards restarts the filter at that measurement.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.geometry import wrap_angle


class FilterParams(BaseModel):
    """The filter's parameters (``[services.pose_estimator.filter]``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    accel_sigma: float = Field(default=0.02, gt=0.0, description="m/s², white acceleration")
    yaw_accel_sigma: float = Field(default=0.5, gt=0.0, description="rad/s²")
    gait_sigma: tuple[float, float, float] = Field(default=(0.003, 0.003, 0.02), description=(
        "x m, y m, yaw rad: how far the marker moves about the body in the gait (its rock), "
        "added to each measurement's own covariance"))
    gate_sigma: float = Field(default=5.0, gt=0.0, description="restart beyond this")
    max_gap_s: float = Field(default=1.0, gt=0.0, description="restart after a longer gap")
    default_sigma: tuple[float, float, float] = Field(
        default=(0.005, 0.005, 0.02), description="x m, y m, yaw rad when none is given")


class PoseFilter:
    """Feed it timed floor poses; read back the filtered pose and its covariance."""

    def __init__(self, params: FilterParams | None = None) -> None:
        self.params = params or FilterParams()
        self.x = np.zeros(6)
        self.P = np.eye(6)
        self.stamp_ns: int | None = None
        self.restarts = 0

    def update(self, stamp_ns: int, pose: tuple[float, float, float],
               covariance: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Take one measurement; returns the filtered (x, y, yaw) and its 3 x 3 covariance."""
        z = np.array(pose, dtype=np.float64)
        R = (np.asarray(covariance, dtype=np.float64) if covariance is not None
             else np.diag(np.square(self.params.default_sigma)))
        R = 0.5 * (R + R.T) + np.diag(np.square(self.params.gait_sigma)) + np.eye(3) * 1e-12
        if self.stamp_ns is None or not (0 <= stamp_ns - self.stamp_ns
                                         <= self.params.max_gap_s * 1e9):
            return self._restart(stamp_ns, z, R)
        self._predict((stamp_ns - self.stamp_ns) / 1e9)
        H = np.zeros((3, 6))
        H[:, :3] = np.eye(3)
        innovation = z - self.x[:3]
        innovation[2] = wrap_angle(float(innovation[2]))
        S = self.P[:3, :3] + R
        try:
            S_inv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return self._restart(stamp_ns, z, R)
        if float(innovation @ S_inv @ innovation) > self.params.gate_sigma ** 2:
            return self._restart(stamp_ns, z, R)
        K = self.P @ H.T @ S_inv
        self.x = self.x + K @ innovation
        self.x[2] = wrap_angle(float(self.x[2]))
        IKH = np.eye(6) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form: stays symmetric, PSD
        self.stamp_ns = stamp_ns
        return self.x[:3].copy(), self.P[:3, :3].copy()

    def _predict(self, dt: float) -> None:
        F = np.eye(6)
        F[0, 3] = F[1, 4] = F[2, 5] = dt
        q = np.array([self.params.accel_sigma] * 2 + [self.params.yaw_accel_sigma]) ** 2
        Q = np.zeros((6, 6))
        for i in range(3):  # white acceleration, integrated over dt
            Q[i, i] = q[i] * dt ** 4 / 4
            Q[i, i + 3] = Q[i + 3, i] = q[i] * dt ** 3 / 2
            Q[i + 3, i + 3] = q[i] * dt ** 2
        self.x = F @ self.x
        self.x[2] = wrap_angle(float(self.x[2]))
        self.P = F @ self.P @ F.T + Q

    def _restart(self, stamp_ns: int, z: np.ndarray, R: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        if self.stamp_ns is not None:
            self.restarts += 1
        self.x = np.concatenate([z, np.zeros(3)])
        self.P = np.zeros((6, 6))
        self.P[:3, :3] = R
        self.P[3:, 3:] = np.diag([0.1 ** 2, 0.1 ** 2, math.radians(45) ** 2])  # at rest, ±
        self.stamp_ns = stamp_ns
        return z.copy(), R.copy()
