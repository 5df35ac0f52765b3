"""The Shepherd wire contract: message models and the key-expression table."""

from schemas.keys import TOPICS, Keys, model_for
from schemas.messages import (
    ROBOSAPIEN_CODES,
    CameraGoal,
    CameraIntrinsics,
    CameraPose,
    Command,
    FrameEncoding,
    FrameHeader,
    Hold,
    HumanoidPose,
    IrBackendRequest,
    IrBackendStatus,
    IrCommand,
    MarkerInCamera,
    MarkerVertices,
    Message,
    MissionGoal,
    MissionState,
    Phase,
    Pose2D,
    ServiceStats,
    SimTruth,
    now_ns,
)
from schemas.validation import describe_validation_error

ALL_MODELS: tuple[type[Message], ...] = (
    FrameHeader, CameraIntrinsics, CameraPose, CameraGoal, MarkerVertices, MarkerInCamera,
    HumanoidPose, MissionGoal, MissionState, Hold, IrCommand, IrBackendRequest,
    IrBackendStatus, Pose2D, ServiceStats, SimTruth,
)

__all__ = [
    "ALL_MODELS", "ROBOSAPIEN_CODES", "TOPICS", "CameraGoal", "CameraIntrinsics", "CameraPose",
    "Command", "FrameEncoding", "FrameHeader", "Hold", "HumanoidPose", "IrBackendRequest",
    "IrBackendStatus", "IrCommand", "Keys", "MarkerInCamera", "MarkerVertices", "Message",
    "MissionGoal", "MissionState", "Phase", "Pose2D", "ServiceStats", "SimTruth",
    "describe_validation_error", "model_for", "now_ns",
]
