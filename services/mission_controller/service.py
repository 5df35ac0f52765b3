"""The ``mission_controller`` service: humanoid poses -> IR commands (paper section 5).

Subscribes ``humanoid/pose`` (latest), ``mission/goal`` and ``mission/hold``; at ``rate_hz``
decides a command and publishes it on ``ir/command`` when it changes (and every
``keepalive_s``); publishes ``mission/state``. Sends ``stop`` at shutdown. Each command carries
this run's session id, a sequence number and the monotonic clock, by which the IR transmitter
judges its freshness (issue 20).
"""

from __future__ import annotations

import itertools
import math
import secrets
import time
from typing import Literal

from pydantic import Field

from schemas import Command, Hold, HumanoidPose, IrCommand, MissionGoal, MissionState, Phase
from schemas.keys import IR_COMMAND, MISSION_GOAL, MISSION_HOLD, MISSION_STATE
from services.mission_controller.controller import ControlParams, HeuristicController
from services.mission_controller.pose_freshness import PoseFreshness
from services.runtime.clock import Ticker, age_s
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext


class Settings(ServiceSettings, ControlParams):
    """The controller's parameters (``ControlParams``) and the service loop's own."""

    rate_hz: float = Field(default=10.0, gt=0.0, le=200.0, description="decisions per second")
    waypoints: list[tuple[float, float]] = Field(default_factory=list,
                                                 description="initial mission, world m")
    pose_topic: Literal["humanoid/pose", "humanoid/pose_filtered"] = Field(
        default="humanoid/pose", description=(
            "which pose to steer by; the raw pose by measurement: over 20 seeds of the "
            "stepping humanoid the filtered one's lag made the final error worse (p90 2.1 vs "
            "1.7 cm)"))
    keepalive_s: float = Field(default=0.2, gt=0.0, description=(
        "repeat the current command this often: the IR transmitter's dead-man (0.5 s) "
        "stops the humanoid when the repeats stop"))
    pose_rearm_s: float = Field(default=0.3, ge=0.0, description=(
        "after a gap in the poses (longer than pose_timeout_s), steer again only once they "
        "have come without a gap this long: what a network cut held back arrives at once, the "
        "live poses follow it"))
    hold_timeout_s: float = Field(default=2.0, gt=0.0, description="a hold expires unrenewed")
    exit_when_done: bool = Field(default=False, description="stop the deployment when done")
    loop: bool = Field(default=False, description="when done, run the waypoints again in "
                       "reverse order (soak tests)")


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log
    ctrl = HeuristicController(config.part(ControlParams))
    ctrl.set_waypoints(config.waypoints)
    poses = bus.subscribe(config.pose_topic, HumanoidPose, latest=True)
    goals = bus.subscribe(MISSION_GOAL, MissionGoal, latest=False, queue=8)
    holds = bus.subscribe(MISSION_HOLD, Hold, latest=True)
    last_cmd: Command | None = None
    last_sent = 0.0
    pose: tuple[float, float, float] | None = None
    heading_sigma: float | None = None
    hold = False
    origin: tuple[float, float] | None = None  # where the current leg started (loop)
    ticker = Ticker(1.0 / config.rate_hz)
    fresh = PoseFreshness(config.pose_timeout_s, config.pose_rearm_s)
    session, seq = secrets.token_hex(8), itertools.count()

    def stamped(cmd: Command) -> IrCommand:
        return IrCommand(command=cmd, session=session, seq=next(seq),
                         sent_mono_ns=time.monotonic_ns())

    def send(cmd: Command) -> None:
        nonlocal last_cmd, last_sent
        bus.put(IR_COMMAND, stamped(cmd))
        if cmd is not last_cmd:
            log.info("command %s", cmd.value)
        last_cmd, last_sent = cmd, time.monotonic()

    try:
        while True:
            while (g := goals.get_nowait()) is not None:
                ctrl.set_waypoints([(w[0], w[1]) for w in g.waypoints])
                origin = (pose[0], pose[1]) if pose is not None else None
                if g.tolerance_m is not None:
                    ctrl.params = ctrl.params.model_copy(
                        update={"goal_tolerance_m": g.tolerance_m})
                log.info("new mission: %d waypoints", len(g.waypoints))
            if (p := poses.get_nowait()) is not None:
                fresh.arrived(p.stamp_ns, poses.last_received_ns)
            if p is not None and p.x is not None and p.y is not None and p.yaw is not None:
                pose = (p.x, p.y, p.yaw)
                heading_sigma = math.sqrt(max(p.covariance[2][2], 0.0)) \
                    if p.covariance is not None else None
                if origin is None:
                    origin = (p.x, p.y)
            if (h := holds.get_nowait()) is not None:
                hold = h.hold
            if hold and age_s(holds.last_received_ns) > config.hold_timeout_s:
                hold = False
            was_done = ctrl.phase is Phase.DONE
            try:
                now_ns = time.time_ns()
                d = ctrl.decide(pose, fresh.age_s(now_ns), hold, time.monotonic(),
                                heading_sigma, stale=fresh.why_stale(now_ns))
            except Exception:
                log.exception("control step failed; stopping the humanoid")
                send(Command.STOP)
                await ticker.wait()
                continue
            if d.command is not last_cmd or time.monotonic() - last_sent >= config.keepalive_s:
                send(d.command)
            bus.put(MISSION_STATE, MissionState(phase=d.phase, waypoint_index=d.waypoint_index,
                                                distance_m=d.distance_m,
                                                heading_error_rad=d.heading_error_rad,
                                                last_command=last_cmd or Command.STOP,
                                                reason=d.reason, reversals=ctrl.reversals))
            if d.phase is Phase.DONE and not was_done:
                log.info("mission complete (e = %.1f cm)", 100 * (d.distance_m or 0.0))
                if config.exit_when_done:
                    ctx.request_exit(0)
                if config.loop and origin is not None:
                    # back the way it came, to where this leg started
                    back = [*ctrl.waypoints[-2::-1], origin]
                    origin = ctrl.waypoints[-1]
                    ctrl.set_waypoints(back)
            await ticker.wait()
    finally:
        bus.put(IR_COMMAND, stamped(Command.STOP))
