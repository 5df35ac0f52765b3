"""A pseudo-terminal standing in for the IR microcontroller's serial port."""

from __future__ import annotations

import os
import time
from pathlib import Path


class Pty:
    """A pseudo-terminal pair with a stable symlink, so it can be unplugged and replugged."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.plug()

    def plug(self) -> None:
        import tty
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.slave_fd = slave
        if self.link.is_symlink():
            self.link.unlink()
        self.link.symlink_to(os.ttyname(slave))

    def unplug(self) -> None:
        self.link.unlink()
        os.close(self.master)
        os.close(self.slave_fd)

    def read(self, n: int, timeout: float = 2.0) -> bytes:
        import select
        out = b""
        end = time.monotonic() + timeout
        while len(out) < n and time.monotonic() < end:
            r, _, _ = select.select([self.master], [], [], 0.1)
            if r:
                out += os.read(self.master, 64)
        return out
