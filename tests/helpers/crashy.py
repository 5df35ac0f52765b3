"""A service for launcher tests: crashes on its first two starts, then runs."""

from __future__ import annotations

import asyncio

from services.runtime.config import ServiceSettings

STARTS: list[int] = []
SESSIONS: list[object] = []  # the Zenoh session of each start
LOCAL_DELIVERY: list[bool] = []  # the bus's local_delivery at each start


class Settings(ServiceSettings):
    pass


async def main(ctx, config: Settings) -> None:
    STARTS.append(len(STARTS))
    SESSIONS.append(ctx.bus.session)
    LOCAL_DELIVERY.append(ctx.bus.local_delivery)
    if len(STARTS) <= 2:
        raise RuntimeError(f"deliberate crash number {len(STARTS)}")
    while True:
        await asyncio.sleep(0.1)
