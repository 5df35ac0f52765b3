"""The Foxglove live view: conversions, and the server advertising its channels."""

import asyncio
import base64
import json
import os
import shutil
import socket
import struct
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from schemas import Command, HumanoidPose, MarkerInCamera, MarkerVertices, MissionState, Phase
from schemas.keys import HUMANOID_POSE, MISSION_STATE, VERTICES
from services.core.world import CircleObstacle, World
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.viz.convert import floor_scene, image, image_annotations
from tests.conftest import ROOT, free_port, wait_alive_async
from tests.helpers.fake_frames import publish_frame, render_marker

# end-to-end: left out of `make test-fast`; on one xdist worker, so that the npm install of
# the foxglove client (a session fixture) happens once
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("foxglove")]

VERTS = MarkerVertices(seq=1, stamp_ns=5, found=True, vertices_px=((10, 20), (20, 10),
                                                                   (30, 20), (20, 30)),
                       area_ratio=0.05, residual_px=0.1)
POSE = HumanoidPose(seq=1, stamp_ns=5, x=0.3, y=0.0, yaw=0.2,
                    marker_in_camera=MarkerInCamera(position=(0, 0, 0.25),
                                                    quaternion=(0, 0, 0, 1)),
                    reprojection_px=0.1)
STATE = MissionState(phase=Phase.WALKING, waypoint_index=0, distance_m=0.3,
                     last_command=Command.WALK_FORWARD)


def test_conversions():
    # Foxglove's messages are opaque; their protobuf encodings carry what we put in
    ann = image_annotations(VERTS).encode()
    for u, v in ((10, 20), (20, 10), (30, 20), (20, 30)):  # + 0.5: Foxglove's pixel origin
        assert struct.pack("<d", u + 0.5) in ann and struct.pack("<d", v + 0.5) in ann
    miss = image_annotations(MarkerVertices(seq=2, stamp_ns=5, found=False, reason="too dark"))
    assert b"no marker: too dark" in miss.encode()
    data = image(np.zeros((48, 64, 3), np.uint8), 5).encode()
    start = data.index(b"\xff\xd8")
    jpeg = data[start:data.rindex(b"\xff\xd9") + 2]
    assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), 1).shape == (48, 64, 3)
    scene = floor_scene(5, POSE, None, None, None, [(0.6, 0.0)],
                        World(obstacles=[CircleObstacle(x=1, y=0, radius=0.1)])).encode()
    for name in (b"humanoid (estimated)", b"waypoints", b"obstacles"):
        assert name in scene
    assert b"humanoid (truth)" not in scene


def _recv(s: socket.socket) -> bytes:
    """The next bytes from ``s``; a closed connection is an error, never an endless loop."""
    data = s.recv(65536)
    if not data:
        raise ConnectionError("the server closed the connection")
    return data


def _fill(s: socket.socket, buf: bytes, n: int) -> bytes:
    """``buf`` with bytes from ``s`` until it holds at least ``n``."""
    while len(buf) < n:
        buf += _recv(s)
    return buf


def _handshake(port: int, timeout: float) -> tuple[socket.socket, bytes]:
    """A WebSocket connection as a Foxglove client, and the bytes after the server's answer."""
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
               "Sec-WebSocket-Version: 13\r\n"
               "Sec-WebSocket-Protocol: foxglove.sdk.v1, foxglove.websocket.v1\r\n\r\n"
               ).encode())
    buf = b""
    try:
        while b"\r\n\r\n" not in buf:
            buf += _recv(s)
    except OSError:
        s.close()
        raise
    head, buf = buf.split(b"\r\n\r\n", 1)
    assert b" 101 " in head.split(b"\r\n")[0], head
    return s, buf


def _ws_messages(port: int, want: set[str], timeout: float = 10.0) -> dict[str, str]:
    """Connect as a Foxglove client (raw WebSocket) and collect advertised topics with their
    schema names (the handshake tried again until ``timeout`` s where the server drops it)."""
    end = time.monotonic() + timeout
    while True:
        try:
            s, buf = _handshake(port, timeout)
            break
        except OSError as e:
            assert time.monotonic() < end, f"no WebSocket handshake in {timeout} s: {e}"
            time.sleep(0.2)
    topics: dict[str, str] = {}
    with s:
        while not want <= set(topics) and time.monotonic() < end:
            buf = _fill(s, buf, 2)
            opcode, n = buf[0] & 0x0F, buf[1] & 0x7F
            off = 2
            if n == 126:
                buf = _fill(s, buf, 4)
                n, off = int.from_bytes(buf[2:4], "big"), 4
            elif n == 127:
                buf = _fill(s, buf, 10)
                n, off = int.from_bytes(buf[2:10], "big"), 10
            buf = _fill(s, buf, off + n)
            payload, buf = buf[off:off + n], buf[off + n:]
            if opcode == 1:
                msg = json.loads(payload)
                if msg.get("op") == "advertise":
                    topics |= {c["topic"]: c.get("schemaName", "") for c in msg["channels"]}
    return topics


