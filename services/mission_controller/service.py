"""The ``mission_controller`` service: humanoid poses -> IR commands (paper section 5).

Subscribes ``humanoid/pose`` (latest), ``mission/goal`` and ``mission/hold``; at ``rate_hz``
decides a command and publishes it on ``ir/command`` when it changes (and every
``keepalive_s``); publishes ``mission/state``. Sends ``stop`` at shutdown.
"""

from __future__ import annotations

import asyncio
import math
import time

from pydantic import Field

from schemas import Command, Hold, HumanoidPose, IrCommand, MissionGoal, MissionState, Phase
from schemas.keys import HUMANOID_POSE, IR_COMMAND, MISSION_GOAL, MISSION_HOLD, MISSION_STATE
from services.config import ServiceSettings
from services.mission_controller.controller import ControlParams, HeuristicController


class Settings(ServiceSettings):
    rate_hz: float = Field(default=10.0, gt=0.0, le=200.0)
    waypoints: list[tuple[float, float]] = Field(default_factory=list,
                                                 description="initial mission, world m")
    goal_tolerance_m: float = Field(default=0.01, gt=0.0, description="l")
    turn_threshold_deg: float = Field(default=15.0, gt=0.0, lt=180.0, description="k")
    turn_release_deg: float = Field(default=5.0, gt=0.0, lt=180.0)
    stop_lead_m: float = Field(default=0.012, ge=0.0,
                               description="stop this early: IR delay x walking speed")
    pose_timeout_s: float = Field(default=0.3, gt=0.0, description="stop when the pose is older")
    keepalive_s: float = Field(default=1.0, gt=0.0)
    hold_timeout_s: float = Field(default=2.0, gt=0.0, description="a hold expires unrenewed")
    exit_when_done: bool = Field(default=False, description="stop the deployment when done")
    loop: bool = Field(default=False, description="when done, run the waypoints again in "
                       "reverse order (soak tests)")


def params_from(config: Settings) -> ControlParams:
    return ControlParams(math.radians(config.turn_threshold_deg),
                         math.radians(config.turn_release_deg), config.goal_tolerance_m,
                         config.stop_lead_m, config.pose_timeout_s)


async def main(ctx, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    ctrl = HeuristicController(params_from(config))
    ctrl.set_waypoints(config.waypoints)
    poses = bus.subscribe(HUMANOID_POSE, HumanoidPose, latest=True)
    goals = bus.subscribe(MISSION_GOAL, MissionGoal, latest=False, queue=8)
    holds = bus.subscribe(MISSION_HOLD, Hold, latest=True)
    last_cmd: Command | None = None
    last_sent = 0.0
    pose: tuple[float, float, float] | None = None
    pose_mono = 0.0
    hold, hold_mono = False, 0.0
    origin: tuple[float, float] | None = None  # where the current leg started (loop)
    period = 1.0 / config.rate_hz

    def send(cmd: Command) -> None:
        nonlocal last_cmd, last_sent
        bus.put(IR_COMMAND, IrCommand(command=cmd))
        if cmd is not last_cmd:
            log.info("command %s", cmd.value)
        last_cmd, last_sent = cmd, time.monotonic()

    try:
        while True:
            while (g := goals.get_nowait()) is not None:
                ctrl.set_waypoints([tuple(w) for w in g.waypoints])
                origin = (pose[0], pose[1]) if pose is not None else None
                ctrl.params = ControlParams(**{**ctrl.params.__dict__,
                                               "goal_tolerance_m": g.tolerance_m})
                log.info("new mission: %d waypoints", len(g.waypoints))
            if (p := poses.get_nowait()) is not None and p.x is not None:
                pose = (p.x, p.y, p.yaw)  # type: ignore[assignment]
                if origin is None:
                    origin = (p.x, p.y)  # type: ignore[assignment]
                pose_mono = time.monotonic() - max(0.0, (time.time_ns() - p.stamp_ns) / 1e9)
            if (h := holds.get_nowait()) is not None:
                hold, hold_mono = h.hold, time.monotonic()
            now = time.monotonic()
            if hold and now - hold_mono > config.hold_timeout_s:
                hold = False
            was_done = ctrl._phase is Phase.DONE
            try:
                d = ctrl.decide(pose, now - pose_mono if pose else math.inf, hold)
            except Exception:
                log.exception("control step failed; stopping the humanoid")
                send(Command.STOP)
                await asyncio.sleep(period)
                continue
            if d.command is not last_cmd or now - last_sent >= config.keepalive_s:
                send(d.command)
            bus.put(MISSION_STATE, MissionState(phase=d.phase, waypoint_index=d.waypoint_index,
                                                distance_m=d.distance_m,
                                                heading_error_rad=d.heading_error_rad,
                                                last_command=last_cmd or Command.STOP))
            if d.phase is Phase.DONE and not was_done:
                log.info("mission complete (e = %.1f cm)", 100 * (d.distance_m or 0.0))
                if config.exit_when_done:
                    ctx.request_exit(0)
                if config.loop and origin is not None:
                    # back the way it came, to where this leg started
                    back = [*ctrl.waypoints[-2::-1], origin]
                    origin = ctrl.waypoints[-1]
                    ctrl.set_waypoints(back)
            await asyncio.sleep(period)
    finally:
        bus.put(IR_COMMAND, IrCommand(command=Command.STOP))
