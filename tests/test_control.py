import asyncio
import math
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from schemas import Command, IrBackendRequest, IrBackendStatus, IrCommand, Phase
from schemas.keys import IR_BACKEND, IR_COMMAND
from services.camera_planner.planner import CameraPlanner, PlannerParams
from services.core.world import CircleObstacle, World
from services.ir_transmitter.backends import BackendError, LircBackend, SerialBackend
from services.ir_transmitter.protocol import decode_timings, lircd_conf, timings_us
from services.ir_transmitter.service import Settings as IrSettings
from services.ir_transmitter.service import Transmitter
from services.mission_controller.controller import ControlParams, HeuristicController
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from tests.conftest import wait_alive_async, wait_until
from tests.helpers.pty import Pty

ROOT = Path(__file__).resolve().parent.parent
K = math.radians(15)


def ctrl(**kw: Any) -> HeuristicController:
    c = HeuristicController(ControlParams(turn_threshold_deg=15, turn_release_deg=5,
                                          goal_tolerance_m=0.02, stop_lead_m=0.01, **kw))
    c.set_waypoints([(1.0, 0.0)])
    return c


@pytest.mark.parametrize("pose,age,hold,command,phase", [
    ((0.0, 0.0, 0.0), 0.0, False, Command.WALK_FORWARD, Phase.WALKING),       # aligned, far
    ((0.0, 0.0, math.radians(40)), 0.0, False, Command.TURN_RIGHT, Phase.TURNING),
    ((0.0, 0.0, math.radians(-40)), 0.0, False, Command.TURN_LEFT, Phase.TURNING),
    ((0.0, 0.0, math.radians(10)), 0.0, False, Command.WALK_FORWARD, Phase.WALKING),  # < k
    ((0.0, 0.0, math.radians(179)), 0.0, False, Command.TURN_RIGHT, Phase.TURNING),  # behind
    ((0.99, 0.0, 0.0), 0.0, False, Command.STOP, Phase.DONE),                 # within l
    ((0.0, 0.0, 0.0), 0.0, True, Command.STOP, Phase.HOLD),                   # hold
    ((0.0, 0.0, 0.0), 0.8, False, Command.STOP, Phase.WAITING_POSE),          # stale pose
    (None, 0.0, False, Command.STOP, Phase.WAITING_POSE),                     # no pose
])
def test_controller_decisions(pose, age, hold, command, phase):
    d = ctrl().decide(pose, age, hold)
    assert (d.command, d.phase) == (command, phase)


def test_controller_hysteresis_does_not_chatter():
    c = ctrl()
    assert c.decide((0, 0, math.radians(20)), 0, False).command is Command.TURN_RIGHT
    # still 10 deg off: below k but above the release angle -> keeps turning
    assert c.decide((0, 0, math.radians(10)), 0, False).command is Command.TURN_RIGHT
    assert c.decide((0, 0, math.radians(4)), 0, False).command is Command.WALK_FORWARD
    # walking, 10 deg off: below k -> keeps walking
    assert c.decide((0.1, 0, math.radians(10)), 0, False).command is Command.WALK_FORWARD


def test_controller_stop_lead_settling_and_waypoint_sequence():
    c = HeuristicController(ControlParams(goal_tolerance_m=0.02, stop_lead_m=0.01))
    c.set_waypoints([(0.5, 0.0), (0.5, 0.5)])
    assert c.decide((0.0, 0.0, 0.0), 0, False, now_s=0.0).command is Command.WALK_FORWARD
    d = c.decide((0.475, 0.0, 0.0), 0, False, now_s=1.0)  # 2.5 cm: within l + lead
    assert (d.command, d.phase) == (Command.STOP, Phase.SETTLING) and d.reason
    d = c.decide((0.49, 0.0, 0.0), 0, False, now_s=1.5)  # the last step still under way
    assert (d.command, d.phase, d.waypoint_index) == (Command.STOP, Phase.SETTLING, 0)
    d = c.decide((0.49, 0.0, 0.0), 0, False, now_s=2.0)  # settled 1 cm short: reached
    assert d.waypoint_index == 1 and d.command is Command.TURN_LEFT
    d = c.decide((0.5, 0.49, math.pi / 2), 0, False, now_s=9.0)
    assert d.phase is Phase.DONE and "waypoint reached: 1.0 cm off" in d.reason
    assert c.reversals == 0
    c.set_waypoints([])
    assert c.decide((0, 0, 0), 0, False).phase is Phase.IDLE


