"""Which of the controller's commands may still move the humanoid (issue 20). No bus inside.

A network cut shorter than Zenoh's lease leaves the session up: what the controller put during
the cut is held in a buffer and delivered in one burst when the link comes back. None of it may
move the humanoid. Decided on this host alone, with no clock synchronisation between hosts:

- **order**: a session's commands carry an increasing ``seq``; one not newer than the newest
  seen is dropped (a burst collapses to its newest: the service sends only that);
- **cadence**: after any gap longer than ``deadman_s`` between arrivals (the controller repeats
  its command every keepalive, 0.2 s), after a dead-man stop, and at a new session, motion is
  re-armed only after ``rearm_arrivals`` arrivals each within ``deadman_s`` of the previous.
  Arrivals closer than ``burst_s`` to the previous are the same arrival: a buffered burst
  counts once, so a command decided before the gap is never the one that re-arms;
- **lag**: a command that arrived more than ``stale_s`` later than the stream's fastest
  delivery (:class:`~services.runtime.clock.LagFloor` over the sender's monotonic clock) is
  stale: this catches a backlog that drains slowly enough to look like a cadence.

``stop`` always passes. Commands without a session (one-shots such as ``shepherd ir send``)
are not judged here: the service relays them as before.
"""

from __future__ import annotations

from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field

from schemas import Command, IrCommand
from services.runtime.clock import LagFloor


class FreshnessParams(BaseModel):
    """The gate's parameters (the IR transmitter's settings extend these; defaults here)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    deadman_s: float = Field(default=0.5, ge=0.0, description=(
        "dead-man: send stop when the humanoid moves and no fresh command (the controller's "
        "keepalive included) came for this long; also the longest gap between arrivals that "
        "keeps motion armed. 0 turns the dead-man off (the gate then re-arms on order alone)"))
    rearm_arrivals: int = Field(default=3, ge=1, description=(
        "after a gap, this many arrivals at the keepalive cadence re-arm motion"))
    burst_s: float = Field(default=0.02, ge=0.0, description=(
        "arrivals closer than this to the previous one belong to the same burst"))
    stale_s: float = Field(default=0.3, gt=0.0, description=(
        "a command that arrived this much later than the stream's fastest is stale"))
    lag_window_s: float = Field(default=10.0, gt=0.0, description=(
        "how long the fastest delivery is remembered (a lasting rise of the delay makes "
        "commands stale for at most this long)"))


#: the reason of a command not newer than one already seen
OLD = "not newer than a command already seen"


@dataclass(frozen=True)
class Verdict:
    send: bool
    reason: str = ""   # why it was dropped


class FreshnessGate:
    """Judges a controller's commands by order, arrival cadence and lag (pure; times in s)."""

    def __init__(self, params: FreshnessParams | None = None) -> None:
        self.params = params or FreshnessParams()
        self.session: str | None = None
        self.last_seq = -1
        self.last_arrival_s: float | None = None
        self.armed = False
        self.cadence = 0          # arrivals at cadence since the last gap
        self.lag = LagFloor(self.params.lag_window_s)
        self.dropped: dict[str, int] = {"old": 0, "rearming": 0, "stale": 0}

    def disarm(self) -> None:
        """Motion waits for the cadence again (a dead-man stop, the controller gone)."""
        self.armed, self.cadence = False, 0

    def judge(self, cmd: IrCommand, arrival_s: float) -> Verdict:
        """Record ``cmd`` (a session's command) arriving at ``arrival_s`` (this host's
        monotonic clock) and say whether it may go to the humanoid."""
        p = self.params
        if cmd.session != self.session:
            self.session, self.last_seq, self.last_arrival_s = cmd.session, -1, None
            self.lag.reset()
            self.disarm()
        seq = -1 if cmd.seq is None else cmd.seq
        if seq <= self.last_seq:
            if cmd.command is Command.STOP:
                return Verdict(True)
            return self._drop("old", OLD)
        self.last_seq = seq
        spacing = float("inf") if self.last_arrival_s is None else arrival_s - self.last_arrival_s
        self.last_arrival_s = arrival_s
        if p.deadman_s and spacing > p.deadman_s:
            self.disarm()
        elif spacing >= p.burst_s or not p.deadman_s:
            self.cadence += 1
            if self.cadence >= p.rearm_arrivals:
                self.armed = True
        excess = 0.0 if cmd.sent_mono_ns is None else self.lag.excess_s(
            cmd.sent_mono_ns / 1e9, arrival_s)
        if cmd.command is Command.STOP:
            return Verdict(True)
        if not self.armed:
            return self._drop("rearming", f"re-arming after a gap: {self.cadence}/"
                              f"{p.rearm_arrivals} arrivals at cadence")
        if excess > p.stale_s:
            return self._drop("stale", f"arrived {1000 * excess:.0f} ms later than the "
                              "stream's fastest")
        return Verdict(True)

    def _drop(self, kind: str, reason: str) -> Verdict:
        self.dropped[kind] += 1
        return Verdict(False, reason)
