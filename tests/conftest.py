"""Shared fixtures: a Zenoh router on a free loopback port, sessions connected to it, and
helpers to run the CLI in subprocesses. Multicast scouting is always off; every session is
closed at teardown."""

from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas import Keys
from services.runtime.bus import Bus
from services.runtime.session import ZenohSettings, zenoh_config

ROOT = Path(__file__).resolve().parent.parent
DATASETS = ROOT / "tests" / "data"  # real data sets, each with its README


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    """Compile the numba kernels once, before any test times a service's start (a fresh
    clone compiles them in about 25 s; later runs load them from the on-disk cache)."""
    import io

    from services.tools.kernels import compile_kernels
    compile_kernels(io.StringIO())


def router_config(ep: str) -> zenoh.Config:
    """A router listening on ``ep`` that opens at once: with multicast scouting off there is
    nobody to scout, so Zenoh's scouting delay (500 ms per router) is set to 0."""
    conf = zenoh_config(ZenohSettings(mode="router", listen=[ep], multicast_scouting=False))
    conf.insert_json5("scouting/delay", "0")
    return conf


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh router in this process; yields its endpoint."""
    ep = endpoint()
    session = zenoh.open(router_config(ep))
    try:
        yield ep
    finally:
        session.close()


@pytest.fixture
def sessions(router: str) -> Iterator[Callable[[], zenoh.Session]]:
    """Factory of peer sessions connected to the router; all closed at teardown."""
    opened: list[zenoh.Session] = []

    def make() -> zenoh.Session:
        s = zenoh.open(zenoh_config(
            ZenohSettings(mode="peer", connect=[router], multicast_scouting=False)))
        opened.append(s)
        return s

    yield make
    for s in opened:
        s.close()


@pytest.fixture
def make_bus(sessions: Callable[[], zenoh.Session]) -> Iterator[Callable[..., Bus]]:
    buses: list[Bus] = []

    def make(service: str = "test", namespace: str = "shepherd") -> Bus:
        bus = Bus(sessions(), Keys(namespace), service)
        buses.append(bus)
        return bus

    yield make
    for b in buses:
        b.close()


def alive_services(session: zenoh.Session, namespace: str = "shepherd") -> set[str]:
    """Names of the services whose liveliness tokens are up now."""
    prefix = f"{namespace}/alive/"
    return {str(r.ok.key_expr).removeprefix(prefix)
            for r in session.liveliness().get(f"{prefix}*", timeout=1.0) if r.ok is not None}


def wait_alive(session: zenoh.Session, *names: str, namespace: str = "shepherd",
               timeout: float = 30.0) -> None:
    """Block until every named service's liveliness token is up (a service declares it once
    its subscriptions exist); fails the test naming the missing ones after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    missing = set(names)
    while time.monotonic() < deadline:
        missing = set(names) - alive_services(session, namespace)
        if not missing:
            return
        time.sleep(0.05)
    pytest.fail(f"services not alive after {timeout:.0f} s: {', '.join(sorted(missing))}")


async def wait_alive_async(session: zenoh.Session, *names: str, namespace: str = "shepherd",
                           timeout: float = 30.0) -> None:
    """:func:`wait_alive` without blocking the event loop (services in this process)."""
    await asyncio.to_thread(wait_alive, session, *names, namespace=namespace, timeout=timeout)


async def wait_matched(bus: Bus, suffix: str, timeout: float = 30.0) -> None:
    """Wait until a subscriber in another session matches ``<namespace>/<suffix>`` as seen
    from ``bus``'s session (its declaration has come through the router), instead of a fixed
    sleep; fails the test after ``timeout`` s."""
    await wait_matched_key(bus.session, bus.keys.key(suffix), timeout)


async def wait_matched_key(session: zenoh.Session, key_expr: str, timeout: float = 30.0,
                           remote_only: bool = False) -> None:
    """:func:`wait_matched` for any key expression (e.g. a ROS 2 topic's data key);
    ``remote_only``: a subscriber of the same session does not count."""
    publisher = session.declare_publisher(key_expr, allowed_destination=(
        zenoh.Locality.REMOTE if remote_only else zenoh.Locality.ANY))
    try:
        deadline = time.monotonic() + timeout
        # zenoh's stub says bool; at run time it is a MatchingStatus with ``matching``
        status: Any = publisher.matching_status
        while not status.matching:
            if time.monotonic() > deadline:
                pytest.fail(f"no subscriber matched {key_expr} in {timeout:.0f} s")
            await asyncio.sleep(0.005)
            status = publisher.matching_status
    finally:
        publisher.undeclare()


async def wait_for(condition: Callable[[], object], what: str, timeout: float = 30.0,
                   poll_s: float = 0.02) -> None:
    """Wait (without blocking the event loop) until ``condition()`` is true, instead of a
    fixed sleep; fails the test naming ``what`` after ``timeout`` s (generous: a loaded
    machine is slow, never wrong)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"{what}: not within {timeout:.0f} s")
        await asyncio.sleep(poll_s)


def wait_until(condition: Callable[[], object], what: str, timeout: float = 30.0,
               poll_s: float = 0.02) -> None:
    """:func:`wait_for` for plain (not asyncio) tests."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"{what}: not within {timeout:.0f} s")
        time.sleep(poll_s)


def shepherd_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "services.tools.cli", *args]


def run_cli(*args: str, timeout: float = 60.0, cwd: Path | None = None
            ) -> subprocess.CompletedProcess[str]:
    return subprocess.run(shepherd_cmd(*args), capture_output=True, text=True, timeout=timeout,
                          cwd=cwd, env={**os.environ, "PYTHONUNBUFFERED": "1"})


def cli_here(*args: str) -> subprocess.CompletedProcess[str]:
    """:func:`run_cli` in this process (the same parser and command, no second interpreter to
    start: about a second less each), for tests about what a command does rather than about
    the process; output captured, exit code as ``shepherd`` would return it. ``main``'s
    event-loop and logging set-up is left out: not for runs that start services (one that
    fails before starting them, as on a busy endpoint, is fine)."""
    import contextlib
    import io

    from services.tools.cli import build_parser
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            parsed = build_parser().parse_args(list(args))
            code = int(parsed.func(parsed) or 0)
        except SystemExit as exit_:  # argparse's errors and --version
            code = exit_.code if isinstance(exit_.code, int) else 1
    return subprocess.CompletedProcess(["shepherd", *args], code, out.getvalue(),
                                       err.getvalue())


def spawn_cli(*args: str, cwd: Path | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(shepherd_cmd(*args), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            start_new_session=True)
