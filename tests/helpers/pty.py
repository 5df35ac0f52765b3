"""A pseudo-terminal standing in for the IR microcontroller's serial port, optionally with a
fake of its firmware's side of the protocol (hello, acknowledgements)."""

from __future__ import annotations

import os
import select
import threading
import time
from pathlib import Path

from services.ir_transmitter.protocol import FIRMWARE_HELLO, REFUSED


class Pty:
    """A pseudo-terminal pair with a stable symlink, so it can be unplugged and replugged.

    With ``firmware=True`` a thread plays the IR firmware: it says ``FIRMWARE_HELLO`` (every
    0.1 s until the host sends its first byte, as a board that resets when the port opens
    would say it once it is up), acknowledges each code (unless ``ack=False``), refuses bytes
    below 0x80 other than the heartbeat, and keeps every byte it got for :meth:`read`.
    """

    def __init__(self, link: Path, firmware: bool = False, ack: bool = True,
                 hello_after_s: float = 0.0) -> None:
        self.link, self.firmware, self.ack, self.hello_after_s = link, firmware, ack, hello_after_s
        self.plug()

    def plug(self) -> None:
        import tty
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.slave_fd = slave
        if self.link.is_symlink():
            self.link.unlink()
        self.link.symlink_to(os.ttyname(slave))
        self._got = bytearray()
        self.acks = 0  # acknowledgements the firmware wrote back
        self._lock = threading.Lock()
        self._stop = threading.Event()
        if self.firmware:
            self._thread = threading.Thread(target=self._play_firmware, daemon=True)
            self._thread.start()

    def _play_firmware(self) -> None:
        start, spoke, heard = time.monotonic(), 0.0, False
        while not self._stop.is_set():
            now = time.monotonic()
            if not heard and now - start >= self.hello_after_s and now - spoke >= 0.1:
                os.write(self.master, FIRMWARE_HELLO)
                spoke = now
            readable, _, _ = select.select([self.master], [], [], 0.02)
            if not readable:
                continue
            try:
                data = os.read(self.master, 64)
            except OSError:
                return
            heard = True
            with self._lock:
                self._got += data
            for byte in data:
                if byte >= 0x80 and self.ack:
                    os.write(self.master, bytes([byte]))
                    self.acks += 1
                elif 0 < byte < 0x80:
                    os.write(self.master, bytes([REFUSED]))

    def unplug(self) -> None:
        self._stop.set()
        if self.firmware:
            self._thread.join(1.0)
        self.link.unlink()
        os.close(self.master)
        os.close(self.slave_fd)

    def read(self, n: int, timeout: float = 2.0) -> bytes:
        """Up to ``n`` bytes the host wrote, waiting at most ``timeout`` s."""
        out = b""
        end = time.monotonic() + timeout
        while len(out) < n and time.monotonic() < end:
            if self.firmware:
                with self._lock:
                    take = bytes(self._got[:n - len(out)])
                    del self._got[:len(take)]
                out += take
                if len(out) < n:
                    time.sleep(0.01)
                continue
            r, _, _ = select.select([self.master], [], [], 0.1)
            if r:
                out += os.read(self.master, 64)
        return out
