"""What a running service is given besides its own settings."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from services.core.mounts import Geometry
from services.core.world import World
from services.runtime.bus import Bus
from services.runtime.config import Deployment


def _no_exit(code: int) -> None:
    pass


@dataclass
class ServiceContext:
    """A service's bus, its deployment, its name, and a way to end the whole deployment."""

    bus: Bus
    deployment: Deployment
    name: str
    request_exit: Callable[[int], None] = field(default=_no_exit)

    @property
    def log(self) -> logging.Logger:
        return self.bus.log

    @property
    def geometry(self) -> Geometry:
        return self.deployment.geometry

    @property
    def world(self) -> World:
        return self.deployment.world
