"""Wire protocol of the dimacq USB DAQ (64 channels, 24-bit, IEPE): documented codec.

The device is a USB 2.0 vendor-class device (VID ``0x1209``, PID ``0xDA64``) with one
configuration, one interface (number 0) and one bulk IN endpoint ``0x81`` for sample frames.
All multi-byte fields are little-endian. The driver and the simulator both import this module;
it is the only thing they share.

Control requests (endpoint 0, ``bmRequestType`` 0x40 = vendor/device/OUT, 0xC0 = vendor/device/IN)
----------------------------------------------------------------------------------------------
===================  ====  ======  ===================  ===============  =========================
request              bReq  dir     wValue               wIndex           data stage
===================  ====  ======  ===================  ===============  =========================
IDENTIFY             0x01  IN      0                    0                :data:`IDENTIFY_STRUCT`
SET_SAMPLE_RATE      0x02  OUT     0                    0                u32 rate in Hz
SET_CHANNEL_ENABLE   0x03  OUT     0 off, 1 on          channel          —
SET_IEPE             0x04  OUT     current in µA        channel          —  (0, 2000, 4000, 10000)
SET_RANGE            0x05  OUT     range code           channel          —  (:data:`RANGES_V`)
SET_COUPLING         0x06  OUT     0 DC, 1 AC           channel          —
START                0x07  OUT     samples per frame    0                —
STOP                 0x08  OUT     0                    0                —
GET_STATUS           0x09  IN      0                    0                :data:`STATUS_STRUCT`
===================  ====  ======  ===================  ===============  =========================

A request the device cannot honour (unsupported rate, channel ≥ n_channels, configuration change
while running, START with no channel enabled) is answered with a STALL on endpoint 0 (pyusb raises
``USBError`` with errno ``EPIPE``); GET_STATUS then tells the state. START resets the sample
counter and the frame sequence number to 0 and starts the sample clock; the clock is also driven
out on the SYNC connector, which the load cell amplifier counts.

Bulk IN sample frames (endpoint 0x81, one frame per transfer)
------------------------------------------------------------
A 32-byte header (:data:`FRAME_HEADER`) then the payload:

======  ====  ========================================================================
offset  type  field
======  ====  ========================================================================
0       2s    magic ``b"DF"``
2       u8    protocol version (1)
3       u8    flags: bit0 ``OVERFLOW`` the device FIFO overflowed before this frame
              (samples were lost: the sample counter jumps); bits 1–7 reserved (0)
4       u32   sequence number (0 after START, +1 per frame, wraps at 2³²)
8       u64   sample counter of the frame's first sample (0 = first sample after START)
16      u16   n_samples in this frame
18      u16   n_channels (enabled channels, ascending physical order)
20      u64   overload mask: bit k set if enabled channel k (in frame order) clipped in this frame
28      u32   CRC-32 (zlib) of the payload
======  ====  ========================================================================

Payload: ``n_samples × n_channels`` samples, sample-major (all channels of sample 0, then of
sample 1, ...), each a signed 24-bit two's-complement integer, little-endian (3 bytes). Full scale
``±(2²³ − 1)`` counts is ``±range`` volts: ``V = counts · range_v / 2²³``. A clipped sample reads
``±(2²³ − 1)`` and sets the channel's overload bit.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum, IntFlag

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import ProtocolError

__all__ = [
    "BM_REQUEST_IN",
    "BM_REQUEST_OUT",
    "DATA_ENDPOINT",
    "FRAME_HEADER",
    "FRAME_MAGIC",
    "FULL_SCALE_COUNTS",
    "IDENTIFY_STRUCT",
    "IEPE_CURRENTS_UA",
    "PRODUCT_ID",
    "PROTOCOL_VERSION",
    "RANGES_V",
    "RATE_STRUCT",
    "STATUS_STRUCT",
    "VENDOR_ID",
    "DeviceIdentity",
    "DeviceStatus",
    "Frame",
    "FrameFlags",
    "Request",
    "decode_frame",
    "encode_frame",
    "frame_size",
    "int24_to_float",
    "pack_int24",
    "unpack_int24",
]

VENDOR_ID = 0x1209
PRODUCT_ID = 0xDA64
DATA_ENDPOINT = 0x81
PROTOCOL_VERSION = 1
BM_REQUEST_OUT = 0x40
BM_REQUEST_IN = 0xC0
FRAME_MAGIC = b"DF"
#: Input ranges (±V) by range code.
RANGES_V: tuple[float, ...] = (10.0, 5.0, 1.0, 0.5, 0.1)
#: IEPE excitation currents the device supports, µA (0 = off).
IEPE_CURRENTS_UA: tuple[int, ...] = (0, 2000, 4000, 10000)
FULL_SCALE_COUNTS = 2**23 - 1
#: Header of a bulk frame: magic, version, flags, sequence, first sample, n_samples, n_channels,
#: overload mask, payload CRC-32.
FRAME_HEADER = struct.Struct("<2sBBIQHHQI")
#: IDENTIFY answer: magic b"DQ64", protocol version, n_channels, max rate (Hz), ADC bits,
#: n_ranges, serial number (16 bytes ASCII, NUL padded), firmware (16 bytes ASCII).
IDENTIFY_STRUCT = struct.Struct("<4sHHIBB16s16s")
#: SET_SAMPLE_RATE data stage: the rate in Hz.
RATE_STRUCT = struct.Struct("<I")
#: GET_STATUS answer: running (0/1), overflowed since START (0/1), reserved u16, actual sample
#: rate (Hz, f64), samples clocked since START (u64), frames lost to FIFO overflow (u32).
STATUS_STRUCT = struct.Struct("<BBHdQI")


class Request(IntEnum):
    """``bRequest`` codes of the vendor control requests."""

    IDENTIFY = 0x01
    SET_SAMPLE_RATE = 0x02
    SET_CHANNEL_ENABLE = 0x03
    SET_IEPE = 0x04
    SET_RANGE = 0x05
    SET_COUPLING = 0x06
    START = 0x07
    STOP = 0x08
    GET_STATUS = 0x09


class FrameFlags(IntFlag):
    """Flags byte of a bulk frame."""

    NONE = 0
    OVERFLOW = 1


@dataclass(frozen=True)
class DeviceIdentity:
    """Decoded IDENTIFY answer."""

    protocol_version: int
    n_channels: int
    max_sample_rate_hz: int
    adc_bits: int
    n_ranges: int
    serial_number: str
    firmware: str

    def encode(self) -> bytes:
        return IDENTIFY_STRUCT.pack(
            b"DQ64",
            self.protocol_version,
            self.n_channels,
            self.max_sample_rate_hz,
            self.adc_bits,
            self.n_ranges,
            self.serial_number.encode("ascii")[:16],
            self.firmware.encode("ascii")[:16],
        )

    @classmethod
    def decode(cls, data: bytes) -> DeviceIdentity:
        if len(data) != IDENTIFY_STRUCT.size:
            raise ProtocolError(
                f"IDENTIFY answer has {len(data)} bytes, expected {IDENTIFY_STRUCT.size}; "
                "check that the device is a dimacq DAQ with protocol version 1"
            )
        magic, ver, n_ch, rate, bits, n_rng, serial, fw = IDENTIFY_STRUCT.unpack(data)
        if magic != b"DQ64":
            raise ProtocolError(f"IDENTIFY answer starts with {magic!r}, expected b'DQ64'")
        return cls(
            ver,
            n_ch,
            rate,
            bits,
            n_rng,
            serial.rstrip(b"\0").decode("ascii", "replace"),
            fw.rstrip(b"\0").decode("ascii", "replace"),
        )


@dataclass(frozen=True)
class DeviceStatus:
    """Decoded GET_STATUS answer."""

    running: bool
    overflowed: bool
    sample_rate_hz: float
    samples_clocked: int
    frames_lost: int

    def encode(self) -> bytes:
        return STATUS_STRUCT.pack(
            int(self.running),
            int(self.overflowed),
            0,
            self.sample_rate_hz,
            self.samples_clocked,
            self.frames_lost,
        )

    @classmethod
    def decode(cls, data: bytes) -> DeviceStatus:
        if len(data) != STATUS_STRUCT.size:
            raise ProtocolError(
                f"GET_STATUS answer has {len(data)} bytes, expected {STATUS_STRUCT.size}"
            )
        run, ovf, _, rate, clocked, lost = STATUS_STRUCT.unpack(data)
        return cls(bool(run), bool(ovf), rate, clocked, lost)


@dataclass(frozen=True, eq=False)
class Frame:
    """One checked bulk frame (header decoded, payload CRC verified, samples still packed).

    ``counts`` unpacks the samples to int32, shape (n_samples, n_channels); ``to_float`` goes
    straight to scaled floats (what the driver uses).
    """

    flags: FrameFlags
    sequence: int
    first_sample: int
    n_samples: int
    n_channels: int
    overload_mask: int
    payload: bytes

    @property
    def counts(self) -> NDArray[np.int32]:
        return unpack_int24(self.payload).reshape(self.n_samples, self.n_channels)

    def to_float(self, scale: NDArray[np.float64]) -> NDArray[np.float64]:
        """``counts · scale`` per channel, shape (n_samples, n_channels)."""
        return int24_to_float(self.payload, self.n_channels, scale)


def frame_size(n_samples: int, n_channels: int) -> int:
    """Bytes of one frame: ``32 + 3 · n_samples · n_channels``."""
    return FRAME_HEADER.size + 3 * n_samples * n_channels


def pack_int24(counts: NDArray[np.integer]) -> bytes:
    """Pack integer counts (any shape, C order) as little-endian signed 24-bit, vectorised."""
    c = np.ascontiguousarray(counts, dtype="<i4").reshape(-1)
    return c.view(np.uint8).reshape(-1, 4)[:, :3].tobytes()


def _int24_words(data: bytes | bytearray | memoryview) -> NDArray[np.int32]:
    """Samples shifted into the top 24 bits of int32 (value · 256), vectorised.

    Each sample is read as a 4-byte little-endian word starting at its own 3-byte offset (a
    strided view over the buffer padded with one byte), so the word's low 3 bytes are the sample
    and its high byte belongs to the next sample; ``<< 8`` drops that byte and leaves
    ``value · 256`` with the sign in place.
    """
    n_bytes = len(data)
    if n_bytes % 3:
        raise ProtocolError(f"24-bit payload of {n_bytes} bytes is not a multiple of 3")
    padded = bytes(data) + b"\0"
    words = np.ndarray((n_bytes // 3,), dtype="<i4", buffer=padded, strides=(3,))
    return np.left_shift(words, 8)


def unpack_int24(data: bytes | bytearray | memoryview) -> NDArray[np.int32]:
    """Unpack little-endian signed 24-bit integers, vectorised (see :func:`_int24_words`)."""
    return np.right_shift(_int24_words(data), 8)


def int24_to_float(
    data: bytes | bytearray | memoryview, n_channels: int, scale: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Decode a sample-major 24-bit payload straight to scaled floats.

    ``x[s, k] = counts[s, k] · scale[k]``, computed as ``(counts · 256) · (scale / 256)`` so
    that one shift and one multiply do the whole conversion.

    Returns
    -------
    ndarray, shape (n_samples, n_channels)
    """
    words = _int24_words(data).reshape(-1, n_channels)
    return np.multiply(words, np.asarray(scale, dtype=float) / 256.0, dtype=np.float64)


