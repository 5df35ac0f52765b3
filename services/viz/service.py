"""The ``viz`` service: a Foxglove WebSocket server (open https://app.foxglove.dev or Foxglove
Studio, connect to ws://HOST:8765) showing the camera image with the detected rhombus and
the poses on a floor plan. Needs the ``viz`` extra (``pip install '.[viz]'``)."""

from __future__ import annotations

import json
import time

from pydantic import Field

from schemas import (
    CameraGoal,
    CameraPose,
    HumanoidPose,
    MarkerVertices,
    MissionGoal,
    MissionState,
    SimTruth,
)
from schemas.keys import (
    CAMERA_GOAL,
    HUMANOID_POSE,
    MISSION_GOAL,
    MISSION_STATE,
    ODOM,
    SIM_TRUTH,
    VERTICES,
)
from services.runtime.clock import Ticker
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext
from services.viz.negotiate import serve_both_subprotocols


class Settings(ServiceSettings):
    host: str = Field(default="127.0.0.1", description="address of the WebSocket server")
    port: int = Field(default=8765, ge=0, le=65535, description="its port (0: any free)")
    fps: float = Field(default=10.0, gt=0.0, description="image and scene rate")
    jpeg_quality: int = Field(default=75, ge=10, le=100, description="of /camera/image")


async def main(ctx: ServiceContext, config: Settings) -> None:
    try:
        import foxglove

        from services.viz.convert import floor_scene, image, image_annotations
    except ImportError:
        ctx.log.error("the viz service needs foxglove-sdk: pip install '.[viz]'")
        return
    bus = ctx.bus
    # the SDK's server on a loopback port of its own; in front of it, on the configured
    # port, a front that also takes the older subprotocol (Lichtblick, ws-protocol clients)
    server = foxglove.start_server(name="shepherd", host="127.0.0.1", port=0)
    front = await serve_both_subprotocols(config.host, config.port, server.port)
    ctx.log.info("Foxglove server on ws://%s:%d (foxglove.sdk.v1 and foxglove.websocket.v1)",
                 config.host, front.sockets[0].getsockname()[1])
    frames = bus.subscribe_frames()
    verts = bus.subscribe(VERTICES, MarkerVertices)
    poses = bus.subscribe(HUMANOID_POSE, HumanoidPose)
    truth_sub = bus.subscribe(SIM_TRUTH, SimTruth)
    odom_sub = bus.subscribe(ODOM, CameraPose)
    goal_sub = bus.subscribe(CAMERA_GOAL, CameraGoal)
    mission_sub = bus.subscribe(MISSION_GOAL, MissionGoal)
    state_sub = bus.subscribe(MISSION_STATE, MissionState)
    mc = ctx.deployment.settings.get("mission_controller")
    waypoints = list(mc.waypoints) if mc is not None else []
    pose = truth = odom = goal = None
    # JSON channels under their message names, with the messages' own JSON Schemas
    pose_channel, state_channel = (foxglove.Channel(topic, message_encoding="json", schema=(
        foxglove.Schema(name=f"shepherd.{model.__name__}", encoding="jsonschema",
                        data=json.dumps(model.model_json_schema()).encode())))
        for topic, model in (("/humanoid/pose", HumanoidPose), ("/mission/state", MissionState)))
    ticker = Ticker(1.0 / config.fps)
    try:
        while True:
            if (m := mission_sub.get_nowait()) is not None:
                waypoints = list(m.waypoints)
            pose = poses.get_nowait() or pose
            truth = truth_sub.get_nowait() or truth
            odom = odom_sub.get_nowait() or odom
            goal = goal_sub.get_nowait() or goal
            now = time.time_ns()
            if (f := frames.get_nowait()) is not None and f.image.ndim == 3:
                foxglove.log("/camera/image", image(f.image, f.header.stamp_ns,
                                                    config.jpeg_quality))
            if (v := verts.get_nowait()) is not None:
                foxglove.log("/camera/annotations", image_annotations(v))
            if (s := state_sub.get_nowait()) is not None:
                state_channel.log(s.model_dump(mode="json"))
            if pose is not None:
                pose_channel.log(pose.model_dump(mode="json"))
            foxglove.log("/floor", floor_scene(now, pose, truth, odom, goal, waypoints,
                                               ctx.deployment.world))
            await ticker.wait()
    finally:
        front.close()
        server.stop()
