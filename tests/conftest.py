"""Shared fixtures: a Zenoh router on a free loopback port, sessions connected to it, and
helpers to run the CLI in subprocesses. Multicast scouting is always off; every session is
closed at teardown."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from schemas import Keys
from services.bus import Bus, ZenohSettings, open_session, zenoh_config

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
DATASETS = SHARED / "datasets"


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

    from services.cli import compile_kernels
    compile_kernels(io.StringIO())


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh router in this process; yields its endpoint."""
    ep = endpoint()
    with open_session(ZenohSettings(mode="router", listen=[ep], multicast_scouting=False)):
        yield ep


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


def shepherd_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "services.cli", *args]


def run_cli(*args: str, timeout: float = 60.0, cwd: Path | None = None
            ) -> subprocess.CompletedProcess[str]:
    return subprocess.run(shepherd_cmd(*args), capture_output=True, text=True, timeout=timeout,
                          cwd=cwd, env={**os.environ, "PYTHONUNBUFFERED": "1"})


def spawn_cli(*args: str, cwd: Path | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(shepherd_cmd(*args), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            start_new_session=True)