def encode_frame(
    sequence: int,
    first_sample: int,
    counts: NDArray[np.integer],
    *,
    overload_mask: int = 0,
    flags: FrameFlags = FrameFlags.NONE,
) -> bytes:
    """Encode one frame from counts of shape (n_samples, n_channels)."""
    counts = np.asarray(counts)
    if counts.ndim != 2:
        raise ProtocolError(f"frame counts have shape {counts.shape}; need (n_samples, n_ch)")
    payload = pack_int24(counts)
    header = FRAME_HEADER.pack(
        FRAME_MAGIC,
        PROTOCOL_VERSION,
        int(flags),
        sequence & 0xFFFFFFFF,
        first_sample,
        counts.shape[0],
        counts.shape[1],
        overload_mask,
        zlib.crc32(payload),
    )
    return header + payload


def _header(buf: bytes | memoryview, where: str) -> tuple[int, int, int, int, int, int, int]:
    if len(buf) < FRAME_HEADER.size:
        raise ProtocolError(f"{where}: {len(buf)} bytes is shorter than the 32-byte frame header")
    magic, ver, flags, seq, first, n_s, n_ch, ovl, crc = FRAME_HEADER.unpack_from(buf)
    if magic != FRAME_MAGIC or ver != PROTOCOL_VERSION:
        raise ProtocolError(
            f"{where}: header starts {magic!r} version {ver}, expected {FRAME_MAGIC!r} version "
            f"{PROTOCOL_VERSION}; the stream is out of step, stop and restart the task"
        )
    if len(buf) != frame_size(n_s, n_ch):
        raise ProtocolError(
            f"{where}: {len(buf)} bytes but the header announces {n_s} samples x {n_ch} "
            f"channels ({frame_size(n_s, n_ch)} bytes); truncated transfer"
        )
    return flags, seq, first, n_s, n_ch, ovl, crc


def decode_frame(buf: bytes | bytearray | memoryview) -> Frame:
    """Decode and check one frame (magic, version, length, CRC-32)."""
    mv = memoryview(buf)
    flags, seq, first, n_s, n_ch, ovl, crc = _header(mv, "frame")
    payload = mv[FRAME_HEADER.size :]
    if zlib.crc32(payload) != crc:
        raise ProtocolError(f"frame {seq}: payload CRC mismatch; the transfer was corrupted")
    return Frame(FrameFlags(flags), seq, first, n_s, n_ch, ovl, bytes(payload))
