"""The microcontroller firmware, built with gcc-avr + avr-libc and run in simavr (Debian
packages; make test installs them): the traced IR pin decodes back to the codes sent."""

import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from schemas import ROBOSAPIEN_CODES
from services.ir_transmitter.protocol import CARRIER_HZ, FIRMWARE_HELLO, T_US, timings_us
from services.ir_transmitter.waveform import decode_trace

FIRMWARE = Path(__file__).resolve().parent.parent / "deploy" / "firmware"


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fw")
    res = subprocess.run(["make", "-C", str(FIRMWARE), f"OUT={out}"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert (out / "robosapien_ir.hex").stat().st_size > 100
    return out


@dataclass
class Simulation:
    frames: list        # decoded IR frames
    echoed: list[int]   # bytes the firmware sent back
    fed_s: list[float]  # when each byte was fed to its UART
    rising_s: list[float]  # rising edges of the IR pin


def _simulate(build: Path, codes: list[int | str]) -> Simulation:
    res = subprocess.run([str(build / "sim_harness"), str(build / "robosapien_ir.elf"),
                          *map(str, codes)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = [ln.split() for ln in res.stdout.splitlines()]
    freq = next(int(ln[1]) for ln in lines if ln[0] == "freq")
    pins = [ln for ln in lines if ln[0] == "pin"]
    t = np.array([int(p[1]) for p in pins]) / freq
    level = np.array([int(p[2]) & 1 for p in pins])
    return Simulation(decode_trace(t, level), [int(ln[2]) for ln in lines if ln[0] == "uart"],
                      [int(ln[1]) / freq for ln in lines if ln[0] == "rx"],
                      [float(x) for x in t[level == 1]])


def _run(build: Path, codes: list[int | str]) -> tuple[list, list[int]]:
    sim = _simulate(build, codes)
    assert bytes(sim.echoed[:len(FIRMWARE_HELLO)]) == FIRMWARE_HELLO
    return sim.frames, sim.echoed[len(FIRMWARE_HELLO):]


def test_the_firmware_announces_itself_before_anything_else(build: Path):
    sim = _simulate(build, [0x86])
    assert bytes(sim.echoed[:len(FIRMWARE_HELLO)]) == FIRMWARE_HELLO
    assert sim.echoed[len(FIRMWARE_HELLO):] == [0x86]
    assert [f.code for f in sim.frames] == [0x86]


def test_every_command_is_emitted_with_the_right_carrier_and_timing(build: Path):
    codes: list[int | str] = [ROBOSAPIEN_CODES[c] for c in ROBOSAPIEN_CODES]
    frames, echoed = _run(build, codes)
    assert [f.code for f in frames] == codes
    assert echoed == codes  # the firmware acknowledges each frame
    for f in frames:
        assert abs(f.carrier_hz - CARRIER_HZ) / CARRIER_HZ < 0.02
        expected = timings_us(f.code)
        assert len(f.durations_us) == len(expected)
        for got, want in zip(f.durations_us, expected, strict=True):
            assert abs(got - want) / want < 0.05, (hex(f.code), got, want)
        assert expected[0] == 8 * T_US


def test_a_byte_that_is_not_a_code_is_refused(build: Path):
    frames, echoed = _run(build, [0x10, 0x8E])
    assert [f.code for f in frames] == [0x8E]
    assert echoed == [ord("?"), 0x8E]


def test_watchdog_stops_the_robot_within_half_a_second_of_silence(build: Path):
    # walk, three heartbeats, then the host goes quiet (crash, pulled cable)
    sim = _simulate(build, [0x86, "wait:100", 0, "wait:100", 0, "wait:100", 0, "wait:1000"])
    assert [f.code for f in sim.frames] == [0x86, 0x8E]
    assert sim.echoed == [*FIRMWARE_HELLO, 0x86, ord("!")]
    stop_start = next(t for t in sim.rising_s if t > sim.fed_s[-1])
    assert 0.35 < stop_start - sim.fed_s[-1] < 0.5, stop_start - sim.fed_s[-1]


def test_heartbeats_hold_off_the_watchdog(build: Path):
    beats: list[int | str] = [x for _ in range(8) for x in (0, "wait:140")]
    frames, echoed = _run(build, [0x86, *beats, 0x8E])
    assert [f.code for f in frames] == [0x86, 0x8E]  # no watchdog stop in between
    assert ord("!") not in echoed and ord("?") not in echoed
