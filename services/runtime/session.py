"""The Zenoh session a deployment opens: its ``[zenoh]`` table, the native config, opening."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path

import zenoh
from pydantic import BaseModel, ConfigDict, Field

#: Where commands that talk to the bus connect without ``--connect`` (``deploy/sim.toml``
#: listens here).
LOCAL_ENDPOINT = "tcp/127.0.0.1:7447"

#: How often a lost link is tried again: from 0.25 s, doubling to at most 1 s (Zenoh's
#: default: 1 s doubling to 4 s).
CONNECT_RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}


class ZenohSettings(BaseModel):
    """The ``[zenoh]`` table of a deployment file."""

    model_config = ConfigDict(extra="forbid")
    mode: str = Field(default="peer", pattern="^(peer|client|router)$",
                      description="the Zenoh session's role: peer, client or router")
    connect: list[str] = Field(default_factory=list,
                               description="endpoints to connect to, e.g. tcp/192.168.1.10:7447")
    listen: list[str] = Field(default_factory=list,
                              description="endpoints to listen on, e.g. tcp/0.0.0.0:7447")
    multicast_scouting: bool = Field(default=True,
                                     description="find peers by UDP multicast on the LAN")
    config_file: Path | None = Field(default=None, description=(
        "a native Zenoh config (JSON5: TLS, users, access control) read first"))
    lease_s: float | None = Field(default=None, ge=0.1, le=3600.0, description=(
        "the session's lease announced to its peers: a link silent this long is closed and "
        "the liveliness tokens behind it go away (Zenoh's default: 10 s). Short (1-2 s) on the "
        "controller's and the IR transmitter's hosts, so a network partition reaches the "
        "liveliness stop too; too short a lease on a jittery link closes healthy links "
        "(the manual: How it works, Safety)"))
    connect_timeout_s: float = Field(default=10.0, ge=0.0, le=3600.0, description=(
        "a client waits this long for its router at start (a robot booting before the "
        "router, or the laptop before the robot), then fails with a message (0: at once)"))
    open_timeout_s: float = Field(default=2.0, ge=0.1, le=60.0, description=(
        "one attempt to open a link is given up after this and a new one made: a link back "
        "from a silent drop (Wi-Fi out of range) is found within about this once it heals. "
        "Zenoh's default (10 s) waits out TCP's backoff of its connection request: up to "
        "7.5 s after a 5 s drop. Raise it over a link slower than about 0.3 s a round trip"))
    keep_alive: int | None = Field(default=None, ge=1, le=100, description=(
        "keep-alive messages per lease on an otherwise idle link (Zenoh's default: 4)"))
    local_delivery: bool = Field(default=True, description=(
        "services sharing a session take each other's messages in-process (still published "
        "to Zenoh for everyone else)"))
    timestamping: bool = Field(default=True, description=(
        "stamp samples with the session's clock, as rmw_zenoh does: zenoh-ext's cached "
        "(transient-local) publishers need it, e.g. the ROS 2 bridge's /tf_static"))


class Limits(BaseModel):
    """The ``[limits]`` table: what a service accepts from the bus before anything is
    allocated for it."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    max_json_bytes: int = Field(default=64 * 1024, ge=1024, le=16 * 1024 * 1024,
                                description="larger JSON messages are refused unparsed")
    max_frame_side: int = Field(default=4096, ge=16, le=16384,
                                description="frames wider or taller (px) are refused")


def zenoh_logging() -> None:
    """Zenoh's own log on stdout when ``RUST_LOG`` is set (e.g. ``RUST_LOG=zenoh=debug``:
    links opened, leases expired, reconnection attempts); silent otherwise."""
    if os.environ.get("RUST_LOG"):
        zenoh.init_log_from_env_or("error")


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """Build a ``zenoh.Config``: the native config file first, then our table on top."""
    if settings.config_file is not None:
        if not settings.config_file.is_file():
            raise FileNotFoundError(f"zenoh config_file {settings.config_file} does not exist")
        conf = zenoh.Config.from_file(str(settings.config_file))
    else:
        conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(settings.mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    conf.insert_json5("timestamping/enabled", json.dumps(settings.timestamping))
    if settings.connect:
        conf.insert_json5("connect/endpoints", json.dumps(settings.connect))
    if settings.listen:
        conf.insert_json5("listen/endpoints", json.dumps(settings.listen))
    if settings.mode == "client":
        timeout_ms = round(1000 * settings.connect_timeout_s)
        conf.insert_json5("connect/timeout_ms", json.dumps(timeout_ms))
    conf.insert_json5("connect/retry", json.dumps(CONNECT_RETRY))
    conf.insert_json5("transport/unicast/open_timeout",
                      json.dumps(round(1000 * settings.open_timeout_s)))
    if settings.lease_s is not None:
        conf.insert_json5("transport/link/tx/lease", json.dumps(round(1000 * settings.lease_s)))
    if settings.keep_alive is not None:
        conf.insert_json5("transport/link/tx/keep_alive", json.dumps(settings.keep_alive))
    return conf


@contextlib.contextmanager
def open_session(settings: ZenohSettings) -> Iterator[zenoh.Session]:
    """Open a Zenoh session and close it on every path."""
    session = zenoh.open(zenoh_config(settings))
    try:
        yield session
    finally:
        session.close()
