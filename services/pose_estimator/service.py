"""The ``pose_estimator`` service: ``marker/vertices`` + ``camera/odom`` -> ``humanoid/pose``."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
from pydantic import Field, ValidationError

from schemas import (
    CameraIntrinsics,
    CameraPose,
    HumanoidPose,
    MarkerInCamera,
    MarkerVertices,
    describe_validation_error,
)
from schemas.keys import HUMANOID_POSE, HUMANOID_POSE_FILTERED, INTRINSICS, ODOM, VERTICES
from services.core.camera import CameraModel
from services.core.geometry import T_floor, inv_T, make_T, quaternion_from_R
from services.pose_estimator.estimate import (
    ELEVATION_UP,
    TILT_SIGMA_DEG,
    UPRIGHT_PROBABILITY,
    VERTEX_SIGMA_PX,
    humanoid_floor_pose,
    up_in_camera,
    warm_up,
)
from services.pose_estimator.odometry import OdometryBuffer
from services.pose_estimator.p4p import PoseError
from services.pose_estimator.pose_filter import FilterParams, PoseFilter
from services.pose_estimator.sequence import (
    CONTINUITY_WINDOW_S,
    MOUNT_CORRECTION,
    NOISE_SIGMA_PX,
    ROCK_SIGMA_DEG,
    SCALE_SIGMA_PX,
    MarkerSequence,
    SequenceParams,
)
from services.runtime.config import RelPath, ServiceSettings
from services.runtime.context import ServiceContext


class Settings(ServiceSettings):
    intrinsics: RelPath | None = Field(default=None,
                                       description="TOML file; else served on camera/intrinsics")
    odom_timeout_s: float = Field(default=0.5, gt=0.0,
                                  description="hold odometry at most this far from a frame (s)")
    odom_wait_s: float = Field(default=0.05, ge=0.0,
                               description="wait this long for odometry at the frame's stamp (s)")
    static_camera_pose: tuple[float, float, float] | None = Field(
        default=None, description="x m, y m, yaw rad of a camera that does not move")
    refine: bool = Field(default=True, description="Gauss-Newton to the MAP pose")
    vertex_sigma_px: float = Field(default=VERTEX_SIGMA_PX, gt=0.0,
                                   description="vertex noise, 1-sigma px")
    tilt_sigma_deg: float = Field(default=TILT_SIGMA_DEG, gt=0.0, le=45.0,
                                  description="upright prior: marker normal level within (deg)")
    upright_probability: float = Field(default=UPRIGHT_PROBABILITY, gt=0.0, le=1.0, description=(
        "each frame tests the upright prior: the pose weighs the upright and a leaning "
        "model by their posterior probabilities, starting from this one for upright (1: the "
        "prior always holds)"))
    elevation_up: bool = Field(default=ELEVATION_UP, description=(
        "each frame's upright prior takes the vertical from where the marker is seen (its "
        "centre's height over the camera, from the mounts), blended with the mount's: a "
        "camera pitched a few degrees off the deployment file's costs the prior little"))
    noise_sigma_px: float = Field(default=NOISE_SIGMA_PX, gt=0.0, description=(
        "the covariance's vertex noise (1-sigma px per coordinate) when the extractor sends "
        "no per-vertex covariance"))
    scale_sigma_px: float = Field(default=SCALE_SIGMA_PX, ge=0.0, description=(
        "the covariance's common scale error of the rhombus (1-sigma px at each vertex)"))
    filter: FilterParams = Field(default_factory=FilterParams, description=(
        "the steady pose published on humanoid/pose_filtered"))
    continuity_window_s: float = Field(default=CONTINUITY_WINDOW_S, ge=0.0,
                                       description="use the previous pose this recent as a prior")
    rock_sigma_deg: float = Field(default=ROCK_SIGMA_DEG, ge=0.0, le=20.0, description=(
        "the marker's roll about its normal with the gait (1-sigma, deg): the body rocks "
        "about its feet, moving the floor position the marker implies"))
    mount_correction: bool = Field(default=MOUNT_CORRECTION, description=(
        "once the marker's mean lean over a sequence has settled on a real camera mount "
        "significantly off the deployment file's, use the estimated up for the upright "
        "prior and the world pose"))


class PoseEstimator:
    """Turns vertices into poses; holds the intrinsics, mounts and latest odometry."""

    def __init__(self, camera: CameraModel, geometry, config: Settings) -> None:
        self.camera = camera
        self.config = config
        self.points = geometry.marker_points()
        self.T_base_camera = geometry.T_base_camera()
        self.T_marker_humanoid = inv_T(geometry.T_humanoid_marker())
        self.up_cam = up_in_camera(self.T_base_camera)
        self.odom = OdometryBuffer(maxlen=64)
        self.odom_stalled = False  # the last wait for odometry ran out; none since
        self.steady = PoseFilter(config.filter)
        self._mount_told: tuple[float, float, bool] | None = None
        self.sequence = MarkerSequence(camera, self.points, self.up_cam, SequenceParams(
            continuity_window_s=config.continuity_window_s,
            vertex_sigma_px=config.vertex_sigma_px,
            tilt_sigma_rad=math.radians(config.tilt_sigma_deg), refine=config.refine,
            rock_sigma_rad=math.radians(config.rock_sigma_deg),
            noise_sigma_px=config.noise_sigma_px, scale_sigma_px=config.scale_sigma_px,
            mount_correction=config.mount_correction,
            height_m=geometry.marker_centre_height_m - geometry.camera_height_m
            if config.elevation_up else None,
            upright_probability=config.upright_probability))

    def estimate(self, msg: MarkerVertices) -> HumanoidPose:
        """Raises PoseError when the vertices give no pose (or one no message can carry)."""
        try:
            return self._estimate(msg)
        except ValidationError as err:  # e.g. a world pose beyond the 10 km the schema allows
            raise PoseError(f"pose out of range: {describe_validation_error(err)}") from None

    def _estimate(self, msg: MarkerVertices) -> HumanoidPose:
        if not msg.found or msg.vertices_px is None:
            raise PoseError(f"marker not found: {msg.reason}")
        if msg.width and (msg.width, msg.height) != (self.camera.width, self.camera.height):
            raise PoseError(f"frame is {msg.width}x{msg.height} but the intrinsics are for "
                            f"{self.camera.width}x{self.camera.height}")
        self.sequence.camera = self.camera
        mp = self.sequence.update(msg.stamp_ns, np.array(msg.vertices_px, dtype=np.float64),
                                  msg.vertices_cov_px2)
        T, note = mp.T_camera_marker, mp.reason
        marker = MarkerInCamera(position=tuple(T[:3, 3].tolist()),  # type: ignore[arg-type]
                                quaternion=quaternion_from_R(T[:3, :3]))
        base_pose, reason = self._camera_base_pose(msg.stamp_ns)
        if base_pose is None:
            return HumanoidPose(seq=msg.seq, stamp_ns=msg.stamp_ns, marker_in_camera=marker,
                                reprojection_px=mp.reprojection_px,
                                reason="; ".join(r for r in (reason, note) if r),
                                area_ratio=msg.area_ratio)
        # the mount the sequence found (identity unless it corrects the file's)
        T_world_camera = T_floor(*base_pose) @ self.T_base_camera @ make_T(
            self.sequence.R_mount_correction.T, (0.0, 0.0, 0.0))
        (x, y, yaw), cov = humanoid_floor_pose(T_world_camera, T, self.T_marker_humanoid,
                                               mp.covariance)
        cov_rows = tuple(map(tuple, cov.tolist())) if cov is not None else None
        return HumanoidPose(seq=msg.seq, stamp_ns=msg.stamp_ns, x=x, y=y, yaw=yaw,
                            marker_in_camera=marker, reprojection_px=mp.reprojection_px,
                            covariance=cov_rows, area_ratio=msg.area_ratio,  # type: ignore[arg-type]
                            reason=note)

    def mount_warning(self) -> str:
        """A message the first time the frames say the camera mount is off the deployment
        file's (and again whenever that estimate moves by more than 2° or the correction
        starts or stops), else ""."""
        mount = self.sequence.mount
        off = mount.offset_deg() if mount is not None else None
        correcting = self.sequence.mount_d is not None
        if mount is None or off is None or not (message := mount.message(correcting)):
            if self._mount_told is not None and self._mount_told[2] and not correcting:
                self._mount_told = None
                return "the camera mount correction is off again (the evidence changed)"
            return ""
        if self._mount_told is not None and self._mount_told[2] == correcting and math.hypot(
                off[0] - self._mount_told[0], off[1] - self._mount_told[1]) <= 2.0:
            return ""
        self._mount_told = (off[0], off[1], correcting)
        return message

    def filtered(self, pose: HumanoidPose) -> HumanoidPose | None:
        """The steady counterpart of a world pose (None while the world pose is unknown)."""
        if pose.x is None or pose.y is None or pose.yaw is None:
            return None
        cov = np.array(pose.covariance) if pose.covariance is not None else None
        (x, y, yaw), P = self.steady.update(pose.stamp_ns, (pose.x, pose.y, pose.yaw), cov)
        try:
            return pose.model_copy(update={
                "x": float(x), "y": float(y), "yaw": float(yaw),
                "covariance": tuple(tuple(float(v) for v in row) for row in P)})
        except ValidationError:
            return None

    def needs_odometry(self, stamp_ns: int) -> bool:
        """True while no odometry at or after ``stamp_ns`` has arrived (and the camera moves)."""
        return self.config.static_camera_pose is None and not self.odom.covers(stamp_ns)

    def _camera_base_pose(self, stamp_ns: int) -> tuple[tuple[float, float, float] | None, str]:
        if self.config.static_camera_pose is not None:
            return self.config.static_camera_pose, ""
        return self.odom.at(stamp_ns, self.config.odom_timeout_s)


async def await_odometry(est: PoseEstimator, odom, stamp_ns: int, wait_s: float) -> None:
    """Take queued odometry; wait up to ``wait_s`` for a sample at or after ``stamp_ns``.

    After a wait runs out, frames do not wait again until odometry flows (one wait an outage).
    """
    while (o := odom.get_nowait()) is not None:
        est.odom.add(o)
        est.odom_stalled = False
    deadline = time.monotonic() + wait_s
    while not est.odom_stalled and est.needs_odometry(stamp_ns):
        left = deadline - time.monotonic()
        if left <= 0:
            est.odom_stalled = True
            return
        try:
            est.odom.add(await odom.recv(timeout=left))
        except TimeoutError:
            est.odom_stalled = True


async def _intrinsics(ctx, config: Settings) -> CameraModel:
    if config.intrinsics is not None:
        return CameraModel.load(config.intrinsics)
    waited = 0.0
    while True:
        replies = await ctx.bus.get(INTRINSICS, CameraIntrinsics, timeout=1.0)
        if replies:
            return CameraModel.from_message(replies[0])
        waited += 1.0
        if waited in (2.0, 10.0, 60.0):
            ctx.log.warning("no intrinsics on camera/intrinsics after %.0f s; still asking",
                            waited)
        await asyncio.sleep(0.5)


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    vertices = bus.subscribe(VERTICES, MarkerVertices, latest=True)
    odom = bus.subscribe(ODOM, CameraPose, latest=False, queue=64)
    updates = bus.subscribe(INTRINSICS, CameraIntrinsics, latest=True)
    await asyncio.to_thread(warm_up)  # compiled kernels ready before the first vertices
    camera = await _intrinsics(ctx, config)
    log.info("intrinsics %dx%d fx=%.1f fy=%.1f", camera.width, camera.height, camera.K[0, 0],
             camera.K[1, 1])
    est = PoseEstimator(camera, ctx.deployment.geometry, config)
    failures: set[str] = set()
    async for msg in vertices:
        if config.intrinsics is None and (k := updates.get_nowait()) is not None:
            est.camera = CameraModel.from_message(k)
        if not msg.found:
            continue
        await await_odometry(est, odom, msg.stamp_ns, config.odom_wait_s)
        try:
            pose = est.estimate(msg)
        except PoseError as err:
            if str(err) not in failures:
                failures.add(str(err))
                log.warning("no pose for frame %d: %s", msg.seq, err)
            continue
        bus.put(HUMANOID_POSE, pose)
        if warning := est.mount_warning():
            log.warning("%s", warning)
        if (steady := est.filtered(pose)) is not None:
            bus.put(HUMANOID_POSE_FILTERED, steady)
