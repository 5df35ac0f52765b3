"""Is the latest pose fresh enough to steer by? Decided on this host, without clock sync.

A pose's age is measured from its arrival here (:mod:`services.runtime.clock`), which a network
cut shorter than Zenoh's lease fools: the poses held in a buffer during the cut arrive at once
when the link comes back, each looking new (issue 20). So besides its arrival age a pose must

- not have arrived later than the stream's fastest by more than ``timeout_s`` (its lag over the
  vision host's stamp, :class:`~services.runtime.clock.LagFloor`), and
- after a gap longer than ``timeout_s``, come from a stream that has been arriving without a gap
  for ``rearm_s``: the held burst comes at once, the live poses follow it.
"""

from __future__ import annotations

from services.runtime.clock import LagFloor


class PoseFreshness:
    """The pose stream's freshness; times are this host's Unix ns, stamps the sender's."""

    def __init__(self, timeout_s: float, rearm_s: float, lag_window_s: float = 10.0) -> None:
        self.timeout_s, self.rearm_s = timeout_s, rearm_s
        self.lag = LagFloor(lag_window_s)
        self.last_arrival_ns = 0
        self.since_ns = 0          # when the stream came back after its last gap
        self.excess_s = 0.0        # the latest pose's lag above the stream's fastest

    def arrived(self, stamp_ns: int, arrival_ns: int) -> None:
        if arrival_ns - self.last_arrival_ns > self.timeout_s * 1e9:
            self.since_ns = arrival_ns
        self.last_arrival_ns = arrival_ns
        self.excess_s = self.lag.excess_s(stamp_ns / 1e9, arrival_ns / 1e9)

    def age_s(self, now_ns: int) -> float:
        """Seconds since the latest pose arrived (inf before the first)."""
        return float("inf") if not self.last_arrival_ns else (now_ns - self.last_arrival_ns) / 1e9

    def why_stale(self, now_ns: int) -> str:
        """Why the latest pose must not be steered by, or '' when it may."""
        if self.excess_s > self.timeout_s:
            return (f"pose arrived {1000 * self.excess_s:.0f} ms later than the stream's "
                    "fastest (held during a network cut?)")
        back_s = (now_ns - self.since_ns) / 1e9
        if self.last_arrival_ns and back_s < self.rearm_s:
            return (f"poses back {1000 * back_s:.0f} ms after a gap: waiting "
                    f"{1000 * self.rearm_s:.0f} ms for live ones")
        return ""