def test_an_overshoot_is_corrected_by_stepping_back_not_by_turning_round():
    c = HeuristicController(ControlParams())
    c.set_waypoints([(0.5, 0.0)])
    c.decide((0.3, 0.0, 0.0), 0, False, now_s=0.0)
    assert c.decide((0.47, 0.0, 0.0), 0, False, now_s=1.0).phase is Phase.SETTLING
    d = c.decide((0.545, 0.002, 0.0), 0, False, now_s=2.0)  # the last step carried it past
    assert (d.command, d.phase) == (Command.WALK_BACKWARD, Phase.CORRECTING)
    assert "-4.5 cm to go" in d.reason
    d = c.decide((0.54, 0.0, 0.0), 0, False, now_s=2.2)  # one step: stop at once after it
    assert (d.command, d.phase) == (Command.STOP, Phase.SETTLING)
    d = c.decide((0.51, 0.0, 0.0), 0, False, now_s=3.2)
    assert d.phase is Phase.DONE and d.command is Command.STOP
    assert c.reversals == 1  # forward, then back: one reversal


def test_near_the_goal_the_gaits_sway_does_not_make_it_turn():
    c = HeuristicController(ControlParams())
    c.set_waypoints([(0.5, 0.0)])
    for k, y in enumerate((0.004, -0.004, 0.004, -0.004)):  # 5-6 cm away, bearing ±5-12°
        d = c.decide((0.44 + 0.004 * k, y, 0.1 * (-1) ** k), 0, False, now_s=0.1 * k)
        assert d.command is Command.WALK_FORWARD, d
    assert c.reversals == 0


def planner(**kw) -> CameraPlanner:
    return CameraPlanner(PlannerParams(distance_m=0.25, **kw))


