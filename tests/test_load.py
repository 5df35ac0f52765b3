"""Load: 640x480 frames published flat out for a minute (SHEPHERD_LOAD_S to change) into the
vertex extractor and pose estimator in their own process: memory stays flat, latency stays
bounded, and the newest frame is the one processed."""

import asyncio
import os
import time
from pathlib import Path

import numpy as np
import pytest

from schemas import HumanoidPose
from schemas.keys import HUMANOID_POSE
from services.runtime.frames import encode_frame
from tests.conftest import ROOT, spawn_cli, wait_alive_async, wait_for
from tests.helpers.fake_frames import render_marker

# end-to-end: left out of `make test-fast`; in real time, so `make test` runs it on the
# worker of the other real-time tests, one after another
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("realtime")]

LOAD_S = float(os.environ.get("SHEPHERD_LOAD_S", "60"))
TAIL_FRAMES, TAIL_PERIOD_S = 10, 0.05  # frames sent after the flood, and their spacing


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def test_frames_flat_out_for_a_minute(tmp_path: Path, router, make_bus):
    dep = tmp_path / "vision.toml"
    dep.write_text(f'[zenoh]\nconnect = ["{router}"]\nmulticast_scouting = false\n'
                   "[services.vertex_extractor]\n[services.pose_estimator]\n"
                   f'intrinsics = "{ROOT / "deploy/paper-camera.toml"}"\n'
                   "static_camera_pose = [0.0, 0.0, 0.0]\n")
    proc = spawn_cli("--log-level", "WARNING", "run", str(dep))
    frames = [render_marker(0.3 + 0.01 * k, seed=k).image for k in range(8)]
    bus = make_bus("flood")

    async def go() -> tuple[list[tuple[float, int]], list[tuple[float, float]], int, int]:
        poses = bus.subscribe_stamped(HUMANOID_POSE, HumanoidPose, queue=100000)
        await wait_alive_async(bus.session, "vertex_extractor", "pose_estimator")
        rss: list[tuple[float, int]] = []
        t0 = time.monotonic()
        seq = 0
        sent_ns: dict[int, int] = {}
        next_sample = 0.0
        while (elapsed := time.monotonic() - t0) < LOAD_S:
            stamp = time.time_ns()
            header, payload = encode_frame(frames[seq % len(frames)], seq, stamp)
            bus.put_frame(header, payload)
            sent_ns[seq] = stamp
            seq += 1
            if elapsed >= next_sample:
                rss.append((elapsed, _rss_kb(proc.pid)))
                next_sample += LOAD_S / 24
            await asyncio.sleep(0)
        # then a few at a walking pace: one of them must come back as a pose. A frame put in
        # the flood's last instant may be dropped on the way, as any frame under congestion
        # (frames are dropped, never queued), and then no pose of the last ten ever comes
        for _ in range(TAIL_FRAMES):
            stamp = time.time_ns()
            header, payload = encode_frame(frames[seq % len(frames)], seq, stamp)
            bus.put_frame(header, payload)
            sent_ns[seq] = stamp
            seq += 1
            await asyncio.sleep(TAIL_PERIOD_S)
        last_sent = seq - 1
        lat: list[tuple[float, float]] = []
        last_pose = -1

        def take() -> bool:  # until a pose of one of the last frames (not a fixed wait)
            nonlocal last_pose
            while (item := poses.get_nowait()) is not None:
                recv, p = item
                lat.append(((sent_ns[p.seq] - sent_ns[0]) / 1e9, (recv - sent_ns[p.seq]) / 1e6))
                last_pose = max(last_pose, p.seq)
            return last_sent - last_pose <= 10
        await wait_for(take, "a pose of one of the last 10 frames")
        return rss, lat, last_sent, last_pose

    try:
        rss, lat, last_sent, last_pose = asyncio.run(go())
    finally:
        proc.terminate()
        proc.communicate(timeout=10)
    t = np.array([a for a, _ in lat])
    ms = np.array([b for _, b in lat])
    early, late = ms[t < LOAD_S / 4], ms[t > 3 * LOAD_S / 4]
    # a leak shows as a trend: the last quarter's median against the second quarter's
    warm = float(np.median([kb for t_s, kb in rss if LOAD_S / 4 <= t_s < LOAD_S / 2]))
    end = float(np.median([kb for t_s, kb in rss if t_s >= 3 * LOAD_S / 4]))
    growth = (end - warm) / warm
    print(f"\nload: {last_sent + 1} frames in {LOAD_S:.0f} s ({(last_sent + 1) / LOAD_S:.0f}/s), "
          f"{len(lat)} poses ({len(lat) / LOAD_S:.0f}/s); latency p50 first quarter "
          f"{np.median(early):.1f} ms, last quarter {np.median(late):.1f} ms; RSS "
          f"{warm / 1024:.0f} MB (second quarter) -> {end / 1024:.0f} MB (last quarter) "
          f"({100 * growth:+.1f}%); samples "
          f"{[(round(t_s), kb // 1024) for t_s, kb in rss]}")
    # it keeps processing, in every quarter of the run (a rate would be the machine's, and a
    # benchmark's business: see the figures printed above)
    quarters = np.histogram(t, bins=4, range=(0, LOAD_S))[0]
    assert np.all(quarters > 0), quarters
    # no growing backlog: the last quarter's latency against the first quarter's, both
    # measured on the same machine under the same load
    assert np.median(late) < 2 * np.median(early) + 20
    # (the 95th percentile: a neighbouring test's burst on a two-core CI machine put over 1 %
    # of the last quarter's 2 600 poses 280-450 ms late once; a backlog moves this too)
    assert np.percentile(late, 95) < 2 * np.percentile(early, 95) + 100
    assert last_sent - last_pose <= 10  # the newest frames are the ones processed
    assert growth < 0.05, [(round(t_s, 1), kb // 1024) for t_s, kb in rss]
