import asyncio

import pytest

from schemas import CameraPose, Command, Hold, IrCommand, MissionGoal
from schemas.keys import IR_COMMAND, MISSION_GOAL, MISSION_HOLD, ODOM
from tests.conftest import cli_here, run_cli, spawn_cli, wait_matched, wait_matched_key


@pytest.mark.slow
def test_echo_shows_messages_published_by_another_process(router, make_bus):
    echo = spawn_cli("echo", "shepherd/**", "--connect", router, "--count", "3",
                     "--duration", "20")
    bus = make_bus("pub")
    for key in (ODOM, IR_COMMAND, MISSION_HOLD):  # echo's subscriber is up, not a sleep
        asyncio.run(wait_matched(bus, key))
    bus.put(ODOM, CameraPose(x=0.5, y=-0.25, yaw=0.0))
    bus.put(IR_COMMAND, IrCommand(command=Command.TURN_LEFT))
    bus.put(MISSION_HOLD, Hold(hold=True, reason="\x1b[2J\rgone\u202e"))  # hostile text
    out, err = echo.communicate(timeout=30)
    assert echo.returncode == 0, err
    assert "camera/odom: x=50.0 cm y=-25.0 cm yaw=0.0°" in out
    assert "ir/command: turn_left (0x88)" in out
    assert "mission/hold: hold=True \\x1b[2J\\x0dgone\\u202e" in out
    assert "\x1b" not in out and "\r" not in out


@pytest.mark.slow
def test_typed_round_trip_between_processes(router, make_bus, sessions):
    bus = make_bus("sub")
    elsewhere = sessions()  # sees our subscribers once the router has them

    async def go():
        cmds = bus.subscribe(IR_COMMAND, IrCommand, latest=False)
        goals = bus.subscribe(MISSION_GOAL, MissionGoal, latest=False)
        for key in (IR_COMMAND, MISSION_GOAL):
            await wait_matched_key(elsewhere, bus.keys.key(key))
        out = await asyncio.to_thread(run_cli, "ir", "send", "walk_forward", "--connect",
                                      router)
        assert out.returncode == 0, out.stderr
        assert (await cmds.recv(timeout=5)).code == 0x86
        out = await asyncio.to_thread(run_cli, "mission", "goto", "0.6", "0", "0.8", "0.2",
                                      "--connect", router)
        assert out.returncode == 0, out.stderr
        g = await goals.recv(timeout=5)
        assert g.waypoints == [(0.6, 0.0), (0.8, 0.2)]
    asyncio.run(go())


def test_mission_goto_needs_pairs():
    out = cli_here("mission", "goto", "0.6")
    assert out.returncode == 2 and "X Y pairs" in out.stderr


@pytest.mark.slow
def test_ir_send_waits_for_a_transmitter_that_subscribes_late(router, make_bus):
    bus = make_bus("late")

    async def go():
        sending = asyncio.create_task(asyncio.to_thread(
            run_cli, "ir", "send", "turn_right", "--connect", router))
        await asyncio.sleep(2.5)  # the command line is waiting for a subscriber by now
        cmds = bus.subscribe(IR_COMMAND, IrCommand, latest=False)
        out = await sending
        assert out.returncode == 0, out.stderr
        assert (await cmds.recv(timeout=5)).command == Command.TURN_RIGHT
        assert "nothing subscribes" not in out.stderr
    asyncio.run(go())


def test_publish_once_with_no_subscriber_says_so(router, capsys):
    from services.runtime.session import ZenohSettings
    from services.tools.echo import publish_once
    settings = ZenohSettings(mode="peer", connect=[router], multicast_scouting=False)
    rc = asyncio.run(publish_once(settings, "nobody", IR_COMMAND,
                                  IrCommand(command=Command.STOP), wait_s=0.3))
    err = capsys.readouterr().err
    assert rc == 0
    assert "nothing subscribes to nobody/ir/command" in err
