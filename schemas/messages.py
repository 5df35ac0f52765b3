"""Every message on the Shepherd bus, as frozen pydantic v2 models.

SI units on the wire: metres, radians, Unix nanoseconds. Frames follow DESIGN.md: world ``W``
(z up), camera optical ``C`` (OpenCV: x right, y down, z forward), marker ``M`` (origin at the
rhombus centre, z out of the humanoid's back).
"""

from __future__ import annotations

import math
import time
from enum import StrEnum
from typing import Annotated, Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
#: a world coordinate (m): finite and within 10 km, so downstream arithmetic cannot overflow
Coord = Annotated[float, Field(allow_inf_nan=False, ge=-1e4, le=1e4)]
Vec2 = tuple[FiniteFloat, FiniteFloat]
CoordXY = tuple[Coord, Coord]
#: a 2x2 covariance in px^2 (rows), e.g. of a vertex's (u, v)
Cov2 = tuple[tuple[FiniteFloat, FiniteFloat], tuple[FiniteFloat, FiniteFloat]]
Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]
Row3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


def now_ns() -> int:
    """Current Unix time in nanoseconds."""
    return time.time_ns()


class Message(BaseModel):
    """Base of every bus message: frozen, finite floats, unknown fields ignored."""

    model_config = ConfigDict(frozen=True, extra="ignore", allow_inf_nan=False)
    VERSION: ClassVar[int] = 1

    @classmethod
    def zenoh_encoding(cls) -> str:
        """Zenoh encoding string, e.g. ``application/json;shepherd.HumanoidPose/1``."""
        return f"application/json;shepherd.{cls.__name__}/{cls.VERSION}"


class Command(StrEnum):
    """Robosapien motion commands the system uses."""

    WALK_FORWARD = "walk_forward"
    WALK_BACKWARD = "walk_backward"
    TURN_LEFT = "turn_left"
    TURN_RIGHT = "turn_right"
    STOP = "stop"


# Robosapien V1 IR codes (implementation notes, section 1).
ROBOSAPIEN_CODES: dict[Command, int] = {
    Command.WALK_FORWARD: 0x86,
    Command.WALK_BACKWARD: 0x87,
    Command.TURN_LEFT: 0x88,
    Command.TURN_RIGHT: 0x80,
    Command.STOP: 0x8E,
}


class FrameEncoding(StrEnum):
    BGR8 = "bgr8"
    MONO8 = "mono8"
    JPEG = "jpeg"


class FrameHeader(Message):
    """JSON header of a ``camera/frame`` sample, carried in the Zenoh attachment."""

    seq: int = Field(ge=0)
    stamp_ns: int = Field(ge=0, description="capture time, Unix ns")
    width: int = Field(gt=0, le=16384)
    height: int = Field(gt=0, le=16384)
    encoding: FrameEncoding
    stamp_source: Literal["grab", "container", "read"] | None = Field(default=None, description=(
        "the clock of stamp_ns: a live camera's grab time, a video file's own timestamps, "
        "or when an image file was read"))

    def expected_size(self) -> int | None:
        """Payload size in bytes for raw encodings, None for JPEG."""
        channels = {FrameEncoding.BGR8: 3, FrameEncoding.MONO8: 1}.get(self.encoding)
        return None if channels is None else self.width * self.height * channels


class CameraIntrinsics(Message):
    """Pinhole intrinsics with OpenCV's distortion model; K and dist in pixels / unitless."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    K: tuple[Row3, Row3, Row3] = Field(description="3x3 camera matrix, rows")
    dist: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] = (
        0.0, 0.0, 0.0, 0.0, 0.0,
    )
    rms_px: FiniteFloat = Field(default=0.0, ge=0.0)

    @field_validator("K")
    @classmethod
    def _k_is_camera_matrix(cls, K: tuple[Row3, Row3, Row3]) -> tuple[Row3, Row3, Row3]:
        if K[0][0] <= 0 or K[1][1] <= 0:
            raise ValueError("K[0][0] and K[1][1] (focal lengths in px) must be positive")
        if K[1][0] != 0 or K[2][0] != 0 or K[2][1] != 0 or K[2][2] != 1:
            raise ValueError("K must be upper triangular with K[2] = [0, 0, 1]")
        return K


class CameraPose(Message):
    """Camera robot base ``B`` in the world: position in m, yaw in rad about world z."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    x: Coord
    y: Coord
    yaw: FiniteFloat


