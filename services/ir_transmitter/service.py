"""The ``ir_transmitter`` service: ``ir/command`` -> the humanoid, through a swappable backend.

Commands are sent in order, at least ``min_gap_s`` apart; a repeat of the command last sent
within ``repeat_window_s`` is coalesced (counted, not sent). A put on ``ir/backend`` swaps the
backend after the command in flight; a bad request is rejected with its reason and the old
backend stays. A query on ``ir/backend`` returns the backend and its counters. While a serial
device is unplugged, commands are reported as failed; after it comes back the latest command
is sent only if it is younger than ``fresh_s``. ``stop`` is sent at shutdown.

The controller's commands (those with a session) go through the freshness gate
(:mod:`services.ir_transmitter.freshness`): what arrives together collapses to its newest, and
after a network cut nothing decided before it moves the humanoid; a motion command the gate
drops while the humanoid moves sends ``stop``. The dead-man counts fresh commands only.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from schemas import Command, IrBackendRequest, IrBackendStatus, IrCommand
from schemas.keys import IR_BACKEND, IR_COMMAND, SIM_IR
from services.ir_transmitter.backends import BackendError, IrBackend, make_backend
from services.ir_transmitter.freshness import OLD, FreshnessGate, FreshnessParams, Verdict
from services.runtime.config import ServiceSettings
from services.runtime.context import ServiceContext

T = TypeVar("T")

BackendName = Literal["serial", "lirc", "sim", "log"]


class BackendChoice(BaseModel):
    """A backend with its options (serial port, LIRC socket or host, ...)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    backend: BackendName
    options: dict[str, Any] = Field(default_factory=dict)


class Settings(ServiceSettings, FreshnessParams):
    """The freshness gate's parameters (``FreshnessParams``, the dead-man's among them) and
    the transmitter's own."""

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
    controller: str = Field(default="mission_controller", description=(
        "the service whose liveliness token going away sends stop at once ('' for none)"))


class Transmitter:
    """Sequencing, coalescing, counters and hot swap around one backend (no bus inside)."""

    def __init__(self, backend: IrBackend, config: Settings) -> None:
        self.backend, self.config = backend, config
        # the backend's own thread: a stop never waits behind other services' blocking calls
        # (queries of up to 2 s) in the loop's shared executor
        self._io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ir-backend")
        self.sent = self.failed = self.coalesced = self.deadman_stops = 0
        self.gate = FreshnessGate(config.part(FreshnessParams))
        self.superseded = 0   # passed the gate, but a newer one came with it
        self.last_error = ""
        self._last: tuple[Command, float] | None = None
        self.pending: IrCommand | None = None  # latest command that failed to go out

    async def call(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` on the backend's own thread."""
        return await asyncio.get_running_loop().run_in_executor(self._io, fn, *args)

    def close(self) -> None:
        """Let the backend's thread go (after the last send)."""
        self._io.shutdown(wait=False)

    def status(self) -> IrBackendStatus:
        return IrBackendStatus(backend=self.backend.name, options=self.backend.options,
                               sent=self.sent, failed=self.failed, coalesced=self.coalesced,
                               deadman_stops=self.deadman_stops,
                               not_fresh={**self.gate.dropped, "superseded": self.superseded},
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
            await self.call(self.backend.send, cmd)
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
            await self.call(beat)
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
        if reconnect is not None and await self.call(reconnect):
            await self.send(cmd)

    @property
    def moving(self) -> bool:
        """The last command that went out set the humanoid moving."""
        return self._last is not None and self._last[0] is not Command.STOP

    async def deadman_stop(self, why: str) -> None:
        """Stop the humanoid because its controller is gone or silent."""
        self.deadman_stops += 1
        self.gate.disarm()
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


async def relay(tx: Transmitter, batch: list[tuple[int, IrCommand]],
                log: logging.Logger) -> bool:
    """Send what arrived together (``(arrival monotonic ns, command)``, oldest first):
    one-shots in order, the controller's commands collapsed to the newest, if fresh. True
    if a fresh command came (it feeds the dead-man)."""
    fresh = False
    newest: tuple[IrCommand, Verdict] | None = None
    passed = 0
    for arrival_ns, cmd in batch:
        if cmd.session is None:
            fresh = True
            if not await tx.send(cmd):
                log.warning("IR %s not sent: %s", cmd.command.value, tx.last_error)
            continue
        verdict = tx.gate.judge(cmd, arrival_ns / 1e9)
        passed += verdict.send
        if newest is None or verdict.reason != OLD:  # the newest seen so far
            newest = (cmd, verdict)
    if newest is None:
        return fresh
    cmd, (ok, why) = newest[0], (newest[1].send, newest[1].reason)
    tx.superseded += passed - ok
    if ok:
        if not await tx.send(cmd):
            log.warning("IR %s not sent: %s", cmd.command.value, tx.last_error)
        return True
    log.info("IR %s #%s not sent: %s", cmd.command.value, cmd.seq, why)
    if tx.moving:
        await tx.deadman_stop(f"{cmd.command.value} #{cmd.seq} not fresh ({why})")
    return fresh


async def main(ctx: ServiceContext, config: Settings) -> None:
    bus, log = ctx.bus, ctx.log

    def publish_sim(cmd: IrCommand) -> None:
        bus.put(SIM_IR, cmd)

    tx = Transmitter(make_backend(config.backend, dict(config.options), publish_sim), config)
    log.info("IR backend %s %s", tx.backend.name, tx.backend.options)
    commands = bus.subscribe_stamped(IR_COMMAND, IrCommand, queue=64, clock=time.monotonic_ns)
    requests = bus.subscribe(IR_BACKEND, IrBackendRequest, latest=False, queue=8)
    bus.declare_queryable(IR_BACKEND, tx.status)
    tokens = bus.subscribe_liveliness(bus.keys.alive(config.controller)) \
        if config.controller else None
    pending: set[asyncio.Future[Any]] = set()
    last_beat = last_command = time.monotonic()
    try:
        while True:
            cmd_task: asyncio.Future[tuple[int, IrCommand]] = asyncio.ensure_future(
                commands.recv())
            req_task: asyncio.Future[IrBackendRequest] = asyncio.ensure_future(requests.recv())
            pending = {cmd_task, req_task}
            wake_s = config.heartbeat_s  # sooner when the dead-man is due
            if config.deadman_s and tx.moving:
                wake_s = min(wake_s, max(0.01, config.deadman_s
                                         - (time.monotonic() - last_command) + 0.005))
            done, _ = await asyncio.wait(pending, timeout=wake_s,
                                         return_when=asyncio.FIRST_COMPLETED)
            for task in (cmd_task, req_task):
                if task not in done:
                    task.cancel()
            while tokens is not None and (token := tokens.get_nowait()) is not None:
                if not token[1]:
                    tx.gate.disarm()
                    if tx.moving:
                        await tx.deadman_stop(
                            f"{config.controller}'s liveliness token went away")
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
                if await relay(tx, [cmd_task.result(), *iter(commands.get_nowait, None)], log):
                    last_command = time.monotonic()
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
            await asyncio.wait_for(tx.call(tx.backend.send, IrCommand(command=Command.STOP)),
                                   1.0)
            log.info("sent stop at shutdown")
        except Exception as err:
            log.error("could not send stop at shutdown: %r", err)
        tx.backend.close()
        tx.close()
