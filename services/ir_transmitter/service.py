"""The ``ir_transmitter`` service: ``ir/command`` -> the humanoid, through a swappable backend.

Commands are sent in order, at least ``min_gap_s`` apart; a repeat of the command last sent
within ``repeat_window_s`` is coalesced (counted, not sent). A put on ``ir/backend`` swaps the
backend after the command in flight; a bad request is rejected with its reason and the old
backend stays. A query on ``ir/backend`` returns the backend and its counters. While a serial
device is unplugged, commands are reported as failed; after it comes back the latest command
is sent only if it is younger than ``fresh_s``. ``stop`` is sent at shutdown.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas import Command, IrBackendRequest, IrBackendStatus, IrCommand
from schemas.keys import IR_BACKEND, IR_COMMAND, SIM_IR
from services.ir_transmitter.backends import BackendError, IrBackend, make_backend
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext

BackendName = Literal["serial", "lirc", "sim", "log"]


class BackendChoice(BaseModel):
    """A backend with its options (serial port, LIRC socket or host, ...)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    backend: BackendName
    options: dict[str, Any] = Field(default_factory=dict)


class Settings(ServiceSettings):
    backend: BackendName = Field(default="log", description=(
        "serial (the Arduino), lirc, sim (the simulator) or log (only logs)"))
    options: dict[str, Any] = Field(default_factory=dict, description=(
        "the backend's: serial { port, baud, ... }, lirc { socket, remote, timeout_s }"))
    allowed: list[BackendChoice] = Field(default_factory=list, description=(
        "what a put on ir/backend may switch to, besides the backend above (exactly these "
        "options); anything else is rejected"))
    min_gap_s: float = Field(default=0.06, ge=0.0, description="between IR frames (>= 30 ms)")
    repeat_window_s: float = Field(default=0.5, ge=0.0, description=(
        "a repeat of the command last sent this soon is coalesced"))
    fresh_s: float = Field(default=1.0, gt=0.0,
                           description="after a lost device returns, resend only this young")
    heartbeat_s: float = Field(default=0.15, gt=0.0, le=0.3,
                               description="heartbeat to the firmware's 0.4 s watchdog")
    deadman_s: float = Field(default=0.5, ge=0.0, description=(
        "dead-man: send stop when the humanoid moves and no command (the controller's "
        "keepalive included) came for this long; 0 turns it off"))
    controller: str = Field(default="mission_controller", description=(
        "the service whose liveliness token going away sends stop at once ('' for none)"))


class Transmitter:
    """Sequencing, coalescing, counters and hot swap around one backend (no bus inside)."""

    def __init__(self, backend: IrBackend, config: Settings) -> None:
        self.backend, self.config = backend, config
        self.sent = self.failed = self.coalesced = self.deadman_stops = 0
        self.last_error = ""
        self._last: tuple[Command, float] | None = None
        self.pending: IrCommand | None = None  # latest command that failed to go out

    def status(self) -> IrBackendStatus:
        return IrBackendStatus(backend=self.backend.name, options=self.backend.options,
                               sent=self.sent, failed=self.failed, coalesced=self.coalesced,
                               deadman_stops=self.deadman_stops,
                               unacked=getattr(self.backend, "unacked", 0),
                               firmware_watchdog_stops=getattr(self.backend, "watchdog_stops", 0),
                               connected=self.backend.connected, last_error=self.last_error)

    async def send(self, cmd: IrCommand) -> bool:
        now = time.monotonic()
        if (self._last and self._last[0] is cmd.command
                and now - self._last[1] < self.config.repeat_window_s):
            self.coalesced += 1
            return True
        if self._last is not None:
            wait = self.config.min_gap_s - (now - self._last[1])
            if wait > 0:
                await asyncio.sleep(wait)
        try:
            await asyncio.to_thread(self.backend.send, cmd)
        except BackendError as err:
            self.failed += 1
            self.last_error = str(err)
            self.pending = cmd
            return False
        self.sent += 1
        self.pending = None
        self._last = (cmd.command, time.monotonic())
        return True

    async def heartbeat(self) -> None:
        """Keep the firmware's watchdog fed (serial backend only)."""
        beat = getattr(self.backend, "heartbeat", None)
        if beat is None:
            return
        try:
            await asyncio.to_thread(beat)
        except BackendError as err:
            self.last_error = str(err)

    async def retry_pending(self) -> None:
        """After a reconnect: resend the latest failed command if still fresh."""
        cmd = self.pending
        if cmd is None:
            return
        age = (time.time_ns() - cmd.stamp_ns) / 1e9
        if age > self.config.fresh_s:
            self.pending = None
            return
        reconnect = getattr(self.backend, "reconnect", None)
        if reconnect is not None and await asyncio.to_thread(reconnect):
            await self.send(cmd)

    @property
    def moving(self) -> bool:
        """The last command that went out set the humanoid moving."""
        return self._last is not None and self._last[0] is not Command.STOP

    async def deadman_stop(self, why: str) -> None:
        """Stop the humanoid because its controller is gone or silent."""
        self.deadman_stops += 1
        logging.getLogger("shepherd.ir_transmitter").warning("dead-man: %s; sending stop", why)
        if not await self.send(IrCommand(command=Command.STOP)):
            logging.getLogger("shepherd.ir_transmitter").error(
                "dead-man stop not sent: %s", self.last_error)

    def swap(self, backend: IrBackend) -> None:
        old, self.backend = self.backend, backend
        self._last = None
        old.close()


