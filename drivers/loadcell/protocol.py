"""CAN protocol of the dimacq 6-DOF load cell amplifier (12 gauges): documented codec.

The amplifier digitises the 12 gauges of one 6-DOF load cell (24 bits, ±10 full-scale units: mV/V
for strain-gauge bridges, read ratiometrically against its excitation; V for AC-coupled gauges) and
counts the DAQ's sample clock on its SYNC input, so every sample it sends carries the DAQ's sample
counter: the host aligns the two streams by counter, never by arrival time. The driver and the
simulator both import this module; it is the only thing they share.

Bus: control frames are classic CAN (≤ 8 data bytes); data frames need CAN FD (48 data bytes), so
the interface must be FD-capable (PCAN-USB FD, Kvaser, SocketCAN ``can0`` with ``fd on``,
python-can ``virtual``). 11-bit identifiers, node id ``N`` (1..127, default 1):

==================  ===========  =========  ==========================================
frame               identifier   direction  content
==================  ===========  =========  ==========================================
command             0x600 + N    host → amp byte 0 opcode, then arguments (classic CAN)
response            0x580 + N    amp → host byte 0 opcode | 0x80, or 0xFF error (classic CAN)
data                0x180 + N    amp → host one sample, 48 bytes (CAN FD, DLC 13)
heartbeat           0x700 + N    amp → host counter u32, local time µs u32 (classic CAN)
==================  ===========  =========  ==========================================

Commands (little-endian arguments)
----------------------------------
=====  ==================  ===============================  ===========================================
code   command             arguments                        response
=====  ==================  ===============================  ===========================================
0x01   IDENTIFY            —                                0x81, n_gauges u8, fw major u8, fw minor u8,
                                                            serial number u32
0x02   START               clock u8 (0 internal, 1 SYNC)    0x82. Counter := 0; with SYNC it counts the
                                                            DAQ's clock pulses from the next pulse on
0x03   STOP                —                                0x83, pulses counted u32
0x04   SET_RATE            rate u32 (Hz)                    0x84, rate u32. Internal clock rate and the
                                                            nominal SYNC rate used by the heartbeat
0x05   TARE                n_samples u16                    0x85 when done (offsets zeroed)
0x06   CAL_DOWNLOAD_BEGIN  n_bytes u16                      0x86 (host → amplifier matrix transfer)
0x07   CAL_SEGMENT         index u8, 6 data bytes           none
0x08   CAL_DOWNLOAD_END    crc32 u32 of the n_bytes         0x88, or error 4 (CRC) / 5 (missing segment)
0x09   CAL_UPLOAD          —                                0x89, n_bytes u16, crc32 u32; then segment
                                                            frames 0x8A, index u8, 6 data bytes
0x0B   GET_STATUS          —                                0x8B, state u8 (0 idle, 1 armed, 2 streaming),
                                                            flags u8 (bit1 SYNC missing), 0, counter u32
=====  ==================  ===============================  ===========================================

Error response: ``0xFF, opcode, code`` with codes 1 unknown command, 2 bad argument, 3 busy
(not allowed while streaming), 4 CRC mismatch, 5 missing segment.

The message table
-----------------
Every control frame above is one frozen dataclass below (:class:`Message`: an opcode byte, then
its fields packed by a ``struct`` format), each request naming the reply it gets
(:attr:`Request.REPLY`). :data:`REQUESTS` and :data:`REPLIES` map opcodes to the classes;
:func:`decode_request` / :func:`decode_reply` decode any control payload. The driver, the
simulator and the tests all build and read frames through these classes, never by slicing bytes.
A new command is one new class in the table (and its row in the table above).

Calibration blob (download/upload, "download" = host to amplifier as in CANopen SDO): the 6×12
matrix ``C`` as float32, row-major (288 bytes), mapping gauge volts to ``[Fx, Fy, Fz]`` in N and
``[Mx, My, Mz]`` in N·m in the cell's own frame: ``F = C g``.

Data frame (48 bytes)
---------------------
======  =====  ==================================================================
offset  type   field
======  =====  ==================================================================
0       u32    sample counter (pulse index since START; wraps at 2³²)
4       u8     status: bit0 a gauge is overloaded, bit1 SYNC clock missing
5       3 B    reserved (0)
8       36 B   12 gauges, signed 24-bit little-endian; ±(2²³ − 1) counts = ±10 V
44      4 B    padding (0) to the CAN FD length 48
======  =====  ==================================================================

Heartbeat (every 256 samples while streaming): the counter reached and the amplifier's own
oscillator time in µs (u32, wraps). Pulses counted per local second must equal the DAQ's rate:
missed or extra SYNC pulses show as a counter drifting away from ``rate · Δt``.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import ClassVar, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import ProtocolError

__all__ = [
    "DATA_LENGTH",
    "FULL_SCALE_COUNTS",
    "FULL_SCALE_V",
    "HEARTBEAT_EVERY",
    "N_GAUGES",
    "REPLIES",
    "REQUESTS",
    "BadMessage",
    "CalDownloadBegin",
    "CalDownloadBeginReply",
    "CalDownloadEnd",
    "CalDownloadEndReply",
    "CalSegment",
    "CalUpload",
    "CalUploadReply",
    "CalUploadSegment",
    "Command",
    "ErrorCode",
    "ErrorReply",
    "GetStatus",
    "Heartbeat",
    "Identify",
    "IdentifyReply",
    "Message",
    "Reply",
    "Request",
    "SetRate",
    "SetRateReply",
    "Start",
    "StartReply",
    "StatusReply",
    "Stop",
    "StopReply",
    "Tare",
    "TareReply",
    "blob_crc",
    "command_id",
    "data_id",
    "decode_data_frames",
    "decode_reply",
    "decode_request",
    "encode_data_frames",
    "heartbeat_id",
    "join_segments",
    "matrix_from_blob",
    "matrix_to_blob",
    "n_segments",
    "response_id",
    "segments",
]

N_GAUGES = 12
FULL_SCALE_V = 10.0
FULL_SCALE_COUNTS = 2**23 - 1
DATA_LENGTH = 48
HEARTBEAT_EVERY = 256
STATUS_OVERLOAD = 1
STATUS_SYNC_MISSING = 2
SEGMENT_BYTES = 6
HEARTBEAT = struct.Struct("<II")


class Command(IntEnum):
    IDENTIFY = 0x01
    START = 0x02
    STOP = 0x03
    SET_RATE = 0x04
    TARE = 0x05
    CAL_DOWNLOAD_BEGIN = 0x06
    CAL_SEGMENT = 0x07
    CAL_DOWNLOAD_END = 0x08
    CAL_UPLOAD = 0x09
    GET_STATUS = 0x0B


UPLOAD_SEGMENT = 0x8A
ERROR = 0xFF
REPLY_BIT = 0x80


class ErrorCode(IntEnum):
    UNKNOWN_COMMAND = 1
    BAD_ARGUMENT = 2
    BUSY = 3
    CRC_MISMATCH = 4
    MISSING_SEGMENT = 5


def command_id(node: int) -> int:
    return 0x600 + node


def response_id(node: int) -> int:
    return 0x580 + node


def data_id(node: int) -> int:
    return 0x180 + node


def heartbeat_id(node: int) -> int:
    return 0x700 + node


# ---------------------------------------------------------------------------- message table


class BadMessage(ProtocolError):
    """A control payload that is not a message of the table; ``code`` is what the amplifier
    answers it with (unknown command or bad argument)."""

    def __init__(self, message: str, code: ErrorCode) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Message:
    """One control frame: the opcode byte, then the dataclass fields packed by :attr:`ARGS`.

    Subclasses set ``OPCODE`` and ``ARGS`` (a little-endian ``struct`` whose items are the fields
    in order; pad bytes ``x`` are written as 0) and may override :meth:`check` to refuse values
    the protocol does not define.
    """

    OPCODE: ClassVar[int]
    ARGS: ClassVar[struct.Struct] = struct.Struct("<")

    def encode(self) -> bytes:
        values = [getattr(self, f.name) for f in fields(self)]
        try:
            return bytes([self.OPCODE]) + self.ARGS.pack(*values)
        except struct.error as err:
            raise ProtocolError(f"{type(self).__name__}{tuple(values)}: {err}") from err

    @classmethod
    def decode(cls, data: bytes | bytearray) -> Self:
        name = cls.__name__
        if not data or data[0] != cls.OPCODE:
            raise BadMessage(
                f"{name}: payload {bytes(data).hex()} does not start with opcode {cls.OPCODE:#04x}",
                ErrorCode.UNKNOWN_COMMAND,
            )
        if len(data) != 1 + cls.ARGS.size:
            raise BadMessage(
                f"{name}: payload {bytes(data).hex()} has {len(data)} bytes, expected "
                f"{1 + cls.ARGS.size}",
                ErrorCode.BAD_ARGUMENT,
            )
        msg = cls(*cls.ARGS.unpack_from(data, 1))
        msg.check()
        return msg

    def check(self) -> None:
        """Raise :class:`BadMessage` for field values the protocol does not define."""


@dataclass(frozen=True)
class Reply(Message):
    """An amplifier → host control frame (response identifier)."""


@dataclass(frozen=True)
class Request(Message):
    """A host → amplifier command (command identifier); ``REPLY`` is the answer it gets (None:
    no answer)."""

    REPLY: ClassVar[type[Reply] | None]


@dataclass(frozen=True)
class IdentifyReply(Reply):
    OPCODE = Command.IDENTIFY | REPLY_BIT
    ARGS = struct.Struct("<BBBI")
    n_gauges: int
    firmware_major: int
    firmware_minor: int
    serial_number: int


@dataclass(frozen=True)
class Identify(Request):
    OPCODE = Command.IDENTIFY
    REPLY = IdentifyReply


@dataclass(frozen=True)
class StartReply(Reply):
    OPCODE = Command.START | REPLY_BIT


@dataclass(frozen=True)
class Start(Request):
    """``clock`` 0 internal, 1 SYNC (count the DAQ's sample clock)."""

    OPCODE = Command.START
    ARGS = struct.Struct("<B")
    REPLY = StartReply
    clock: int

    def check(self) -> None:
        if self.clock not in (0, 1):
            raise BadMessage(f"START clock {self.clock}: 0 or 1", ErrorCode.BAD_ARGUMENT)


@dataclass(frozen=True)
class StopReply(Reply):
    OPCODE = Command.STOP | REPLY_BIT
    ARGS = struct.Struct("<I")
    pulses: int


@dataclass(frozen=True)
class Stop(Request):
    OPCODE = Command.STOP
    REPLY = StopReply


@dataclass(frozen=True)
class SetRateReply(Reply):
    OPCODE = Command.SET_RATE | REPLY_BIT
    ARGS = struct.Struct("<I")
    rate_hz: int


@dataclass(frozen=True)
class SetRate(Request):
    OPCODE = Command.SET_RATE
    ARGS = struct.Struct("<I")
    REPLY = SetRateReply
    rate_hz: int

    def check(self) -> None:
        if self.rate_hz <= 0:
            raise BadMessage(f"SET_RATE {self.rate_hz} Hz: give > 0", ErrorCode.BAD_ARGUMENT)


@dataclass(frozen=True)
class TareReply(Reply):
    OPCODE = Command.TARE | REPLY_BIT


@dataclass(frozen=True)
class Tare(Request):
    OPCODE = Command.TARE
    ARGS = struct.Struct("<H")
    REPLY = TareReply
    n_samples: int


@dataclass(frozen=True)
class CalDownloadBeginReply(Reply):
    OPCODE = Command.CAL_DOWNLOAD_BEGIN | REPLY_BIT


@dataclass(frozen=True)
class CalDownloadBegin(Request):
    OPCODE = Command.CAL_DOWNLOAD_BEGIN
    ARGS = struct.Struct("<H")
    REPLY = CalDownloadBeginReply
    n_bytes: int


@dataclass(frozen=True)
class CalSegment(Request):
    """One 6-byte piece of the blob, host → amplifier (no answer)."""

    OPCODE = Command.CAL_SEGMENT
    ARGS = struct.Struct(f"<B{SEGMENT_BYTES}s")
    REPLY = None
    index: int
    data: bytes


@dataclass(frozen=True)
class CalDownloadEndReply(Reply):
    OPCODE = Command.CAL_DOWNLOAD_END | REPLY_BIT


@dataclass(frozen=True)
class CalDownloadEnd(Request):
    OPCODE = Command.CAL_DOWNLOAD_END
    ARGS = struct.Struct("<I")
    REPLY = CalDownloadEndReply
    crc32: int


@dataclass(frozen=True)
class CalUploadReply(Reply):
    """Header of an upload; the segments follow as :class:`CalUploadSegment` frames."""

    OPCODE = Command.CAL_UPLOAD | REPLY_BIT
    ARGS = struct.Struct("<HI")
    n_bytes: int
    crc32: int


@dataclass(frozen=True)
class CalUploadSegment(Reply):
    OPCODE = UPLOAD_SEGMENT
    ARGS = struct.Struct(f"<B{SEGMENT_BYTES}s")
    index: int
    data: bytes


@dataclass(frozen=True)
class CalUpload(Request):
    OPCODE = Command.CAL_UPLOAD
    REPLY = CalUploadReply


@dataclass(frozen=True)
class StatusReply(Reply):
    """``state`` 0 idle, 1 armed, 2 streaming; ``flags`` bit1 SYNC missing (as in the data frame status)."""

    OPCODE = Command.GET_STATUS | REPLY_BIT
    ARGS = struct.Struct("<BBxI")
    state: int
    flags: int
    counter: int


@dataclass(frozen=True)
class GetStatus(Request):
    OPCODE = Command.GET_STATUS
    REPLY = StatusReply


@dataclass(frozen=True)
class ErrorReply(Reply):
    """The amplifier refused command ``opcode`` with ``code`` (:class:`ErrorCode`)."""

    OPCODE = ERROR
    ARGS = struct.Struct("<BB")
    opcode: int
    code: int


#: Requests by opcode.
REQUESTS: Mapping[int, type[Request]] = {
    cls.OPCODE: cls
    for cls in (
        Identify,
        Start,
        Stop,
        SetRate,
        Tare,
        CalDownloadBegin,
        CalSegment,
        CalDownloadEnd,
        CalUpload,
        GetStatus,
    )
}
#: Replies by opcode.
REPLIES: Mapping[int, type[Reply]] = {
    cls.OPCODE: cls
    for cls in (
        IdentifyReply,
        StartReply,
        StopReply,
        SetRateReply,
        TareReply,
        CalDownloadBeginReply,
        CalDownloadEndReply,
        CalUploadReply,
        CalUploadSegment,
        StatusReply,
        ErrorReply,
    )
}


def _decode(table: Mapping[int, type[Message]], data: bytes | bytearray, what: str) -> Message:
    if not data:
        raise BadMessage(f"empty {what} payload", ErrorCode.UNKNOWN_COMMAND)
    cls = table.get(data[0])
    if cls is None:
        raise BadMessage(
            f"{what} payload {bytes(data).hex()}: opcode {data[0]:#04x} is not in the message table",
            ErrorCode.UNKNOWN_COMMAND,
        )
    return cls.decode(data)


def decode_request(data: bytes | bytearray) -> Request:
    """Decode a command payload (raises :class:`BadMessage` with the code to answer)."""
    msg = _decode(REQUESTS, data, "command")
    assert isinstance(msg, Request)
    return msg


def decode_reply(data: bytes | bytearray) -> Reply:
    """Decode a response payload (raises :class:`BadMessage`)."""
    msg = _decode(REPLIES, data, "response")
    assert isinstance(msg, Reply)
    return msg


@dataclass(frozen=True)
class Heartbeat:
    """Heartbeat frame: the counter reached and the amplifier's own time in µs (both u32, wrap)."""

    STRUCT: ClassVar[struct.Struct] = HEARTBEAT
    counter: int
    time_us: int

    def encode(self) -> bytes:
        return self.STRUCT.pack(self.counter & 0xFFFFFFFF, self.time_us & 0xFFFFFFFF)

    @classmethod
    def decode(cls, data: bytes | bytearray) -> Heartbeat:
        if len(data) != cls.STRUCT.size:
            raise ProtocolError(f"heartbeat of {len(data)} bytes, expected {cls.STRUCT.size}")
        return cls(*cls.STRUCT.unpack(data))


# ---------------------------------------------------------------------------- calibration blob


def matrix_to_blob(matrix: NDArray[np.float64]) -> bytes:
    """6×12 matrix → 288-byte float32 row-major blob."""
    m = np.asarray(matrix, dtype=float)
    if m.shape != (6, N_GAUGES):
        raise ProtocolError(f"calibration matrix has shape {m.shape}; it must be (6, 12)")
    return m.astype("<f4").tobytes()


def matrix_from_blob(blob: bytes) -> NDArray[np.float64]:
    if len(blob) != 6 * N_GAUGES * 4:
        raise ProtocolError(f"calibration blob has {len(blob)} bytes; expected 288")
    return np.frombuffer(blob, dtype="<f4").astype(float).reshape(6, N_GAUGES)


def segments(blob: bytes) -> list[bytes]:
    """Split a blob into 6-byte segment payloads (the last zero-padded)."""
    return [
        blob[i : i + SEGMENT_BYTES].ljust(SEGMENT_BYTES, b"\0")
        for i in range(0, len(blob), SEGMENT_BYTES)
    ]


def n_segments(n_bytes: int) -> int:
    """Segments that carry a blob of ``n_bytes``."""
    return (n_bytes + SEGMENT_BYTES - 1) // SEGMENT_BYTES


def join_segments(parts: Mapping[int, bytes], n_bytes: int) -> bytes:
    """The blob of ``n_bytes`` from segments by index (any order).

    Raises
    ------
    BadMessage
        A segment is missing (code ``MISSING_SEGMENT``).
    """
    missing = [i for i in range(n_segments(n_bytes)) if i not in parts]
    if missing:
        raise BadMessage(
            f"calibration segment {missing[0]} of {n_segments(n_bytes)} missing",
            ErrorCode.MISSING_SEGMENT,
        )
    return b"".join(parts[i] for i in range(n_segments(n_bytes)))[:n_bytes]


def blob_crc(blob: bytes) -> int:
    """CRC-32 (zlib) of a calibration blob, as CAL_DOWNLOAD_END and CAL_UPLOAD carry it."""
    return zlib.crc32(blob)


# ---------------------------------------------------------------------------- data frames


def encode_data_frames(
    counters: int | ArrayLike,
    gauges_v: NDArray[np.float64],
    status: NDArray[np.uint8] | None = None,
) -> tuple[list[bytes], NDArray[np.bool_]]:
    """Encode ``n`` samples (gauge volts, shape (n, 12)) as ``n`` 48-byte data frames.

    ``counters`` is each sample's counter (shape (n,), sent modulo 2³²) or, as an int, the
    first of ``counters .. counters + n − 1``. Clips at full scale and sets the overload status
    bit. Returns the frames and the per-sample overload flags.
    """
    g = np.asarray(gauges_v, dtype=float)
    n = g.shape[0]
    if isinstance(counters, int | np.integer):
        ctr = int(counters) + np.arange(n, dtype=np.int64)
    else:
        ctr = np.asarray(counters, dtype=np.int64).reshape(-1)
        if ctr.shape != (n,):
            raise ProtocolError(f"{ctr.size} counters for {n} samples; give one per sample")
    counts = np.rint(g / FULL_SCALE_V * 2**23)
    over = np.any(np.abs(counts) > FULL_SCALE_COUNTS, axis=1)
    np.clip(counts, -FULL_SCALE_COUNTS, FULL_SCALE_COUNTS, out=counts)
    buf = np.zeros((n, DATA_LENGTH), dtype=np.uint8)
    buf[:, 0:4] = (ctr & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(n, 4)
    st = np.zeros(n, dtype=np.uint8) if status is None else np.asarray(status, np.uint8).copy()
    st |= over.astype(np.uint8) * STATUS_OVERLOAD
    buf[:, 4] = st
    c32 = counts.astype("<i4").view(np.uint8).reshape(n, N_GAUGES, 4)[:, :, :3]
    buf[:, 8:44] = c32.reshape(n, 36)
    raw = buf.tobytes()
    return [raw[i * DATA_LENGTH : (i + 1) * DATA_LENGTH] for i in range(n)], over


def decode_data_frames(
    payloads: Sequence[bytes | bytearray],
) -> tuple[NDArray[np.int64], NDArray[np.uint8], NDArray[np.float64]]:
    """Decode data frames in one vectorised pass.

    Returns
    -------
    counters : ndarray of int64, shape (n,)
        As sent (u32, not unwrapped).
    status : ndarray of uint8, shape (n,)
    gauges_v : ndarray, shape (n, 12)
        Gauge volts.
    """
    if not payloads:
        return np.zeros(0, np.int64), np.zeros(0, np.uint8), np.zeros((0, N_GAUGES))
    raw = b"".join(payloads)
    bad = [i for i, d in enumerate(payloads) if len(d) != DATA_LENGTH]
    if bad:
        raise ProtocolError(
            f"data frame {bad[0]} has {len(payloads[bad[0]])} bytes, expected {DATA_LENGTH}; "
            "the bus must run CAN FD"
        )
    buf = np.frombuffer(raw, dtype=np.uint8).reshape(-1, DATA_LENGTH)
    counters = buf[:, 0:4].copy().view("<u4").reshape(-1).astype(np.int64)
    status = buf[:, 4].copy()
    words = np.zeros((buf.shape[0], N_GAUGES, 4), dtype=np.uint8)
    words[:, :, 1:] = buf[:, 8:44].reshape(-1, N_GAUGES, 3)
    counts = words.view("<i4").reshape(-1, N_GAUGES) >> 8
    gauges_v = np.multiply(counts, FULL_SCALE_V / 2**23, dtype=np.float64)
    return counters, status, gauges_v
