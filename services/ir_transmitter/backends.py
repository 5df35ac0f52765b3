"""IR backends: how a Robosapien command leaves the computer.

- ``serial``: one byte per command, the Robosapien code itself, to a microcontroller that
  modulates the IR LED (deploy/firmware). Reconnects after the device is unplugged.
- ``lirc``: ``SEND_ONCE <remote> <NAME>`` to a lircd socket (deploy/lirc/robosapien.lircd.conf).
- ``sim``: publishes the command on ``sim/ir`` for the simulated humanoid.
- ``log``: dry run; only logs.

``send`` blocks (serial and socket I/O); the service calls it from a worker thread.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable
from typing import Any, Protocol

from schemas import ROBOSAPIEN_CODES, Command, IrCommand

log = logging.getLogger("shepherd.ir_transmitter")


class BackendError(Exception):
    """The backend could not send (the message says why); the command was not sent."""


class IrBackend(Protocol):
    name: str
    options: dict[str, Any]
    connected: bool

    def send(self, command: IrCommand) -> None: ...
    def close(self) -> None: ...


class LogBackend:
    name = "log"

    def __init__(self, **options: Any) -> None:
        if options:
            raise ValueError(f"log backend takes no options, got {sorted(options)}")
        self.options: dict[str, Any] = {}
        self.connected = True
        self.sent: list[IrCommand] = []

    def send(self, command: IrCommand) -> None:
        log.info("IR (dry run): %s 0x%02X", command.command.value,
                 ROBOSAPIEN_CODES[command.command])
        self.sent.append(command)
        del self.sent[:-100]

    def close(self) -> None:
        pass


class SimBackend:
    """Publishes on ``sim/ir`` through a callback given by the service."""

    name = "sim"

    def __init__(self, publish: Callable[[IrCommand], None], **options: Any) -> None:
        if options:
            raise ValueError(f"sim backend takes no options, got {sorted(options)}")
        self.options: dict[str, Any] = {}
        self.connected = True
        self._publish = publish

    def send(self, command: IrCommand) -> None:
        self._publish(command)

    def close(self) -> None:
        pass


class SerialBackend:
    """One byte per command over a serial port (pyserial); reopens after an unplug."""

    name = "serial"

    def __init__(self, port: str, baud: int | str = 115200, reopen_s: float | str = 0.5,
                 **rest: Any) -> None:
        if rest:
            raise ValueError(f"serial backend: unknown options {sorted(rest)} "
                             "(expected port, baud, reopen_s)")
        if not port:
            raise ValueError("serial backend needs a port, e.g. /dev/ttyUSB0")
        self.port, self.baud, self.reopen_s = str(port), int(baud), float(reopen_s)
        self.options = {"port": self.port, "baud": self.baud}
        self._ser: Any = None
        self._last_try = 0.0
        self.connected = False
        self._open(initial=True)

    def _open(self, initial: bool = False) -> bool:
        import serial
        self._last_try = time.monotonic()
        try:
            self._ser = serial.Serial(self.port, self.baud, timeout=0.2, write_timeout=0.5)
        except (serial.SerialException, OSError) as err:
            self._ser, self.connected = None, False
            if initial:
                log.warning("serial port %s not available yet: %s", self.port, err)
            return False
        self.connected = True
        log.info("serial port %s open at %d baud", self.port, self.baud)
        return True

    def send(self, command: IrCommand) -> None:
        import serial
        if self._ser is None:
            if time.monotonic() - self._last_try < self.reopen_s or not self._open():
                raise BackendError(f"serial port {self.port} is disconnected")
        try:
            self._ser.write(bytes([ROBOSAPIEN_CODES[command.command]]))
            self._ser.flush()
        except (serial.SerialException, OSError) as err:
            self.close()
            raise BackendError(f"serial port {self.port} failed: {err}") from None

    def heartbeat(self) -> None:
        """Send the heartbeat byte 0x00 (the firmware's watchdog stops the robot without it)."""
        if self._ser is None:
            raise BackendError(f"serial port {self.port} is disconnected")
        import serial
        try:
            self._ser.write(b"\x00")
        except (serial.SerialException, OSError) as err:
            self.close()
            raise BackendError(f"serial port {self.port} failed: {err}") from None

    def reconnect(self) -> bool:
        """Try to reopen now (rate-limited); True if the port is open."""
        if self._ser is not None:
            return True
        return time.monotonic() - self._last_try >= self.reopen_s and self._open()

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:
                pass
        self._ser, self.connected = None, False


#: LIRC button names in deploy/lirc/robosapien.lircd.conf.
LIRC_NAMES = {Command.WALK_FORWARD: "WALK_FORWARD", Command.WALK_BACKWARD: "WALK_BACKWARD",
              Command.TURN_LEFT: "TURN_LEFT", Command.TURN_RIGHT: "TURN_RIGHT",
              Command.STOP: "STOP"}


class LircBackend:
    """``SEND_ONCE`` to lircd over its Unix socket (or ``host:port`` TCP)."""

    name = "lirc"

    def __init__(self, socket: str = "/var/run/lirc/lircd", remote: str = "robosapien",
                 timeout_s: float | str = 1.0, **rest: Any) -> None:
        if rest:
            raise ValueError(f"lirc backend: unknown options {sorted(rest)} "
                             "(expected socket, remote, timeout_s)")
        self.path, self.remote, self.timeout_s = str(socket), str(remote), float(timeout_s)
        self.options = {"socket": self.path, "remote": self.remote}
        self.connected = True

    def _connect(self) -> socket.socket:
        if ":" in self.path and not self.path.startswith("/"):
            host, port = self.path.rsplit(":", 1)
            return socket.create_connection((host, int(port)), self.timeout_s)
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            s.settimeout(self.timeout_s)
            s.connect(self.path)
        except OSError:
            s.close()
            raise
        return s

    def send(self, command: IrCommand) -> None:
        line = f"SEND_ONCE {self.remote} {LIRC_NAMES[command.command]}\n"
        try:
            with self._connect() as s:
                s.sendall(line.encode())
                reply = _read_lirc_reply(s)
        except OSError as err:
            self.connected = False
            raise BackendError(f"lircd at {self.path} unreachable: {err}") from None
        self.connected = True
        if "SUCCESS" not in reply:
            raise BackendError(f"lircd refused {line.strip()!r}: {' / '.join(reply)}")

    def close(self) -> None:
        pass


def _read_lirc_reply(s: socket.socket) -> list[str]:
    """Lines of one lircd reply: BEGIN / command / SUCCESS|ERROR / [DATA / n / lines] / END."""
    buf = b""
    while b"\nEND\n" not in buf:
        chunk = s.recv(4096)
        if not chunk:
            break
        buf += chunk
    lines = buf.decode(errors="replace").splitlines()
    if "BEGIN" in lines:
        lines = lines[lines.index("BEGIN") + 1:]
    return [ln for ln in lines if ln and ln != "END"]


def make_backend(name: str, options: dict[str, Any],
                 publish_sim: Callable[[IrCommand], None]) -> IrBackend:
    """Build a backend by name; raises ValueError with the reason for a bad request."""
    if name == "log":
        return LogBackend(**options)
    if name == "sim":
        return SimBackend(publish_sim, **options)
    if name == "serial":
        if "port" not in options:
            raise ValueError("serial backend needs option port (e.g. /dev/ttyUSB0)")
        return SerialBackend(**options)
    if name == "lirc":
        return LircBackend(**options)
    raise ValueError(f"unknown IR backend {name!r}; expected serial, lirc, sim or log")
