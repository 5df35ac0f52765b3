"""Faults: a router restarted under traffic, a pose stream that stops, a service that raises.
Where control is lost, `stop` must reach the humanoid within 0.5 s."""

import asyncio
import signal
import time

import pytest
import zenoh

from schemas import HumanoidPose, IrCommand, MarkerInCamera
from schemas.keys import HUMANOID_POSE, SIM_IR
from services.mission_controller import controller as controller_module
from services.runtime.bus import Bus
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.runtime.session import ZenohSettings, zenoh_config
from tests.conftest import endpoint, spawn_cli, wait_alive_async, wait_matched_key, wait_until

pytestmark = pytest.mark.slow  # end-to-end: left out of `make test-fast`


def test_router_restart_under_traffic_sessions_reconnect():
    ep = endpoint()
    router = spawn_cli("router", "--listen", ep)
    settings = ZenohSettings(mode="client", connect=[ep], multicast_scouting=False)
    try:
        for _ in range(50):
            try:
                a = zenoh.open(zenoh_config(settings))
                break
            except zenoh.ZError:
                time.sleep(0.2)
        b = zenoh.open(zenoh_config(settings))
        got: list[float] = []
        sub = b.declare_subscriber("shepherd/t", lambda s: got.append(time.monotonic()))
        asyncio.run(wait_matched_key(a, "shepherd/t"))
        a.put("shepherd/t", b"1")
        wait_until(lambda: got, "the first sample")
        assert len(got) == 1
        router.send_signal(signal.SIGKILL)
        router.communicate(timeout=5)  # reaps it and closes its pipes
        for _ in range(10):  # traffic while the router is down is lost, never queued forever
            a.put("shepherd/t", b"1")
            time.sleep(0.05)
        assert len(got) == 1
        router = spawn_cli("router", "--listen", ep)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 20 and len(got) == 1:
            a.put("shepherd/t", b"1")
            time.sleep(0.02)
        resumed = time.monotonic() - t0
        assert len(got) > 1, "traffic did not resume"
        print(f"\nrouter restart: traffic resumed {resumed:.2f} s after the new router started")
        sub.undeclare()
        a.close()
        b.close()
    finally:
        router.kill()
        router.communicate()


def _pose(x: float) -> HumanoidPose:
    return HumanoidPose(seq=1, stamp_ns=time.time_ns(), x=x, y=0.0, yaw=0.0,
                        marker_in_camera=MarkerInCamera(position=(0, 0, 0.3),
                                                        quaternion=(0, 0, 0, 1)),
                        reprojection_px=0.1)


async def _walk_poses(bus: Bus, seconds: float) -> None:
    """Poses far from the goal at 30 Hz for ``seconds``: the controller walks."""
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        bus.put(HUMANOID_POSE, _pose(0.3))
        await asyncio.sleep(1 / 30)


def _control_deployment(router: str):
    return parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                             "services": {"mission_controller": {"waypoints": [[2.0, 0.0]]},
                                          "ir_transmitter": {"backend": "sim",
                                                             "repeat_window_s": 0.0,
                                                             "min_gap_s": 0.0}}})


@pytest.mark.xdist_group("realtime")  # a deadline in real time: beside no other
def test_a_pose_stream_that_stops_ends_in_stop_within_half_a_second(router, make_bus):
    bus = make_bus("camera")

    async def go() -> float:
        heard = bus.subscribe_stamped(SIM_IR, IrCommand, queue=256)
        task = asyncio.create_task(run_deployment(_control_deployment(router), duration=20))
        await wait_alive_async(bus.session, "mission_controller", "ir_transmitter")
        for _ in range(45):  # 1.5 s of poses at 30 Hz, far from the goal: walk
            bus.put(HUMANOID_POSE, _pose(0.3))
            await asyncio.sleep(1 / 30)
        last = time.time_ns()
        await asyncio.sleep(1.0)
        task.cancel()
        cmds = [(t, m.command.value) for t, m in iter(heard.get_nowait, None)]
        walking = [t for t, c in cmds if c == "walk_forward" and t < last]
        stops = [t for t, c in cmds if c == "stop" and t > last]
        assert walking and stops, cmds
        return (stops[0] - last) / 1e9
    delay = asyncio.run(go())
    print(f"\npose stream stopped: stop reached the humanoid after {1000 * delay:.0f} ms")
    assert delay < 0.5


def test_an_unhandled_exception_in_the_controller_sends_stop(router, make_bus, monkeypatch):
    original = controller_module.HeuristicController.decide
    calls = [0]

    def flaky(self, pose, age, hold, now_s=None, *args, **kwargs):
        calls[0] += 1
        if calls[0] == 15:
            raise RuntimeError("injected fault")
        return original(self, pose, age, hold, now_s, *args, **kwargs)

    monkeypatch.setattr(controller_module.HeuristicController, "decide", flaky)
    bus = make_bus("camera")

    async def go() -> list[tuple[int, str]]:
        heard = bus.subscribe_stamped(SIM_IR, IrCommand, queue=256)
        task = asyncio.create_task(run_deployment(_control_deployment(router), duration=20))
        await wait_alive_async(bus.session, "mission_controller", "ir_transmitter")
        await _walk_poses(bus, 4.0)
        task.cancel()
        return [(t, m.command.value) for t, m in iter(heard.get_nowait, None)]
    cmds = asyncio.run(go())
    values = [c for _, c in cmds]
    first_walk = values.index("walk_forward")
    # walking, then the caught fault sends stop, then the same controller walks again
    assert "stop" in values[first_walk:]
    after = values[first_walk:][values[first_walk:].index("stop"):]
    assert "walk_forward" in after


def test_a_controller_that_crashes_sends_stop_and_is_restarted(router, make_bus, monkeypatch):
    """An exception outside the control step ends the controller's main: its ``finally``
    sends stop, and the launcher restarts it (counted in ``stats/mission_controller``)."""
    from schemas import ServiceStats
    from services.mission_controller import service as controller_service
    real_state = controller_service.MissionState
    calls = [0]

    def crashing_state(**kw: object) -> object:
        calls[0] += 1
        if calls[0] == 15:
            raise RuntimeError("injected crash")
        return real_state(**kw)

    monkeypatch.setattr(controller_service, "MissionState", crashing_state)
    bus = make_bus("camera")

    async def go() -> tuple[list[str], list[ServiceStats]]:
        heard = bus.subscribe_stamped(SIM_IR, IrCommand, queue=256)
        task = asyncio.create_task(run_deployment(_control_deployment(router), duration=20))
        await wait_alive_async(bus.session, "mission_controller", "ir_transmitter")
        await _walk_poses(bus, 4.0)
        stats = await bus.get("stats/mission_controller", ServiceStats, timeout=2)
        task.cancel()
        return [m.command.value for _, m in iter(heard.get_nowait, None)], stats
    values, stats = asyncio.run(go())
    assert calls[0] > 15  # the restarted controller went on publishing its state
    assert stats and stats[0].restarts == 1
    first_walk = values.index("walk_forward")
    after_crash = values[first_walk:][values[first_walk:].index("stop"):]
    assert "walk_forward" in after_crash  # the restarted controller walks again
