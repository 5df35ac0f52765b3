"""``shepherd soak``: the simulated mission driven back and forth for a long time, with the
process's memory sampled every minute; exit 0 if it grew less than 5% after warm-up."""

from __future__ import annotations

import asyncio
import sys
import time
from pathlib import Path

from services.runtime.config import Deployment


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


async def soak(dep: Deployment, minutes: float, sample_s: float = 60.0) -> int:
    from services.runtime.launcher import run_deployment
    mc = dep.settings.get("mission_controller")
    if mc is None or not mc.waypoints:
        print("shepherd: soak needs a mission_controller with waypoints", file=sys.stderr)
        return 2
    dep.settings["mission_controller"] = mc.model_copy(update={"loop": True,
                                                               "exit_when_done": False})
    dep.settings.pop("monitor", None)
    dep.services.pop("monitor", None)
    samples: list[tuple[float, float]] = []
    t0 = time.monotonic()

    last_s = max(minutes * 60 - 1.0, 0.0)  # the last sample a second before the run ends

    async def sample() -> None:
        while True:
            elapsed = time.monotonic() - t0
            samples.append((elapsed / 60, _rss_mb()))
            m, rss = samples[-1]
            print(f"  {m:6.1f} min  RSS {rss:7.1f} MB", flush=True)
            if elapsed >= last_s - 0.1:
                return
            await asyncio.sleep(min(sample_s, last_s - elapsed))

    sampler = asyncio.create_task(sample())
    try:
        await run_deployment(dep, duration=minutes * 60)
    finally:
        sampler.cancel()
    # the verdict is on the running services: what their shutdown allocates is no leak (under
    # load it was 40 MB once, after a steady run), so it is printed beside it, not counted
    after = _rss_mb()
    warm = samples[1] if len(samples) > 2 else samples[0]
    growth = (samples[-1][1] - warm[1]) / warm[1]
    print(f"\nsoak: {minutes:g} min; RSS {warm[1]:.1f} MB after warm-up -> "
          f"{samples[-1][1]:.1f} MB at the end ({100 * growth:+.1f}%); goal < 5% "
          f"({after:.1f} MB after the shutdown)")
    return 0 if growth < 0.05 else 1
