"""The microcontroller firmware, built with gcc-avr + avr-libc and run in simavr (Debian
packages; make test installs them): the traced IR pin decodes back to the codes sent."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

from schemas import ROBOSAPIEN_CODES
from services.ir_transmitter.protocol import CARRIER_HZ, T_US, timings_us
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


def _run(build: Path, codes: list[int | str]) -> tuple[list, list[int]]:
    res = subprocess.run([str(build / "sim_harness"), str(build / "robosapien_ir.elf"),
                          *map(str, codes)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    freq = next(int(ln.split()[1]) for ln in lines if ln.startswith("freq"))
    pins = [ln.split() for ln in lines if ln.startswith("pin")]
    t = np.array([int(p[1]) for p in pins]) / freq
    level = np.array([int(p[2]) & 1 for p in pins])
    echoed = [int(ln.split()[2]) for ln in lines if ln.startswith("uart")]
    return decode_trace(t, level), echoed


def test_every_command_is_emitted_with_the_right_carrier_and_timing(build: Path):
    codes = [ROBOSAPIEN_CODES[c] for c in ROBOSAPIEN_CODES]
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


def test_watchdog_stops_the_robot_when_the_host_goes_quiet(build: Path):
    frames, echoed = _run(build, [0x86, "wait:2500"])
    assert [f.code for f in frames] == [0x86, 0x8E]
    assert echoed == [0x86, ord("!")]


def test_keep_alives_hold_off_the_watchdog(build: Path):
    frames, echoed = _run(build, [0x86, "wait:1000", 0x86, "wait:1000", 0x86, "wait:800"])
    assert [f.code for f in frames] == [0x86, 0x86, 0x86]
    assert ord("!") not in echoed
