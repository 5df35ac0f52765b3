"""The one table of key expressions: suffix -> payload model (None for raw frames).

Every key is ``<namespace>/<suffix>``; build them with :class:`Keys`.
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas.messages import (
    CameraGoal,
    CameraIntrinsics,
    CameraPose,
    Hold,
    HumanoidPose,
    IrBackendRequest,
    IrCommand,
    MarkerVertices,
    Message,
    MissionGoal,
    MissionState,
    SimTruth,
)

FRAME = "camera/frame"
INTRINSICS = "camera/intrinsics"
ODOM = "camera/odom"
CAMERA_GOAL = "camera/goal"
VERTICES = "marker/vertices"
HUMANOID_POSE = "humanoid/pose"
HUMANOID_POSE_FILTERED = "humanoid/pose_filtered"
MISSION_GOAL = "mission/goal"
MISSION_STATE = "mission/state"
MISSION_HOLD = "mission/hold"
IR_COMMAND = "ir/command"
IR_BACKEND = "ir/backend"
SIM_IR = "sim/ir"
SIM_TRUTH = "sim/truth"
ALIVE = "alive"
STATS = "stats"  # queryable stats/<service>: ServiceStats

#: Keys that move a robot (suffix key expressions): ``shepherd replay`` leaves them out unless
#: asked to ``--actuate``.
ACTUATION = ("ir/**", "mission/**", CAMERA_GOAL)

#: suffix -> model of its payload; ``None`` marks raw frame bytes with a FrameHeader attachment.
TOPICS: dict[str, type[Message] | None] = {
    FRAME: None,
    INTRINSICS: CameraIntrinsics,
    ODOM: CameraPose,
    CAMERA_GOAL: CameraGoal,
    VERTICES: MarkerVertices,
    HUMANOID_POSE: HumanoidPose,
    HUMANOID_POSE_FILTERED: HumanoidPose,
    MISSION_GOAL: MissionGoal,
    MISSION_STATE: MissionState,
    MISSION_HOLD: Hold,
    IR_COMMAND: IrCommand,
    IR_BACKEND: IrBackendRequest,
    SIM_IR: IrCommand,
    SIM_TRUTH: SimTruth,
}


@dataclass(frozen=True)
class Keys:
    """Key expressions under one namespace (default ``shepherd``)."""

    namespace: str = "shepherd"

    def __post_init__(self) -> None:
        ns = self.namespace
        if not ns or ns.startswith("/") or ns.endswith("/") or any(c in ns for c in "*$?#"):
            raise ValueError(f"namespace {ns!r} must be a plain key prefix like 'shepherd'")

    def key(self, suffix: str) -> str:
        """Full key for a topic suffix such as ``camera/frame``."""
        return f"{self.namespace}/{suffix}"

    def alive(self, service: str) -> str:
        return f"{self.namespace}/{ALIVE}/{service}"

    def stats(self, service: str) -> str:
        return f"{self.namespace}/{STATS}/{service}"

    def suffix(self, key: str) -> str:
        """The topic suffix of a full key (the inverse of :meth:`key`)."""
        prefix = self.namespace + "/"
        return key[len(prefix):] if key.startswith(prefix) else key


def model_or_none(suffix: str) -> type[Message] | None:
    """Payload model of a topic suffix, None for raw frames and unknown keys."""
    return TOPICS.get(suffix)


def model_for(suffix: str) -> type[Message] | None:
    """Payload model of a topic suffix; raises KeyError naming the unknown key."""
    if suffix not in TOPICS:
        raise KeyError(f"unknown topic {suffix!r}; known: {', '.join(TOPICS)}")
    return TOPICS[suffix]
