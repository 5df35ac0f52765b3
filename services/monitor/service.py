"""The ``monitor`` service: a live progress line, a run folder, and the end-of-mission summary.

Subscribes ``sim/truth`` (if simulated), ``humanoid/pose`` and ``mission/state``. Every
second it prints distance to goal, poses per second and frame-to-pose latency. When the
mission is done it waits ``settle_s`` for the humanoid to come to rest, writes
``trajectory.csv`` and ``fig9_distance.png`` (the paper's Fig. 9: distance from the camera over
time) into the run folder, prints the summary beside the paper's result, and, with
``exit_when_done``, ends the deployment: exit 0 if the true final position is within
``success_tolerance_m`` of the goal (or, without truth, the estimate is).
"""

from __future__ import annotations

import csv
import math
import sys
import time
from datetime import datetime
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field

from schemas import Hold, HumanoidPose, MissionState, Phase, SimTruth
from schemas.keys import HUMANOID_POSE, MISSION_HOLD, MISSION_STATE, SIM_TRUTH
from services.monitor.plot import line_plot
from services.runtime.clock import Ticker
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext

PAPER_GOAL_CM = (0.0, 4.7, 60.0)
PAPER_REACHED_CM = (3.3, 4.8, 58.2)


class Settings(ServiceSettings):
    goal: tuple[float, float] | None = Field(default=None, description="world m, for the report")
    run_dir: Path | None = Field(default=Path("runs"), description="parent of run folders")
    exit_when_done: bool = Field(default=True,
                                 description="end the deployment after the summary")
    settle_s: float = Field(default=1.5, ge=0.0, description="wait when done, then judge")
    success_tolerance_m: float = Field(default=0.03, gt=0.0,
                                       description="exit 0 when the humanoid ends this near")
    progress: bool = Field(default=True, description="print a progress line every second")


class Recorder:
    """Rows of the trajectory and the figures of the summary (no bus inside)."""

    def __init__(self) -> None:
        self.t0: int | None = None
        self.truth: list[tuple[float, float, float, float, float, float, float]] = []
        self.poses: list[tuple[float, float, float, float, float]] = []
        self.latency_ms: list[float] = []
        self.holds = 0  # times the camera planner held the humanoid (critical angle)
        self.reversals = 0  # the controller's changes of walking or turning direction
        self.stop_reason = ""

    def _t(self, stamp_ns: int) -> float:
        if self.t0 is None:
            self.t0 = stamp_ns
        return (stamp_ns - self.t0) / 1e9

    def add_truth(self, m: SimTruth) -> None:
        h, c = m.humanoid, m.camera
        self.truth.append((self._t(m.stamp_ns), h.x, h.y, h.yaw, c.x, c.y, c.yaw))

    def add_pose(self, m: HumanoidPose, received_ns: int) -> None:
        self.latency_ms.append((received_ns - m.stamp_ns) / 1e6)
        if m.x is not None:
            self.poses.append((self._t(m.stamp_ns), m.x, m.y, m.yaw,  # type: ignore[arg-type]
                               m.marker_in_camera.position[2]))

    def write(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        with open(folder / "trajectory.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["source", "time_s", "x_m", "y_m", "yaw_rad", "camera_x_m",
                        "camera_y_m", "camera_yaw_rad"])
            for t, x, y, yaw, cx, cy, cyaw in self.truth:
                w.writerow(["truth", f"{t:.3f}", f"{x:.5f}", f"{y:.5f}", f"{yaw:.5f}",
                            f"{cx:.5f}", f"{cy:.5f}", f"{cyaw:.5f}"])
            for t, x, y, yaw, _ in self.poses:
                w.writerow(["estimate", f"{t:.3f}", f"{x:.5f}", f"{y:.5f}", f"{yaw:.5f}",
                            "", "", ""])
        series = []
        residual = None
        if self.truth:
            tr = np.array(self.truth)
            series.append(("true (cm)", tr[:, 0], 100 * tr[:, 1]))
        if self.poses:
            p = np.array(self.poses)
            series.append(("estimated (cm)", p[:, 0], 100 * p[:, 1]))
            if self.truth:
                residual = ("estimate - truth (mm)", p[:, 0],
                            1000 * (p[:, 1] - np.interp(p[:, 0], tr[:, 0], tr[:, 1])))
        img = line_plot(series, title="Humanoid distance from the camera's start along the "
                        "floor (paper Fig. 9: z)", xlabel="time (s)", ylabel="cm",
                        hlines=[("paper goal 60 cm", 60.0)], residual=residual)
        cv2.imwrite(str(folder / "fig9_distance.png"), img)
        plan = []
        if self.truth:
            plan += [("humanoid, true (cm)", 100 * tr[:, 1], 100 * tr[:, 2]),
                     ("camera robot, true (cm)", 100 * tr[:, 4], 100 * tr[:, 5])]
        if self.poses:
            plan.append(("humanoid, estimated (cm)", 100 * p[:, 1], 100 * p[:, 2]))
        cv2.imwrite(str(folder / "floor_plan.png"),
                    line_plot(plan, title="Floor plan (world x right, y up)", xlabel="x (cm)",
                              ylabel="y (cm)", size=(700, 700), equal_axes=True))


