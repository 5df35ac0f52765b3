"""Start the services a deployment file names, supervise them, stop them cleanly.

One process: every service is an asyncio task sharing one Zenoh session, each with its own
:class:`~services.runtime.bus.Bus` (and liveliness token). A service that raises is logged with its
traceback and restarted with exponential backoff. A service marked ``process = true`` (or all,
with ``--processes``) runs as a child ``shepherd run FILE --only NAME``; a child that dies is
restarted the same way. SIGINT/SIGTERM cancel every service (their ``finally`` blocks run,
e.g. the IR transmitter sends ``stop``) and the launcher returns within about 2 s.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import sys
from dataclasses import dataclass, field
from typing import Any

import zenoh

from schemas import Keys, ServiceStats
from schemas.keys import STATS
from services.runtime.bus import Bus
from services.runtime.config import Deployment
from services.runtime.context import ServiceContext
from services.runtime.mailbox import Rejections
from services.runtime.registry import load_service
from services.runtime.session import open_session

log = logging.getLogger("shepherd.launcher")

BACKOFF_S = (0.2, 0.5, 1.0, 2.0, 5.0)
STOP_GRACE_S = 1.5
#: services stopped (and waited for) before the others at shutdown
STOP_FIRST = ("ir_transmitter",)


@dataclass
class _Run:
    stop: asyncio.Event = field(default_factory=asyncio.Event)
    exit_code: int = 0
    restarts: dict[str, int] = field(default_factory=dict)

    def request_exit(self, code: int) -> None:
        self.exit_code = code
        self.stop.set()


async def _supervise_task(name: str, dep: Deployment, session: zenoh.Session,
                         run: _Run) -> None:
    module = load_service(name)
    settings = dep.settings_for(name)
    keys = Keys(dep.namespace)
    rejections = Rejections(logging.getLogger(f"shepherd.{name}"))
    attempt = 0
    while not run.stop.is_set():
        bus = Bus(session, keys, name, rejections, local_delivery=dep.zenoh.local_delivery,
                  limits=dep.limits)
        main: asyncio.Future[None] | None = None
        try:
            bus.declare_queryable(f"{STATS}/{name}", lambda: ServiceStats(
                service=name, rejected=rejections.by_key(), restarts=run.restarts.get(name, 0)))
            main = asyncio.ensure_future(
                module.main(ServiceContext(bus, dep, name, run.request_exit), settings))
            await asyncio.sleep(0)  # main runs to its first await: its subscriptions exist
            bus.declare_alive()  # so a peer that sees the token can talk to it at once
            await main
            log.info("service %s finished", name)
            return
        except asyncio.CancelledError:
            if main is not None:
                main.cancel()
                with contextlib.suppress(BaseException):
                    await main
            raise
        except Exception:
            delay = BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)]
            log.exception("service %s crashed; restarting in %.1f s", name, delay)
            run.restarts[name] = run.restarts.get(name, 0) + 1
            attempt += 1
        finally:
            bus.close()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(run.stop.wait(), delay)


async def _supervise_process(name: str, dep: Deployment, run: _Run) -> None:
    attempt = 0
    while not run.stop.is_set():
        cmd = [sys.executable, "-m", "services.tools.cli", "run", str(dep.path), "--only", name,
               "--child"]
        if dep.zenoh.connect:
            cmd += [a for ep in dep.zenoh.connect for a in ("--connect", ep)]
        if dep.zenoh.listen:
            cmd += [a for ep in dep.zenoh.listen for a in ("--listen", ep)]
        proc = await asyncio.create_subprocess_exec(*cmd)
        log.info("service %s started as process %d", name, proc.pid)
        stop_wait = asyncio.ensure_future(run.stop.wait())
        proc_wait = asyncio.ensure_future(proc.wait())
        try:
            await asyncio.wait({stop_wait, proc_wait}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop_wait.cancel()
            if proc.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    proc.send_signal(signal.SIGTERM)
                try:
                    await asyncio.wait_for(proc.wait(), STOP_GRACE_S)
                except TimeoutError:
                    proc.kill()
                    await proc.wait()
        if run.stop.is_set() or proc.returncode == 0:
            return
        delay = BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)]
        log.error("service %s process exited with %s; restarting in %.1f s", name,
                  proc.returncode, delay)
        run.restarts[name] = run.restarts.get(name, 0) + 1
        attempt += 1
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(run.stop.wait(), delay)


async def run_deployment(dep: Deployment, *, only: list[str] | None = None,
                         duration: float | None = None, processes: bool = False,
                         child: bool = False, session: zenoh.Session | None = None) -> int:
    """Run the deployment's services until a signal, ``duration`` seconds, or a service asks
    to exit; returns the exit code. In-process services share one Zenoh session: ``session``
    (an application embedding the services, left open) or one opened from ``[zenoh]``."""
    names = only or list(dep.services)
    for name in names:
        if name not in dep.services:
            raise KeyError(f"service {name!r} is not in {dep.path}")
    run = _Run()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):  # only possible in the main thread
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, run.stop.set)
    in_process = [n for n in names if child or not (processes or dep.settings_for(n).process)]
    as_process = [n for n in names if n not in in_process]
    if as_process and dep.path is None:
        raise ValueError("running services as processes needs a deployment file on disk")
    tasks: list[asyncio.Task[None]] = []
    own = in_process and session is None
    with open_session(dep.zenoh) if own else contextlib.nullcontext(session) as shared:
        for name in in_process:
            assert shared is not None
            tasks.append(asyncio.create_task(_supervise_task(name, dep, shared, run), name=name))
        for name in as_process:
            tasks.append(asyncio.create_task(_supervise_process(name, dep, run), name=name))
        log.info("running %s", ", ".join(names) or "nothing")
        all_done: asyncio.Future[Any] = asyncio.ensure_future(
            asyncio.gather(*tasks, return_exceptions=True))
        stop_wait: asyncio.Future[Any] = asyncio.ensure_future(run.stop.wait())
        try:
            await asyncio.wait([all_done, stop_wait], timeout=duration,
                               return_when=asyncio.FIRST_COMPLETED)
        finally:
            run.stop.set()
            stop_wait.cancel()
            # the IR transmitter first: its stop goes out while the other services still run
            # (their teardown can hold the process for a second or more)
            first = [t for t in tasks if t.get_name() in in_process and t.get_name() in STOP_FIRST]
            for task in first:
                task.cancel()
            if first:
                await asyncio.wait(first, timeout=STOP_GRACE_S)
            for task in tasks:
                if task.get_name() in in_process:
                    task.cancel()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(all_done), STOP_GRACE_S + 1.0)
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.remove_signal_handler(sig)
    return run.exit_code