def test_live_view_serves_the_camera_and_the_floor_plan(router, make_bus):
    port = free_port()
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"viz": {"port": port, "fps": 20}}})
    bus = make_bus("feeder")
    frame = render_marker(0.3).image

    async def go() -> dict[str, str]:
        # (cancelled once the topics are in: the duration only bounds a hung test)
        task = asyncio.create_task(run_deployment(dep, duration=120))
        await wait_alive_async(bus.session, "viz")
        for k in range(10):
            publish_frame(bus, frame, k)
            bus.put(VERTICES, VERTS)
            bus.put(HUMANOID_POSE, POSE)
            await asyncio.sleep(0.1)
        topics = await asyncio.to_thread(
            _ws_messages, port, {"/camera/image", "/camera/annotations", "/floor",
                                 "/humanoid/pose"})
        task.cancel()
        return topics
    topics = asyncio.run(go())
    assert {"/camera/image", "/camera/annotations", "/floor", "/humanoid/pose"} <= set(topics)
    assert topics["/humanoid/pose"] == "shepherd.HumanoidPose"  # not a generated name
    assert topics["/camera/image"] == "foxglove.CompressedImage"


@pytest.fixture(scope="session")
def foxglove_js(tmp_path_factory) -> Path:
    """The official @foxglove/ws-protocol client and ws, installed from the npm registry."""
    where = tmp_path_factory.mktemp("js")
    shutil.copy(ROOT / "tests" / "js" / "foxglove_client.js", where)
    res = subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--silent",
                          "@foxglove/ws-protocol@0.8", "ws@8"], cwd=where, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, f"npm install failed: {res.stderr[-2000:]}"
    return where


def test_the_official_foxglove_client_with_the_older_subprotocol_gets_every_channel(
        router, make_bus, foxglove_js: Path):
    """What Lichtblick and older Foxglove apps offer (foxglove.websocket.v1) works too."""
    port = free_port()
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"viz": {"port": port, "fps": 20}}})
    bus = make_bus("feeder")
    frame = render_marker(0.3).image

    async def go() -> subprocess.CompletedProcess[str]:
        task = asyncio.create_task(run_deployment(dep, duration=60))
        await wait_alive_async(bus.session, "viz")
        client = asyncio.create_task(asyncio.to_thread(
            subprocess.run, ["node", "foxglove_client.js", f"ws://127.0.0.1:{port}", "5", "30"],
            cwd=foxglove_js, capture_output=True, text=True, timeout=60))
        while not client.done():
            publish_frame(bus, frame, 1)
            bus.put(VERTICES, VERTS)
            bus.put(HUMANOID_POSE, POSE)
            bus.put(MISSION_STATE, STATE)
            await asyncio.sleep(0.1)
        task.cancel()
        return client.result()
    out = asyncio.run(go())
    assert out.returncode == 0, out.stderr
    got = {m["topic"]: m for m in map(json.loads, out.stdout.splitlines())}
    assert set(got) == {"/camera/image", "/camera/annotations", "/floor", "/humanoid/pose",
                        "/mission/state"}
    assert {m["protocol"] for m in got.values()} == {"foxglove.websocket.v1"}
    assert got["/humanoid/pose"]["schemaName"] == "shepherd.HumanoidPose"
    assert got["/humanoid/pose"]["decoded"]["x"] == pytest.approx(POSE.x)
    assert got["/mission/state"]["schemaName"] == "shepherd.MissionState"
    assert got["/camera/image"]["bytes"] > 1000


def test_a_client_connected_when_the_viz_stops_ends_without_an_error() -> None:
    """The front's connection handler, cancelled with a client connected (the service
    stopping), closes the client and ends: Python 3.11's server reported a cancelled
    handler as an error, with a traceback at every stop with Foxglove connected."""
    from services.viz.negotiate import serve_both_subprotocols
    errors: list[dict] = []

    async def sdk(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        await r.readuntil(b"\r\n\r\n")  # the SDK's server, as far as the handshake goes
        w.write(b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n"
                b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n")
        await w.drain()
        await r.read()  # until the front closes its side
        w.close()

    async def go() -> bytes:
        asyncio.get_running_loop().set_exception_handler(lambda _, ctx: errors.append(ctx))
        upstream = await asyncio.start_server(sdk, "127.0.0.1", 0)
        front = await serve_both_subprotocols("127.0.0.1", 0, upstream.sockets[0].getsockname()[1])
        r, w = await asyncio.open_connection(*front.sockets[0].getsockname()[:2])
        w.write(b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                b"Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n")
        answer = await r.readuntil(b"\r\n\r\n")
        handlers = [t for t in asyncio.all_tasks()
                    if getattr(t.get_coro(), "__name__", "") == "_serve"]
        assert len(handlers) == 1
        handlers[0].cancel()  # what stopping the service does to it
        closed = await asyncio.wait_for(r.read(), 5)  # the client is closed
        assert closed == b""
        w.close()
        front.close()
        upstream.close()
        await asyncio.sleep(0.1)
        return answer
    answer = asyncio.run(go())
    assert b" 101 " in answer and b"foxglove.websocket.v1" in answer  # (the older subprotocol)
    assert errors == []
