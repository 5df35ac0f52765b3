"""Infra-red commands to the humanoid: the Robosapien protocol (``protocol``), backends for
the serial microcontroller, LIRC, the simulator and a log (``backends``), a decoder of
recorded waveforms (``waveform``); ``service`` takes ``ir/command``."""

from services.ir_transmitter.backends import BackendError, IrBackend, make_backend
from services.ir_transmitter.protocol import decode_timings, timings_us

__all__ = ["BackendError", "IrBackend", "decode_timings", "make_backend", "timings_us"]