def summary(rec: Recorder, goal: tuple[float, float] | None) -> tuple[str, float | None]:
    """Human-readable summary and the true (or estimated) final distance to the goal (m)."""
    lines = ["", "Mission summary"]
    final_err = None
    if goal is not None:
        lines.append(f"  goal                 x={100 * goal[0]:.1f} cm  y={100 * goal[1]:.1f} cm")
    if rec.poses:
        _, x, y, yaw, _ = rec.poses[-1]
        lines.append(f"  final estimate       x={100 * x:.1f} cm  y={100 * y:.1f} cm  "
                     f"yaw={math.degrees(yaw):.1f}°")
        if goal is not None:
            final_err = math.hypot(x - goal[0], y - goal[1])
    if rec.truth:
        _, tx, ty, tyaw, *_ = rec.truth[-1]
        lines.append(f"  final truth          x={100 * tx:.1f} cm  y={100 * ty:.1f} cm  "
                     f"yaw={math.degrees(tyaw):.1f}°")
        if goal is not None:
            final_err = math.hypot(tx - goal[0], ty - goal[1])
        if rec.poses:
            tt = np.array(rec.truth)
            errs = []
            for t, x, y, _, _ in rec.poses:
                i = int(np.argmin(np.abs(tt[:, 0] - t)))
                errs.append(math.hypot(x - tt[i, 1], y - tt[i, 2]))
            lines.append(f"  estimation error     median {100 * np.median(errs):.2f} cm, "
                         f"max {100 * np.max(errs):.2f} cm over {len(errs)} poses")
    if final_err is not None:
        lines.append(f"  final error          {100 * final_err:.1f} cm "
                     f"({'truth' if rec.truth else 'estimate'})")
    lines.append(f"  critical-angle holds {rec.holds}")
    lines.append(f"  command reversals    {rec.reversals}"
                 + (f"  ({rec.stop_reason})" if rec.stop_reason else ""))
    if rec.latency_ms:
        lat = np.array(rec.latency_ms)
        lines.append(f"  frame-to-pose        p50 {np.median(lat):.1f} ms, "
                     f"p99 {np.percentile(lat, 99):.1f} ms")
    if goal is not None and final_err is not None:
        fx, fz = (rec.truth[-1][2], rec.truth[-1][1]) if rec.truth else rec.poses[-1][2:0:-1]
        lines.append("  paper (x, y, z) cm   goal (0, 4.7, 60) reached (3.3, 4.8, 58.2): "
                     "error 3.8 cm")
        lines.append(f"  ours  (x, z) cm      goal ({-100 * goal[1]:.1f}, {100 * goal[0]:.1f}) "
                     f"reached ({-100 * fx:.1f}, {100 * fz:.1f}): error {100 * final_err:.1f} cm")
    return "\n".join(lines), final_err


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log, dep = ctx.bus, ctx.log, ctx.deployment
    goal = config.goal
    mc = dep.settings.get("mission_controller")
    if goal is None and mc is not None and mc.waypoints:
        goal = tuple(mc.waypoints[-1])
    truth = bus.subscribe(SIM_TRUTH, SimTruth, latest=False, queue=256)
    poses = bus.subscribe_stamped(HUMANOID_POSE, HumanoidPose, queue=256)
    states = bus.subscribe(MISSION_STATE, MissionState, latest=True)
    holds = bus.subscribe(MISSION_HOLD, Hold, latest=False, queue=16)
    holding = False
    rec = Recorder()
    folder = (config.run_dir / datetime.now().strftime("%Y%m%d-%H%M%S")
              if config.run_dir else None)
    done_at: float | None = None
    last_print = time.monotonic()
    n_poses = 0
    state: MissionState | None = None
    tty = sys.stderr.isatty()
    ticker = Ticker(0.05)
    try:
        while True:
            while (m := truth.get_nowait()) is not None:
                rec.add_truth(m)
            while (item := poses.get_nowait()) is not None:
                received_ns, p = item
                rec.add_pose(p, received_ns)
                n_poses += 1
            if (s := states.get_nowait()) is not None:
                state = s
                rec.reversals = s.reversals
                if s.phase is Phase.DONE:
                    rec.stop_reason = s.reason
            while (h := holds.get_nowait()) is not None:
                rec.holds += int(h.hold and not holding)
                holding = h.hold
            now = time.monotonic()
            if config.progress and now - last_print >= 1.0:
                lat = rec.latency_ms[-30:]
                e = state.distance_m if state else None
                line = (f"[{state.phase.value if state else 'starting':>12}] "
                        f"e={'—' if e is None else f'{100 * e:5.1f} cm'}  "
                        f"{n_poses / (now - last_print):5.1f} poses/s  "
                        f"latency {np.median(lat) if lat else float('nan'):5.1f} ms  "
                        f"cmd={state.last_command.value if state else '—'}")
                print(("\r" + line) if tty else line, end="" if tty else "\n",
                      file=sys.stderr, flush=True)
                n_poses, last_print = 0, now
            if state is not None and state.phase is Phase.DONE and done_at is None:
                done_at = now
            if done_at is not None and now - done_at >= config.settle_s and \
                    config.exit_when_done:
                text, err = summary(rec, goal)
                print(text, flush=True)
                if folder:
                    rec.write(folder)
                    print(f"  run folder           {folder}", flush=True)
                    folder = None
                ok = err is not None and err <= config.success_tolerance_m
                ctx.request_exit(0 if ok else 1)
                return
            await ticker.wait()
    finally:
        if folder and (rec.truth or rec.poses):
            rec.write(folder)
            log.info("run folder %s", folder)