class CameraGoal(Message):
    """Where the camera robot base should stand (world, m / rad) and why."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    x: Coord
    y: Coord
    yaw: FiniteFloat
    reason: str = ""


class MarkerVertices(Message):
    """Rhombus vertices in pixels, ordered left, top, right, bottom (empty when not found)."""

    seq: int = Field(ge=0)
    stamp_ns: int = Field(ge=0)
    found: bool
    vertices_px: tuple[Vec2, Vec2, Vec2, Vec2] | None = None
    area_ratio: FiniteFloat = Field(default=0.0, ge=0.0, le=1.0)
    residual_px: FiniteFloat = Field(default=0.0, ge=0.0)
    reason: str = ""
    width: int = Field(default=0, ge=0, description="image width the vertices refer to")
    height: int = Field(default=0, ge=0)
    vertices_cov_px2: tuple[Cov2, Cov2, Cov2, Cov2] | None = Field(
        default=None,
        description="per-vertex 2x2 covariance of (u, v) in px^2, same order as vertices_px; "
        "null when the extractor does not estimate it",
    )



class MarkerInCamera(Message):
    """Pose of the marker frame ``M`` in the camera optical frame ``C`` (T_camera_marker)."""

    position: tuple[Coord, Coord, Coord] = Field(description="m, camera optical frame")
    quaternion: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] = Field(
        description="x, y, z, w"
    )

    @field_validator("quaternion")
    @classmethod
    def _unit(cls, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        n = math.sqrt(sum(c * c for c in q))
        if not 0.99 < n < 1.01:
            raise ValueError(f"quaternion must have unit norm, got {n:.4f}")
        return q


class HumanoidPose(Message):
    """The humanoid's floor pose in the world (m, rad) and the marker pose in the camera."""

    seq: int = Field(ge=0)
    stamp_ns: int = Field(ge=0)
    x: Coord | None = None
    y: Coord | None = None
    yaw: FiniteFloat | None = None
    marker_in_camera: MarkerInCamera
    reprojection_px: FiniteFloat = Field(ge=0.0)
    covariance: tuple[Row3, Row3, Row3] | None = Field(
        default=None, description="3x3 over (x m, y m, yaw rad), world frame"
    )
    reason: str = Field(default="", description=(
        "why x, y, yaw are null, if they are; or that the pose is still ambiguous"))
    area_ratio: FiniteFloat = Field(default=0.0, ge=0.0, le=1.0)


class MissionGoal(Message):
    """Waypoints for the humanoid on the floor (world, m)."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    waypoints: list[CoordXY] = Field(max_length=1000)
    tolerance_m: FiniteFloat | None = Field(
        default=None, gt=0.0, description="goal tolerance l (m); null: the controller's own")


class Phase(StrEnum):
    IDLE = "idle"
    TURNING = "turning"
    WALKING = "walking"
    HOLD = "hold"
    WAITING_POSE = "waiting_pose"
    SETTLING = "settling"
    CORRECTING = "correcting"
    DONE = "done"


class MissionState(Message):
    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    phase: Phase
    waypoint_index: int = Field(ge=0)
    distance_m: FiniteFloat | None = None
    heading_error_rad: FiniteFloat | None = None
    last_command: Command
    reason: str = Field(default="", description="why this phase and command (e.g. why stopped)")
    reversals: int = Field(default=0, ge=0, description="changes of walking or turning direction")


class Hold(Message):
    """The camera planner asks the mission controller to hold the humanoid still."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    hold: bool
    reason: str = ""


class IrCommand(Message):
    """An infra-red command for the humanoid. ``code`` is the Robosapien byte, derived from
    ``command``; a message whose code disagrees with its command is invalid (the byte sent
    always follows the name)."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    command: Command
    code: int = Field(default=-1, ge=-1, le=0xFF)
    session: str | None = Field(default=None, max_length=64, description=(
        "the sending controller's run (random, new at each start); the IR transmitter orders "
        "and ages a session's commands by seq and sent_mono_ns. Null: a one-shot command "
        "(e.g. `shepherd ir send`), relayed as it comes"))
    seq: int | None = Field(default=None, ge=0, description="increases by one per command "
                            "of the session")
    sent_mono_ns: int | None = Field(default=None, ge=0, description=(
        "the sender's monotonic clock when sent (ns): only differences within one session "
        "mean anything, so no clock synchronisation between hosts is needed"))

    @model_validator(mode="after")
    def _code_follows_command(self) -> IrCommand:
        expected = ROBOSAPIEN_CODES[self.command]
        if self.code == -1:
            object.__setattr__(self, "code", expected)
        elif self.code != expected:
            raise ValueError(f"code 0x{self.code:02X} is not {self.command.value}'s "
                             f"(0x{expected:02X}); the code follows the command")
        return self


class IrBackendRequest(Message):
    """A put on ``ir/backend``: switch the IR transmitter to this backend."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    backend: Literal["serial", "lirc", "sim", "log"]
    options: dict[str, Any] = Field(default_factory=dict)


class IrBackendStatus(Message):
    """Reply to a query on ``ir/backend``."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    backend: str
    options: dict[str, Any] = Field(default_factory=dict)
    sent: int = 0
    failed: int = 0
    coalesced: int = 0
    deadman_stops: int = Field(default=0, description="stops sent because commands stopped")
    unacked: int = Field(default=0, description="codes the IR firmware did not acknowledge")
    firmware_watchdog_stops: int = Field(default=0, description=(
        "stops the IR firmware's own watchdog sent (the host went quiet)"))
    not_fresh: dict[str, int] = Field(default_factory=dict, description=(
        "the controller's commands not sent, by why: old (not newer than one already seen), "
        "rearming (motion after a gap, before the cadence came back), stale (arrived late), "
        "superseded (a newer one arrived with it)"))
    connected: bool = True
    last_error: str = ""


class ServiceStats(Message):
    """Reply to a query on ``stats/<service>``: what the service rejected, and restarts."""

    stamp_ns: int = Field(default_factory=now_ns, ge=0)
    service: str
    rejected: dict[str, dict[str, int]] = Field(default_factory=dict,
                                                description="key -> reason -> count")
    restarts: int = Field(default=0, ge=0)


class Pose2D(Message):
    x: Coord
    y: Coord
    yaw: FiniteFloat


class SimTruth(Message):
    """Ground truth from the simulator (world, m / rad)."""

    stamp_ns: int = Field(ge=0)
    seq: int = Field(default=0, ge=0)
    humanoid: Pose2D
    camera: Pose2D
    marker_in_camera: MarkerInCamera | None = None