def test_planner_follows_at_distance_d_and_aims_at_the_marker():
    p = planner()
    plan = p.plan((0.6, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert not plan.hold
    assert plan.goal == pytest.approx((0.55 - 0.25, 0.0, 0.0), abs=1e-9)


def test_planner_past_the_critical_angle_holds_and_goes_to_PD():
    p = planner()
    # humanoid turned 60 deg: the view is 60 deg off the normal > 90 - 50
    yaw = math.radians(60)
    plan = p.plan((0.6, 0.0, yaw), (0.0, 0.0, 0.0))
    assert plan.hold and math.degrees(plan.view_angle_rad) == pytest.approx(60, abs=5)
    m = (0.6 - 0.05 * math.cos(yaw), -0.05 * math.sin(yaw))
    pd = (m[0] - 0.25 * math.cos(yaw), m[1] - 0.25 * math.sin(yaw))
    assert plan.goal[:2] == pytest.approx(pd, abs=1e-9)
    assert plan.goal[2] == pytest.approx(yaw, abs=1e-9)  # looking along the humanoid's x
    # still holding at 30 deg (hysteresis), released under the release angle
    cam_at = (0.6 - 0.3 * math.cos(math.radians(30)), -0.3 * math.sin(math.radians(30)), 0.0)
    assert p.plan((0.6, 0.0, 0.0), cam_at).hold
    assert not p.plan((0.6, 0.0, 0.0), (0.3, 0.0, 0.0)).hold


def test_planner_goal_in_an_obstacle_becomes_the_nearest_free_pose_that_sees():
    world = World(obstacles=[CircleObstacle(x=0.3, y=0.0, radius=0.08)])
    p = CameraPlanner(PlannerParams(distance_m=0.25), world)
    plan = p.plan((0.6, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert "blocked" in plan.reason
    gx, gy, _ = plan.goal
    assert world.clearance(gx, gy) >= 0.08 + 0.02 - 1e-9
    assert p.view_angle((0.6, 0.0, 0.0), plan.goal) <= math.radians(40) + 1e-9


def test_planner_never_puts_the_camera_on_the_humanoid():
    p = CameraPlanner(PlannerParams(distance_m=0.05))
    plan = p.plan((0.6, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert math.hypot(plan.goal[0] - 0.6, plan.goal[1]) >= 0.08 + 0.09 + 0.02 - 1e-9


# -- IR ---------------------------------------------------------------------------------------

def test_protocol_timings_round_trip_every_code():
    for code in range(0x80, 0x100):
        assert decode_timings(timings_us(code)) == code
    with pytest.raises(ValueError, match="not a Robosapien frame"):
        decode_timings([833] * 5)


def test_shipped_lircd_conf_is_the_generated_one():
    assert (ROOT / "deploy/lirc/robosapien.lircd.conf").read_text() == lircd_conf()


def test_serial_backend_writes_the_codes_and_survives_unplug(tmp_path: Path):
    pty = Pty(tmp_path / "ttyRobo", firmware=True)
    tx = Transmitter(SerialBackend(str(pty.link), 115200, reopen_s=0.05),
                     IrSettings(min_gap_s=0.0, repeat_window_s=0.0, fresh_s=1.0))

    async def go():
        for c in ("walk_forward", "turn_left", "turn_right", "walk_backward", "stop"):
            assert await tx.send(IrCommand(command=c))
        assert pty.read(5) == bytes([0x86, 0x88, 0x80, 0x87, 0x8E])
        pty.unplug()
        ok = True
        for _ in range(3):  # the first write after the unplug fails, then the port is gone
            ok = ok and await tx.send(IrCommand(command=Command.WALK_FORWARD))
            await asyncio.sleep(0.06)
        assert not ok and tx.failed >= 1 and "serial port" in tx.last_error
        assert not tx.backend.connected
        pty.plug()
        await asyncio.sleep(0.06)
        await tx.retry_pending()  # the latest command is still fresh: it goes out
        assert pty.read(1) == bytes([0x86])
        # a stale one is not resent
        await asyncio.sleep(0.06)
        tx.pending = IrCommand(command=Command.TURN_LEFT, stamp_ns=time.time_ns() - 5 * 10**9)
        await tx.retry_pending()
        assert pty.read(1, timeout=0.3) == b""
        assert tx.status().connected
        await tx.heartbeat()  # the firmware's watchdog is fed with 0x00
        assert pty.read(1) == b"\x00"
    asyncio.run(go())
    tx.backend.close()
    pty.unplug()


def test_repeated_commands_are_coalesced_and_gapped():
    from services.ir_transmitter.backends import LogBackend
    log = LogBackend()
    tx = Transmitter(log, IrSettings(min_gap_s=0.05, repeat_window_s=0.5))

    async def go():
        t0 = time.monotonic()
        for c in ("walk_forward", "walk_forward", "walk_forward", "stop", "turn_left"):
            await tx.send(IrCommand(command=c))
        return time.monotonic() - t0
    elapsed = asyncio.run(go())
    assert [c.command.value for c in log.sent] == ["walk_forward", "stop", "turn_left"]
    assert tx.coalesced == 2 and elapsed >= 0.1


def test_lirc_backend_against_a_real_lircd(tmp_path: Path):
    """Needs Debian's lirc (make test installs it)."""
    conf, out, sock = tmp_path / "r.conf", tmp_path / "out.txt", tmp_path / "lircd.sock"
    conf.write_text(lircd_conf())
    proc = subprocess.Popen(["lircd", "-n", "-H", "file", "-d", str(out), "-o", str(sock),
                             "-P", str(tmp_path / "pid"), str(conf)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_until(sock.exists, "lircd's socket")
        backend = LircBackend(socket=str(sock))
        sent = [Command.WALK_FORWARD, Command.TURN_LEFT, Command.STOP, Command.TURN_RIGHT,
                Command.WALK_BACKWARD]
        for c in sent:
            backend.send(IrCommand(command=c))

        def values() -> list[int]:
            text = out.read_text() if out.exists() else ""
            return [int(line.split()[1]) for line in text.splitlines() if line.strip()]
        wait_until(lambda: sum(v > 50000 for v in values()) >= len(sent),
                   f"lircd wrote {len(sent)} frames")
        frames: list[list[int]] = []
        current: list[int] = []
        for v in values():
            if v > 50000:  # the trailing gap ends a frame
                frames.append(current)
                current = []
            else:
                current.append(v)
        assert [decode_timings(f) for f in frames] == [IrCommand(command=c).code for c in sent]
        with pytest.raises(BackendError, match="unreachable"):
            LircBackend(socket=str(tmp_path / "nope")).send(IrCommand(command=Command.STOP))
    finally:
        proc.terminate()
        proc.wait(5)


def test_hot_swap_under_a_stream_of_commands_loses_none(router, make_bus):
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ir_transmitter": {
                                "backend": "log", "min_gap_s": 0.0, "repeat_window_s": 0.0,
                                "allowed": [{"backend": "sim"}, {"backend": "serial",
                                                                 "options": {"baud": 9600}}]}}})
    bus = make_bus("driver")

    async def go():
        task = asyncio.create_task(run_deployment(dep, duration=20))
        await wait_alive_async(bus.session, "ir_transmitter")
        cmds = ["walk_forward", "turn_left", "turn_right", "stop"]
        n = 40
        for i in range(n):
            bus.put(IR_COMMAND, IrCommand(command=cmds[i % 4]))
            if i == 15:
                bus.put(IR_BACKEND, IrBackendRequest(backend="sim"))
            if i == 25:
                bus.put(IR_BACKEND, IrBackendRequest(backend="serial",
                                                     options={"baud": 9600}))  # no port: bad
            await asyncio.sleep(0.01)
        deadline = time.monotonic() + 30
        while True:  # until all 40 are accounted for (sent or failed), on a loaded machine too
            status = await bus.get(IR_BACKEND, IrBackendStatus, timeout=2)
            done = bool(status) and status[0].sent + status[0].failed >= n
            if done or time.monotonic() > deadline:
                break
            await asyncio.sleep(0.05)
        task.cancel()
        return status
    status = asyncio.run(go())
    assert status and status[0].backend == "sim"
    assert status[0].sent == 40 and status[0].failed == 0
    assert "rejected" in status[0].last_error and "port" in status[0].last_error


@pytest.mark.slow
def test_the_service_feeds_the_firmware_watchdog(tmp_path: Path, router):
    pty = Pty(tmp_path / "ttyRobo", firmware=True)
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"ir_transmitter": {
                                "backend": "serial", "options": {"port": str(pty.link)}}}})
    asyncio.run(run_deployment(dep, duration=2.0))
    data = pty.read(100, timeout=0.5)
    pty.unplug()
    beats = data.count(0)
    assert beats >= 8  # every 0.15 s: well inside the firmware's 0.4 s watchdog
    assert data[-1] == 0x8E and data.count(0x8E) == 1  # stop once, last, at shutdown


def test_backend_requests_are_limited_to_what_the_deployment_file_allows():
    from schemas import IrBackendRequest
    from services.ir_transmitter.service import allowed_or_raise
    config = IrSettings(backend="serial", options={"port": "/dev/ttyUSB0"},
                        allowed=[{"backend": "lirc", "options": {"socket": "/run/lirc/lircd"}}])
    allowed_or_raise(config, IrBackendRequest(backend="serial",
                                              options={"port": "/dev/ttyUSB0"}))
    allowed_or_raise(config, IrBackendRequest(backend="lirc",
                                              options={"socket": "/run/lirc/lircd"}))
    for backend, options in (("log", {}), ("sim", {}), ("serial", {"port": "/dev/ttyACM9"}),
                             ("lirc", {"socket": "/tmp/evil"})):
        with pytest.raises(ValueError, match="is not allowed by the deployment file"):
            allowed_or_raise(config, IrBackendRequest(backend=backend, options=options))


def test_serial_backend_sends_nothing_before_the_firmware_says_it_is_ready(tmp_path: Path):
    """An Arduino resets when its port opens: the backend waits for the firmware's hello."""
    pty = Pty(tmp_path / "ttyRobo", firmware=True, hello_after_s=0.5)
    backend = SerialBackend(str(pty.link), ready_timeout_s=3.0)
    try:
        assert not backend.connected
        t0 = time.monotonic()
        backend.send(IrCommand(command=Command.WALK_FORWARD))
        assert time.monotonic() - t0 >= 0.4 and backend.connected
        assert pty.read(1) == bytes([0x86])
    finally:
        backend.close()
        pty.unplug()


def test_serial_backend_without_the_firmware_says_so(tmp_path: Path):
    pty = Pty(tmp_path / "ttyRobo")  # a port nobody answers on
    backend = SerialBackend(str(pty.link), ready_timeout_s=0.3)
    try:
        with pytest.raises(BackendError, match="no hello from the IR firmware"):
            backend.send(IrCommand(command=Command.STOP))
        assert not backend.connected
        plain = SerialBackend(str(pty.link), handshake=False)  # a device without it
        plain.send(IrCommand(command=Command.STOP))
        assert plain.connected and pty.read(1) == bytes([0x8E])
        plain.close()
    finally:
        backend.close()
        pty.unplug()


def test_serial_backend_counts_codes_the_firmware_did_not_acknowledge(tmp_path: Path):
    pty = Pty(tmp_path / "ttyRobo", firmware=True, ack=False)
    backend = SerialBackend(str(pty.link), ack_timeout_s=0.2)
    try:
        backend.send(IrCommand(command=Command.WALK_FORWARD))
        backend.send(IrCommand(command=Command.STOP))
        time.sleep(0.3)
        backend.heartbeat()
        assert backend.unacked == 2
    finally:
        backend.close()
        pty.unplug()
    acked = Pty(tmp_path / "ttyRobo2", firmware=True)
    backend = SerialBackend(str(acked.link), ack_timeout_s=0.2)
    try:
        backend.send(IrCommand(command=Command.WALK_FORWARD))
        wait_until(lambda: acked.acks == 1, "the firmware's acknowledgement")  # not a sleep:
        backend.heartbeat()  # the ack is waiting, however late it came, and is matched first
        assert backend.unacked == 0
    finally:
        backend.close()
        acked.unplug()


def test_no_turn_is_decided_on_a_heading_whose_sigma_exceeds_k():
    import math

    from schemas import Command
    from services.mission_controller.controller import ControlParams, HeuristicController
    ctrl = HeuristicController(ControlParams())
    ctrl.set_waypoints([(0.3, 0.3)])
    pose = (0.0, 0.0, 0.0)  # the goal 45° to the left, well beyond k = 15°
    unsure = math.radians(20.0)
    d = ctrl.decide(pose, 0.0, False, now_s=0.0, heading_sigma_rad=unsure)
    assert d.command is Command.STOP and "uncertain" in d.reason
    d = ctrl.decide(pose, 0.0, False, now_s=0.2, heading_sigma_rad=unsure)
    assert d.command is Command.STOP  # still waiting for a surer heading
    d = ctrl.decide(pose, 0.0, False, now_s=0.3, heading_sigma_rad=math.radians(2.0))
    assert d.command is Command.TURN_LEFT  # a sure heading: turn at once
    other = HeuristicController(ControlParams())
    other.set_waypoints([(0.3, 0.3)])
    other.decide(pose, 0.0, False, now_s=0.0, heading_sigma_rad=unsure)
    d = other.decide(pose, 0.0, False, now_s=0.6, heading_sigma_rad=unsure)
    assert d.command is Command.TURN_LEFT  # waited long enough: decide anyway
