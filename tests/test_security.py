"""Mutual TLS, user/password authentication and access control on loopback (deploy/security)."""

import asyncio
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas import Command, IrCommand, Keys
from schemas.keys import IR_COMMAND, SIM_IR
from services.runtime.bus import Bus
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.runtime.session import ZenohSettings, open_session, zenoh_config
from tests.conftest import ROOT, free_port, wait_alive_async, wait_for, wait_until


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
    conf = zenoh_config(settings)
    conf.insert_json5("scouting/delay", "0")  # nobody to scout: open at once (as conftest's)
    session = zenoh.open(conf)
    try:
        yield ep
    finally:
        session.close()


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
            got: list[str] = []

            def turned() -> bool:
                got.extend(m.command.value for m in iter(heard.get_nowait, None))
                return "turn_left" in got
            await wait_for(turned, "the laptop's turn_left on the IR port")
            task.cancel()
            viewer.close()
            laptop.close()
            return got
    got = asyncio.run(go())
    assert got[0] == "turn_left" and "walk_forward" not in got
    assert set(got[1:]) <= {"stop"}  # the dead-man stops it once the laptop goes quiet


def test_the_vision_identity_cannot_command_the_humanoid(secure_router, certs: Path):
    ep = secure_router
    with open_session(_client(ep, certs / "robot.json5")) as a, \
            open_session(_client(ep, certs / "laptop.json5")) as b:
        got: list[bytes] = []
        sub = b.declare_subscriber("shepherd/ir/command", lambda s: got.append(b"x"))
        frames: list[bytes] = []
        sub2 = b.declare_subscriber("shepherd/camera/frame", lambda s: frames.append(b"x"))
        pub = a.declare_publisher("shepherd/camera/frame")
        matching: Any = pub  # zenoh's stub says bool; at run time a MatchingStatus
        wait_until(lambda: matching.matching_status.matching, "b's frame subscriber seen by a")
        a.put("shepherd/ir/command", IrCommand(command=Command.STOP).model_dump_json())
        pub.put(b"pixels")  # after the command, on the same link: it arrives after it
        wait_until(lambda: frames, "the frame (allowed)")
        pub.undeclare()
        sub.undeclare()
        sub2.undeclare()
    assert got == [] and frames == [b"x"]


def test_a_viewer_cannot_answer_queries_a_service_serves(secure_router, certs: Path):
    """The pose estimator takes the first reply on camera/intrinsics: only the vision host's
    may reach it."""
    with open_session(_client(secure_router, certs / "viewer.json5")) as viewer, \
            open_session(_client(secure_router, certs / "robot.json5")) as robot, \
            open_session(_client(secure_router, certs / "laptop.json5")) as laptop:
        fake = viewer.declare_queryable("shepherd/camera/intrinsics",
                                        lambda q: q.reply(q.key_expr, b"fake"))
        real = robot.declare_queryable("shepherd/camera/intrinsics",
                                       lambda q: q.reply(q.key_expr, b"real"))
        answers: list[bytes] = []

        def answered() -> bool:
            answers[:] = [r.ok.payload.to_bytes() for r in laptop.get(
                "shepherd/camera/intrinsics", timeout=1.0) if r.ok is not None]
            return bool(answers)
        wait_until(answered, "an answer on camera/intrinsics")
        fake.undeclare()
        real.undeclare()
    assert answers == [b"real"]


def test_a_service_token_counts_only_from_its_hosts_role(secure_router, certs: Path):
    with open_session(_client(secure_router, certs / "viewer.json5")) as viewer, \
            open_session(_client(secure_router, certs / "robot.json5")) as robot, \
            open_session(_client(secure_router, certs / "laptop.json5")) as laptop:
        tokens = [viewer.liveliness().declare_token("shepherd/alive/mission_controller"),
                  robot.liveliness().declare_token("shepherd/alive/mission_controller"),
                  robot.liveliness().declare_token("shepherd/alive/pose_estimator"),
                  laptop.liveliness().declare_token("shepherd/alive/camera_planner")]
        with open_session(_client(secure_router, certs / "viewer.json5")) as watcher:
            alive: list[str] = []

            def seen() -> bool:  # the believed tokens (a loaded machine takes its time)
                alive[:] = sorted(str(r.ok.key_expr) for r in watcher.liveliness().get(
                    "shepherd/alive/**", timeout=1.0) if r.ok is not None)
                return {"shepherd/alive/camera_planner", "shepherd/alive/pose_estimator"
                        } <= set(alive)
            wait_until(seen, "the camera planner's and pose estimator's tokens")
        for t in tokens:
            t.undeclare()
    # the mission controller's token from the viewer or the vision host is not believed
    assert alive == ["shepherd/alive/camera_planner", "shepherd/alive/pose_estimator"]


def test_the_router_listens_with_tls_when_its_config_says_so(certs: Path, tmp_path: Path):
    from tests.conftest import spawn_cli
    port = free_port()
    config = tmp_path / "router.json5"
    config.write_text((certs / "router.json5").read_text().replace(
        '"tls/0.0.0.0:7447"', f'"tls/127.0.0.1:{port}"'))
    router = spawn_cli("router", "--config", str(config))
    try:
        line = router.stdout.readline() if router.stdout else ""
        assert f"tls/127.0.0.1:{port}" in line, line
        for _ in range(50):  # TLS with the laptop's certificate connects
            try:
                with open_session(_client(f"tls/localhost:{port}", certs / "laptop.json5")):
                    break
            except zenoh.ZError:
                time.sleep(0.1)
        else:
            pytest.fail("no TLS client could connect")
        with pytest.raises(zenoh.ZError):  # plain TCP on that port does not
            zenoh.open(zenoh_config(_client(f"tcp/127.0.0.1:{port}", None)))
    finally:
        router.kill()
        router.communicate()