def allowed_or_raise(config: Settings, request: IrBackendRequest) -> None:
    """Raise ValueError unless the deployment file allows switching to ``request``."""
    choice = BackendChoice(backend=request.backend, options=request.options)
    allowed = [BackendChoice(backend=config.backend, options=config.options), *config.allowed]
    if choice not in allowed:
        listed = "; ".join(f"{a.backend} {a.options}" for a in allowed)
        raise ValueError(f"{request.backend} {request.options} is not allowed by the "
                         f"deployment file (allowed: {listed})")


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log

    def publish_sim(cmd: IrCommand) -> None:
        bus.put(SIM_IR, cmd)

    tx = Transmitter(make_backend(config.backend, dict(config.options), publish_sim), config)
    log.info("IR backend %s %s", tx.backend.name, tx.backend.options)
    commands = bus.subscribe(IR_COMMAND, IrCommand, latest=False, queue=64)
    requests = bus.subscribe(IR_BACKEND, IrBackendRequest, latest=False, queue=8)
    bus.declare_queryable(IR_BACKEND, tx.status)
    tokens = bus.subscribe_liveliness(bus.keys.alive(config.controller)) \
        if config.controller else None
    pending: set[asyncio.Future[Any]] = set()
    last_beat = last_command = time.monotonic()
    try:
        while True:
            cmd_task: asyncio.Future[IrCommand] = asyncio.ensure_future(commands.recv())
            req_task: asyncio.Future[IrBackendRequest] = asyncio.ensure_future(requests.recv())
            pending = {cmd_task, req_task}
            done, _ = await asyncio.wait(pending, timeout=config.heartbeat_s,
                                         return_when=asyncio.FIRST_COMPLETED)
            for task in (cmd_task, req_task):
                if task not in done:
                    task.cancel()
            while tokens is not None and (token := tokens.get_nowait()) is not None:
                if not token[1] and tx.moving:
                    await tx.deadman_stop(f"{config.controller}'s liveliness token went away")
            # a cancelled recv() may have taken nothing; results of finished ones are used
            if req_task in done:
                req = req_task.result()
                try:
                    allowed_or_raise(config, req)
                    new = make_backend(req.backend, dict(req.options), publish_sim)
                except Exception as err:
                    tx.last_error = f"backend request rejected: {err}"
                    log.warning("%s; keeping %s", tx.last_error, tx.backend.name)
                else:
                    log.info("IR backend %s -> %s %s", tx.backend.name, new.name, new.options)
                    tx.swap(new)
            if cmd_task in done:
                cmd = cmd_task.result()
                last_command = time.monotonic()
                if not await tx.send(cmd):
                    log.warning("IR %s not sent: %s", cmd.command.value, tx.last_error)
            else:
                await tx.retry_pending()
            silent_s = time.monotonic() - last_command
            if config.deadman_s and tx.moving and silent_s > config.deadman_s:
                await tx.deadman_stop(f"no command for {1000 * silent_s:.0f} ms")
            if time.monotonic() - last_beat >= config.heartbeat_s:
                await tx.heartbeat()
                last_beat = time.monotonic()
    finally:
        for task in pending:
            task.cancel()
        try:
            await asyncio.wait_for(asyncio.to_thread(tx.backend.send,
                                                     IrCommand(command=Command.STOP)), 1.0)
            log.info("sent stop at shutdown")
        except Exception as err:
            log.error("could not send stop at shutdown: %s", err)
        tx.backend.close()
