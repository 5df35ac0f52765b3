"""``shepherd bench --only e2e``: frame to humanoid/pose through the services."""

from __future__ import annotations

import asyncio
import contextlib
import sys
import time

import numpy as np

from services.tools.bench.common import Row, endpoint, progress, section

E2E_DEPLOYMENT = """
[zenoh]
connect = ["{ep}"]
multicast_scouting = false
[services.vertex_extractor]
[services.pose_estimator]
intrinsics = "{intrinsics}"
static_camera_pose = [0.0, 0.0, 0.0]
"""


def run(quick: bool) -> None:
    """Frame published -> humanoid/pose received, through the vertex extractor and pose
    estimator services, in one process and with one process per service."""
    import subprocess
    import tempfile
    from pathlib import Path

    from services.data import PAPER_CAMERA
    from services.runtime.config import load_deployment
    from services.runtime.launcher import run_deployment
    dur = 3.0 if quick else 8.0
    frames = _e2e_frames(60)
    ep = endpoint()
    rows: list[Row] = []
    intrinsics = PAPER_CAMERA
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "e2e.toml"
        path.write_text(E2E_DEPLOYMENT.format(ep=ep, intrinsics=intrinsics))
        dep = load_deployment(path)
        for mode in E2E_MODES:
            for rate in (30.0, None):
                progress(f"e2e: {mode}, {'30 fps' if rate else 'flat out'}")
                if mode == E2E_MODES[0]:
                    res = asyncio.run(_e2e_run(ep, frames, rate, dur, lambda s: run_deployment(
                        dep, duration=dur + 4, session=s)))
                elif mode == E2E_MODES[1]:
                    res = asyncio.run(_e2e_run(ep, frames, rate, dur, lambda s: run_deployment(
                        dep, duration=dur + 4)))
                else:
                    proc = subprocess.Popen([sys.executable, "-m", "services.tools.cli",
                                             "--log-level", "WARNING", "run", str(path),
                                             "--processes"])
                    try:
                        res = asyncio.run(_e2e_run(ep, frames, rate, dur, None))
                    finally:
                        proc.terminate()
                        proc.wait(10)
                lat, sent, got, first, last = res
                rows.append((mode, "30 fps" if rate else "flat out", f"{sent / dur:.0f}",
                             f"{got / dur:.0f}", f"{np.median(lat):.2f}",
                             f"{np.percentile(lat, 99):.2f}", f"{first:.2f} -> {last:.2f}"))
    section("End to end: frame published -> humanoid/pose received (640x480 bgr8)",
             ("deployment", "rate", "frames/s sent", "poses/s", "p50 ms", "p99 ms",
              "p50 first s -> last s"), rows,
             "Latest-value frames: when the services fall behind, old frames are dropped, so "
             "the latency stays flat (last column) instead of growing. One session: the "
             "publisher shares the services' Zenoh session, as the simulator does in `shepherd "
             "run`; own session: the publisher is a second session in the process, reaching the "
             "services over TCP loopback, as a frame source on another machine would. Event "
             f"loop: {type(asyncio.get_event_loop_policy()).__module__.split('.')[0]}. Goal: "
             "p50 <= 1.5 ms and p99 <= 5 ms in one process at 30 fps; >= 200 frames/s "
             "sustained flat out.")


E2E_MODES = ("one process, one session", "one process, publisher's own session (TCP)",
             "one process per service")


def _e2e_frames(n: int) -> list[np.ndarray]:
    from schemas import Command
    from services.core.camera import CameraModel
    from services.core.mounts import Geometry
    from services.core.world import World
    from services.sim.state import SimWorld
    sim = SimWorld(camera=CameraModel.paper(), geometry=Geometry(), world=World(),
                   humanoid_start=(0.29, 0.0, 0.0), camera_start=(0.0, 0.0, 0.0))
    sim.command(Command.WALK_FORWARD)
    out = []
    for _ in range(n):
        sim.step(1 / 30)
        out.append(sim.render().image)
    return out


async def _e2e_run(ep: str, frames: list[np.ndarray], rate: float | None, duration: float,
                   services) -> tuple[np.ndarray, int, int, float, float]:
    from schemas import HumanoidPose, Keys
    from schemas.keys import HUMANOID_POSE
    from services.runtime.bus import Bus
    from services.runtime.frames import encode_frame
    from services.runtime.session import ZenohSettings, open_session
    with open_session(ZenohSettings(listen=[ep], multicast_scouting=False)) as session:
        bus = Bus(session, Keys("shepherd"), "bench")
        poses = bus.subscribe_stamped(HUMANOID_POSE, HumanoidPose, queue=100000)
        task = asyncio.create_task(services(session)) if services else None
        await asyncio.sleep(2.5)  # services up, intrinsics loaded, discovery done
        sent_at: dict[int, int] = {}
        t0 = time.monotonic()
        seq = 0

        def publish() -> None:
            nonlocal seq
            stamp = time.time_ns()
            header, payload = encode_frame(frames[seq % len(frames)], seq, stamp)
            bus.put_frame(header, payload)
            sent_at[seq] = stamp
            seq += 1

        if rate:  # from the event loop, as the simulator service publishes
            while time.monotonic() - t0 < duration:
                publish()
                await asyncio.sleep(max(0.0, t0 + seq / rate - time.monotonic()))
        else:  # from a thread of its own, as a camera driver would: never starves the loop
            def flat_out() -> None:
                while time.monotonic() - t0 < duration:
                    publish()
                    time.sleep(0)  # let the services' thread have the GIL

            await asyncio.to_thread(flat_out)
        await asyncio.sleep(0.5)
        lat, when = [], []
        while (item := poses.get_nowait()) is not None:
            recv, p = item
            if p.seq in sent_at:
                lat.append((recv - sent_at[p.seq]) / 1e6)
                when.append((sent_at[p.seq] / 1e9) - (sent_at[0] / 1e9))
        if task:
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
        bus.close()
    lat_a, when_a = np.array(lat or [float("nan")]), np.array(when or [0.0])
    first = float(np.median(lat_a[when_a < 1.0])) if np.any(when_a < 1.0) else float("nan")
    last = float(np.median(lat_a[when_a > duration - 1.0])) if np.any(
        when_a > duration - 1.0) else float("nan")
    return lat_a, seq, len(lat), first, last
