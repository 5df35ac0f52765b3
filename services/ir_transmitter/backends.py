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
from services.ir_transmitter.protocol import FIRMWARE_HELLO, REFUSED, WATCHDOG_STOP

log = logging.getLogger("shepherd.ir_transmitter")


class BackendError(Exception):
    """The backend could not send (the message says why); the command was not sent."""


class IrBackend(Protocol):
    name: str
    options: dict[str, Any]

    @property
    def connected(self) -> bool: ...

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
    """One byte per command over a serial port (pyserial) to the IR firmware; reopens after an
    unplug.

    Opening an Arduino's port resets it (DTR), so nothing is sent until the firmware has said
    ``FIRMWARE_HELLO``; ``connected`` is true only from then on. The firmware acknowledges
    every code it sent as IR (and answers '?' to a refused byte, '!' when its own watchdog
    stopped the robot): codes without an acknowledgement within ``ack_timeout_s`` are counted
    in ``unacked``. ``handshake = false`` drives a device without the firmware (no hello, no
    acknowledgements expected).
    """

    name = "serial"

    def __init__(self, port: str, baud: int | str = 115200, reopen_s: float | str = 0.5,
                 handshake: bool | str = True, ready_timeout_s: float | str = 3.0,
                 ack_timeout_s: float | str = 0.5, **rest: Any) -> None:
        if rest:
            raise ValueError(f"serial backend: unknown options {sorted(rest)} (expected port, "
                             "baud, reopen_s, handshake, ready_timeout_s, ack_timeout_s)")
        if not port:
            raise ValueError("serial backend needs a port, e.g. /dev/ttyUSB0")
        self.port, self.baud, self.reopen_s = str(port), int(baud), float(reopen_s)
        self.handshake = handshake not in (False, "false", "0", 0)
        self.ready_timeout_s, self.ack_timeout_s = float(ready_timeout_s), float(ack_timeout_s)
        self.options: dict[str, Any] = {"port": self.port, "baud": self.baud}
        self._ser: Any = None
        self._opened_at = self._last_try = 0.0
        self._ready = False
        self._heard = b""              # bytes read while waiting for the hello
        self._awaiting: list[tuple[int, float]] = []  # (code, sent at) not yet acknowledged
        self.unacked = self.refused = self.watchdog_stops = 0
        self._open(initial=True)

    @property
    def connected(self) -> bool:
        """The port is open and the firmware said it is ready."""
        return self._ser is not None and self._ready

    def _open(self, initial: bool = False) -> bool:
        import serial
        self._last_try = time.monotonic()
        try:
            self._ser = serial.Serial(self.port, self.baud, timeout=0, write_timeout=0.5)
        except (serial.SerialException, OSError) as err:
            self._ser = None
            if initial:
                log.warning("serial port %s not available yet: %s", self.port, err)
            return False
        self._opened_at, self._ready, self._heard = time.monotonic(), not self.handshake, b""
        self._awaiting.clear()
        log.info("serial port %s open at %d baud%s", self.port, self.baud,
                 "; waiting for the firmware" if self.handshake else "")
        return True

    def _read_replies(self) -> None:
        """Take what the firmware said: the hello, acknowledgements, refusals, watchdog."""
        data = self._ser.read(self._ser.in_waiting or 0) if self._ser is not None else b""
        if not self._ready:
            self._heard = (self._heard + data)[-64:]
            if FIRMWARE_HELLO not in self._heard:
                return
            self._ready = True
            log.info("IR firmware ready on %s", self.port)
            data = self._heard.split(FIRMWARE_HELLO, 1)[1]
        if not self.handshake:
            return
        for byte in data:
            if byte == WATCHDOG_STOP:
                self.watchdog_stops += 1
                log.warning("the IR firmware's watchdog stopped the robot (host too quiet)")
            elif byte == REFUSED:
                self.refused += 1
                if self._awaiting:
                    self._awaiting.pop(0)
            elif any(code == byte for code, _ in self._awaiting):
                while self._awaiting and self._awaiting.pop(0)[0] != byte:
                    self.unacked += 1  # an earlier code never came back
        now = time.monotonic()
        while self._awaiting and now - self._awaiting[0][1] > self.ack_timeout_s:
            self._awaiting.pop(0)
            self.unacked += 1

    def _wait_ready(self) -> None:
        """Block (in a worker thread) until the firmware said hello; raise if it does not."""
        while not self._ready:
            self._read_replies()
            if self._ready:
                return
            if time.monotonic() - self._opened_at > self.ready_timeout_s:
                raise BackendError(
                    f"no hello from the IR firmware on {self.port} within "
                    f"{self.ready_timeout_s:.1f} s (is deploy/firmware flashed? "
                    "handshake = false for a device without it)")
            time.sleep(0.01)

    def _io(self, write: bytes, ack: int | None) -> None:
        import serial
        if self._ser is None:
            if time.monotonic() - self._last_try < self.reopen_s or not self._open():
                raise BackendError(f"serial port {self.port} is disconnected")
        try:
            self._wait_ready()
            self._ser.write(write)
            self._ser.flush()
            if ack is not None and self.handshake:
                self._awaiting.append((ack, time.monotonic()))
            self._read_replies()
        except (serial.SerialException, OSError) as err:
            self.close()
            raise BackendError(f"serial port {self.port} failed: {err}") from None

    def send(self, command: IrCommand) -> None:
        code = ROBOSAPIEN_CODES[command.command]
        self._io(bytes([code]), ack=code)

    def heartbeat(self) -> None:
        """Send the heartbeat byte 0x00 (the firmware's watchdog stops the robot without it)
        and take the firmware's replies."""
        if self._ser is None:
            raise BackendError(f"serial port {self.port} is disconnected")
        if not self._ready:  # still resetting: nothing to feed yet
            self._read_replies()
            return
        self._io(b"\x00", ack=None)

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
        self._ser, self._ready = None, False


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
