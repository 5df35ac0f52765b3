"""Mutual TLS, user/password authentication and access control on loopback (deploy/security)."""

import asyncio
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from schemas import Command, IrCommand, Keys
from schemas.keys import IR_COMMAND, SIM_IR
from services.runtime.bus import Bus
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.runtime.session import ZenohSettings, open_session, zenoh_config
from tests.conftest import ROOT, free_port, wait_alive_async


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("certs")
    res = subprocess.run(["bash", str(ROOT / "deploy/security/gen-certs.sh"), str(out)],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return out


@pytest.fixture
def secure_router(certs: Path):
    ep = f"tls/localhost:{free_port()}"
    settings = ZenohSettings(mode="router", listen=[ep.replace("localhost", "127.0.0.1")],
                             multicast_scouting=False, config_file=certs / "router.json5")
    with open_session(settings):
        yield ep


def _client(ep: str, config: Path | None) -> ZenohSettings:
    return ZenohSettings(mode="client", connect=[ep], multicast_scouting=False,
                         config_file=config)


def test_a_client_without_a_certificate_is_refused(secure_router, certs: Path, tmp_path: Path):
    # right password, no client certificate
    laptop = (certs / "laptop.json5").read_text()
    no_cert = tmp_path / "nocert.json5"
    no_cert.write_text(laptop.replace("enable_mtls: true", "enable_mtls: false")
                       .split("connect_private_key")[0] + "} },\n" +
                       laptop.split("} },\n", 1)[1])
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(zenoh_config(_client(secure_router, no_cert)))
    with pytest.raises(zenoh.ZError, match="Unable to connect"):  # and no TLS settings at all
        zenoh.open(zenoh_config(_client(secure_router, None)))


def test_secure_deployment_files_are_valid():
    from services.runtime.config import load_deployment
    for name in ("secure-robot.toml", "secure-laptop.toml"):
        dep = load_deployment(ROOT / "deploy" / name)
        assert dep.zenoh.config_file == ROOT / "deploy" / "certs" / name.replace(
            "secure-", "").replace(".toml", ".json5")


def test_a_wrong_password_is_refused(secure_router, certs: Path, tmp_path: Path):
    text = (certs / "laptop.json5").read_text()
    pw = text.split('password: "')[1].split('"')[0]
    wrong = tmp_path / "wrong.json5"
    wrong.write_text(text.replace(pw, "0" * len(pw)))
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(zenoh_config(_client(secure_router, wrong)))


def test_only_the_mission_controller_identity_drives_the_robot(secure_router, certs: Path):
    ep = secure_router
    robot = parse_deployment({"zenoh": {"mode": "client", "connect": [ep],
                                        "multicast_scouting": False,
                                        "config_file": str(certs / "robot.json5")},
                              "services": {"ir_transmitter": {"backend": "sim",
                                                              "repeat_window_s": 0.0}}})

    async def go() -> list[str]:
        with open_session(_client(ep, certs / "viewer.json5")) as viewer_s, \
                open_session(_client(ep, certs / "laptop.json5")) as laptop_s:
            viewer, laptop = Bus(viewer_s, Keys(), "viewer"), Bus(laptop_s, Keys(), "laptop")
            heard = viewer.subscribe(SIM_IR, IrCommand, latest=False, queue=32)
            task = asyncio.create_task(run_deployment(robot, duration=15))
            await wait_alive_async(laptop_s, "ir_transmitter")
            # authenticated, not allowed:
            viewer.put(IR_COMMAND, IrCommand(command=Command.WALK_FORWARD))
            await asyncio.sleep(0.5)
            # the controller's identity:
            laptop.put(IR_COMMAND, IrCommand(command=Command.TURN_LEFT))
            await asyncio.sleep(1.0)
            got = [m.command.value for m in iter(heard.get_nowait, None)]
            task.cancel()
            viewer.close()
            laptop.close()
            return got
    got = asyncio.run(go())
    assert got == ["turn_left"]


def test_the_vision_identity_cannot_command_the_humanoid(secure_router, certs: Path):
    ep = secure_router
    with open_session(_client(ep, certs / "robot.json5")) as a, \
            open_session(_client(ep, certs / "laptop.json5")) as b:
        got: list[bytes] = []
        sub = b.declare_subscriber("shepherd/ir/command", lambda s: got.append(b"x"))
        frames: list[bytes] = []
        sub2 = b.declare_subscriber("shepherd/camera/frame", lambda s: frames.append(b"x"))
        time.sleep(0.5)
        a.put("shepherd/ir/command", IrCommand(command=Command.STOP).model_dump_json())
        a.put("shepherd/camera/frame", b"pixels")
        time.sleep(0.5)
        sub.undeclare()
        sub2.undeclare()
    assert got == [] and frames == [b"x"]
