"""Frames on ``camera/frame``: raw pixels or JPEG bytes, a JSON ``FrameHeader`` attachment.

Everything about a frame is checked before anything the size of its image is allocated: the
header, the raw payload's length against it, and a JPEG's dimensions as its SOF marker gives
them (against the header and against the largest side allowed, ``[limits] max_frame_side``),
so a hostile header or image cannot make a service allocate gigabytes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import ValidationError

from schemas import FrameEncoding, FrameHeader, describe_validation_error

FRAME_ENCODING = "application/octet-stream;shepherd.Frame/1"
JPEG_ENCODING = "image/jpeg;shepherd.Frame/1"


class FrameError(ValueError):
    """A frame that cannot be used; the message says what was wrong."""


@dataclass(frozen=True)
class Frame:
    """A decoded ``camera/frame``: header and image (H x W x 3 uint8 BGR, or H x W mono)."""

    header: FrameHeader
    image: np.ndarray
    received_ns: int


_SOF_MARKERS = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def jpeg_dimensions(data: bytes) -> tuple[int, int]:
    """(width, height) from a JPEG's first SOF marker, without decoding; raises FrameError."""
    if data[:2] != b"\xff\xd8":
        raise FrameError("frame payload is not a JPEG (no SOI marker)")
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            raise FrameError(f"JPEG is corrupt: no marker at byte {i}")
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if length < 2:
            raise FrameError(f"JPEG is corrupt: segment length {length} at byte {i}")
        if marker in _SOF_MARKERS:
            if i + 9 > n:
                break
            height = int.from_bytes(data[i + 5:i + 7], "big")
            width = int.from_bytes(data[i + 7:i + 9], "big")
            return width, height
        if marker == 0xDA:  # start of scan before any SOF
            break
        i += 2 + length
    raise FrameError("JPEG has no frame (SOF) marker before its image data")


def check_frame(attachment: bytes | None, size: int, payload: Callable[[], bytes],
                max_side: int) -> FrameHeader:
    """Validate a frame sample before decoding it: its header, its size, no side over
    ``max_side`` px, and for JPEG the SOF dimensions. ``payload`` gives the bytes (asked for
    only for JPEG). Raises FrameError."""
    if attachment is None:
        raise FrameError("frame without a header attachment")
    try:
        header = FrameHeader.model_validate_json(attachment)
    except ValidationError as err:
        raise FrameError(f"invalid frame header: {describe_validation_error(err)}") from None
    if header.width > max_side or header.height > max_side:
        raise FrameError(f"frame header says {header.width}x{header.height}, larger than the "
                         f"{max_side}x{max_side} limit")
    if size == 0:
        raise FrameError("empty frame payload")
    expected = header.expected_size()
    if expected is not None:
        if size != expected:
            raise FrameError(f"frame payload is {size} bytes, header {header.width}x"
                             f"{header.height} {header.encoding.value} needs {expected}")
        return header
    data = payload()
    width, height = jpeg_dimensions(data)
    if (width, height) != (header.width, header.height):
        raise FrameError(f"JPEG is {width}x{height}, header says {header.width}x"
                         f"{header.height}")
    if data[-2:] != b"\xff\xd9":
        raise FrameError("JPEG is truncated (no EOI marker)")
    return header


def decode_image(header: FrameHeader, data: bytes) -> np.ndarray:
    """Pixels of a frame payload checked by :func:`check_frame`; raises FrameError."""
    if header.encoding is FrameEncoding.JPEG:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise FrameError("frame payload is not a decodable JPEG")
        if image.shape[:2] != (header.height, header.width):
            raise FrameError(f"JPEG is {image.shape[1]}x{image.shape[0]}, header says "
                             f"{header.width}x{header.height}")
        return image
    expected = header.expected_size()
    if len(data) != expected:
        raise FrameError(f"frame payload is {len(data)} bytes, header {header.width}x"
                         f"{header.height} {header.encoding.value} needs {expected}")
    shape = ((header.height, header.width, 3) if header.encoding is FrameEncoding.BGR8
             else (header.height, header.width))
    return np.frombuffer(data, np.uint8).reshape(shape)


def encode_frame(image: np.ndarray, seq: int, stamp_ns: int, jpeg_quality: int | None = None
                 ) -> tuple[FrameHeader, bytes]:
    """Header and payload for an image (BGR or mono); JPEG when ``jpeg_quality`` is given."""
    height, width = image.shape[:2]
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if not ok:
            raise FrameError("JPEG encoding failed")
        enc, data = FrameEncoding.JPEG, buf.tobytes()
    else:
        if image.ndim == 3 and image.shape[2] == 1:
            image = image[..., 0]
        enc = FrameEncoding.BGR8 if image.ndim == 3 else FrameEncoding.MONO8
        data = np.ascontiguousarray(image).tobytes()
    return FrameHeader(seq=seq, stamp_ns=stamp_ns, width=width, height=height, encoding=enc), data
