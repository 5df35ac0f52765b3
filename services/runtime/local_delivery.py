"""In-process delivery between the buses that share one Zenoh session.

Services launched in one process share a session. Their messages still go out through Zenoh
(to other processes, machines, recorders), but a subscriber in the same session takes them
straight from the publisher as Python objects: no JSON, no pixel copy, no hand-over through
Zenoh's threads. Zenoh-side, those subscribers accept only ``Locality.REMOTE`` samples, so
nothing arrives twice. Hence, in a session with such subscribers, publish through a ``Bus``
(or from another session): a bare ``session.put`` reaches them only from other sessions.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import zenoh

Deliver = Callable[[str, Any], None]


class LocalHub:
    """The in-process subscribers of one session: key expression -> deliver(key, item)."""

    def __init__(self) -> None:
        # (subscribers, routes: key -> its deliverers), replaced whole on every change, so a
        # publisher reads a consistent pair without a lock
        self._state: tuple[list[tuple[zenoh.KeyExpr, Deliver]], dict[str, list[Deliver]]] = \
            ([], {})
        self._lock = threading.Lock()

    def add(self, key_expr: str, deliver: Deliver) -> Callable[[], None]:
        """Register ``deliver`` for keys intersecting ``key_expr``; returns its remover."""
        entry = (zenoh.KeyExpr(key_expr), deliver)
        with self._lock:
            self._state = ([*self._state[0], entry], {})

        def remove() -> None:
            with self._lock:
                self._state = ([e for e in self._state[0] if e is not entry], {})
        return remove

    def deliver(self, key: str, item: Any) -> None:
        """Hand ``item`` published on ``key`` to every matching in-process subscriber."""
        subscribers, routes = self._state
        targets = routes.get(key)
        if targets is None:  # first publication on this key since the last change
            ke = zenoh.KeyExpr(key)
            targets = routes[key] = [d for k, d in subscribers if k.intersects(ke)]
        for deliver in targets:
            deliver(key, item)


_HUBS: dict[int, tuple[zenoh.Session, LocalHub]] = {}
_HUBS_LOCK = threading.Lock()


def hub_for(session: zenoh.Session) -> LocalHub:
    """The hub of ``session`` (kept with a reference to it, so ids cannot be reused)."""
    with _HUBS_LOCK:
        entry = _HUBS.get(id(session))
        if entry is None or entry[0] is not session:
            entry = _HUBS[id(session)] = (session, LocalHub())
        return entry[1]
