"""ATI Net F/T CAN bus protocol: the message table (driver, simulator and tests share it).

From the Net F/T Installation and Operation Manual (ATI Industrial Automation, document
9620-05-Net FT-11, section 15 "CAN Bus Operation"; a public copy is yumpu.com document 54843814,
pages 89-90), and from two independent public Net F/T CAN clients (an Arduino one and a TI Tiva
one; see ``tests/drivers/netft/test_netft_can_references.py`` for the exchanges and where they
come from):

- the Net F/T answers a basic CAN protocol (classic CAN, 11-bit identifiers) that reads its
  force/torque data and system status word without a DeviceNet scanner; its **base address**
  and bit rate are set with its DIP switches (manual §15.1, referring to §3.10, whose table was
  not in the copy; both clients ran at 500 kbit/s with base 0x1B0), CAN Bus selected on its
  Communications page;
- a **request** message to the base address (DLC 1) copies the current force/torque set into an
  output buffer and sends it: ``0x01`` REQUEST LONG (32-bit values in four messages; the Arduino
  client), ``0x02`` REQUEST SHORT (16-bit values in two messages; manual Table 15.2), ``0x04``
  BIAS zeros the readings at the current load (Table 15.3); a clear-threshold-latch command
  exists (Table 15.4), but its byte was in neither source: :data:`CLEAR_THRESHOLD_LATCH` is
  ``0x08``, the next bit, **not confirmed** (the driver never sends it); a request received
  during a transmission ends it and is served;
- **little endian**, two's complement: ``56 02`` is ``0x0256``; ``0F CF DA FD`` is
  ``0xFDDACF0F`` = −35 991 793 (the manual's own examples, :data:`MANUAL_EXAMPLES`; the
  manual prints the 32-bit one with a doubled byte, ``0x0F 0xCF 0xDA 0xDA 0xFD``);
- short answers (Table 15.2): base + 5 = Fx, Tx, Fy, Ty (INT); base + 6 = Fz, Tz, system status,
  sample number (INT);
- long answers (Table 15.1, whose body was not in the copy): four messages of two DINT each;
  base + 1, + 2, + 3 = the x, y, z axis, force in bytes 0-3 and torque in bytes 4-7 (the Arduino
  client, whose own test reads ``0F CF DA FD 00 00 00 00`` as force −35 991 793);
  base + 4 = the status message: read here as status word, sample number, as the short answers
  carry them (**inferred**: no source decodes it);
- values are **counts**: force = counts / counts-per-force (its force unit), torque = counts /
  counts-per-torque (its torque unit); the counts per unit are the sensor's calibration, read
  from the device (its configuration page, or the Read Calibration Info command of its
  Ethernet interface, :class:`CalibrationInfo`), never assumed.

Frame layout (``<``: little endian)::

    id          DLC  bytes
    base        1    command (REQUEST_LONG 0x01, REQUEST_SHORT 0x02, BIAS 0x04, ...)
    base + 1    8    <ii  Fx, Tx      counts
    base + 2    8    <ii  Fy, Ty
    base + 3    8    <ii  Fz, Tz
    base + 4    8    <II  status word, sample number
    base + 5    8    <hhhh  Fx, Tx, Fy, Ty          (short)
    base + 6    8    <hhhh  Fz, Tz, status, sample  (short)

Raw Data Transfer (RDT) over UDP, port :data:`RDT_PORT` 49152, big endian (network order):
a request (:class:`RdtRequest`) of ``uint16 command_header = 0x1234, uint16 command, uint32
sample_count`` (0x0000 stop, 0x0002 start real-time streaming, 0x0003 start buffered streaming,
0x0042 set software bias; ``sample_count`` records, 0 = until stopped) answered by records
(:class:`RdtRecord`) of ``uint32 rdt_sequence`` (1 for the first record after a start, +1 per
record sent: a jump is a lost datagram), ``uint32 ft_sequence`` (the sensor's own sample
counter), ``uint32 status``, ``int32 Fx, Fy, Fz, Tx, Ty, Tz`` counts; one record per datagram in
real-time mode, several in buffered mode.

The Ethernet interface's Read Calibration Info (manual §11: TCP port 49151, every command 20
bytes, every response headed 0x1234, READCALINFO = 1; the structures and unit codes as in ATI's
Ethernet Axia manual §10.4-10.5, document 9610-05-Ethernet Axia-09; network byte order)::

    command   >B19x          READCALINFO = 1, 19 reserved zero bytes
    response  >HBBII6H       header 0x1234, force units, torque units, counts per force,
                             counts per torque, six 16-bit scale factors
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import ProtocolError, SetupError

__all__ = [
    "AXES",
    "CLEAR_THRESHOLD_LATCH",
    "FORCE_UNITS",
    "MANUAL_EXAMPLES",
    "MAX_BASE",
    "RDT_PORT",
    "TCP_PORT",
    "TORQUE_UNITS",
    "CalibrationInfo",
    "Command",
    "LongPair",
    "LongStatus",
    "RdtBlock",
    "RdtCommand",
    "RdtRecord",
    "RdtRequest",
    "Request",
    "ShortXY",
    "ShortZ",
    "check_base",
    "decode",
    "decode_i16",
    "decode_i32",
    "decode_long",
    "decode_rdt",
    "encode_rdt",
    "long_frames",
    "long_payloads",
]

AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


class Command(IntEnum):
    """The one-byte requests to the base address."""

    REQUEST_LONG = 0x01
    REQUEST_SHORT = 0x02
    BIAS = 0x04
    CLEAR_THRESHOLD_LATCH = 0x08


#: in no source found (see the module docstring): the next bit after BIAS, never sent
CLEAR_THRESHOLD_LATCH = Command.CLEAR_THRESHOLD_LATCH

#: the highest base address: base + 6 is still an 11-bit identifier
MAX_BASE = 0x7FF - 6

#: the manual's byte-order examples: (bytes received, signed value)
MANUAL_EXAMPLES: tuple[tuple[bytes, int], ...] = (
    (bytes([0x56, 0x02]), 0x0256),
    (bytes([0x0F, 0xCF, 0xDA, 0xFD]), -35991793),
)

#: unit codes of Read Calibration Info → SI factor (N per unit, N·m per unit)
FORCE_UNITS: dict[int, tuple[str, float]] = {
    1: ("lbf", 4.4482216152605),
    2: ("N", 1.0),
    3: ("klbf", 4448.2216152605),
    4: ("kN", 1e3),
    5: ("kgf", 9.80665),
    6: ("gf", 9.80665e-3),
}
TORQUE_UNITS: dict[int, tuple[str, float]] = {
    1: ("lbf-in", 0.112984829027617),
    2: ("lbf-ft", 1.3558179483314),
    3: ("N-m", 1.0),
    4: ("N-mm", 1e-3),
    5: ("kgf-cm", 0.0980665),
    6: ("kN-m", 1e3),
}


def check_base(base: int) -> int:
    """A base address the identifiers fit (0 .. :data:`MAX_BASE`); :class:`SetupError` else."""
    if not 0 <= base <= MAX_BASE:
        raise SetupError(
            f"Net F/T CAN base address {base:#x}: give 0x000..{MAX_BASE:#x} as its DIP switches "
            "set it (base + 6 must be an 11-bit identifier)"
        )
    return base


def decode_i16(b: bytes) -> int:
    """A little-endian two's-complement 16-bit value."""
    return int(struct.unpack("<h", b)[0])


def decode_i32(b: bytes) -> int:
    """A little-endian two's-complement 32-bit value."""
    return int(struct.unpack("<i", b)[0])


@dataclass(frozen=True)
class Request:
    """To the Net F/T (id ``base``, DLC 1)."""

    command: Command
    OFFSET = 0

    def encode(self) -> bytes:
        return bytes([int(self.command)])

    @classmethod
    def decode(cls, data: bytes) -> Request:
        if len(data) != 1:
            raise ProtocolError(f"Net F/T request of {len(data)} bytes; it is one byte")
        try:
            return cls(Command(data[0]))
        except ValueError as err:
            raise ProtocolError(f"Net F/T request {data[0]:#04x} is not a known command") from err


@dataclass(frozen=True)
class LongPair:
    """Base + 1 + axis: the axis's force and torque counts (``axis`` 0 x, 1 y, 2 z)."""

    axis: int
    force: int
    torque: int

    _FMT = struct.Struct("<ii")

    @property
    def offset(self) -> int:
        return 1 + self.axis

    def encode(self) -> bytes:
        return self._FMT.pack(self.force, self.torque)

    @classmethod
    def decode(cls, axis: int, data: bytes) -> LongPair:
        f, t = _unpack(cls._FMT, data, f"long data base+{1 + axis}")
        return cls(axis, int(f), int(t))


@dataclass(frozen=True)
class LongStatus:
    """Base + 4: the system status word (0: all well) and the sample number."""

    status: int
    sample: int
    OFFSET = 4

    _FMT = struct.Struct("<II")

    def encode(self) -> bytes:
        return self._FMT.pack(self.status & 0xFFFFFFFF, self.sample & 0xFFFFFFFF)

    @classmethod
    def decode(cls, data: bytes) -> LongStatus:
        s, n = _unpack(cls._FMT, data, "long data base+4")
        return cls(int(s), int(n))


@dataclass(frozen=True)
class ShortXY:
    """Base + 5: Fx, Tx, Fy, Ty in short format (16-bit)."""

    fx: int
    tx: int
    fy: int
    ty: int
    OFFSET = 5

    _FMT = struct.Struct("<hhhh")

    def encode(self) -> bytes:
        return self._FMT.pack(self.fx, self.tx, self.fy, self.ty)

    @classmethod
    def decode(cls, data: bytes) -> ShortXY:
        return cls(*(int(v) for v in _unpack(cls._FMT, data, "short data base+5")))


@dataclass(frozen=True)
class ShortZ:
    """Base + 6: Fz, Tz, system status, sample number in short format (16-bit)."""

    fz: int
    tz: int
    status: int
    sample: int
    OFFSET = 6

    _FMT = struct.Struct("<hhhh")

    def encode(self) -> bytes:
        return self._FMT.pack(self.fz, self.tz, self.status, self.sample)

    @classmethod
    def decode(cls, data: bytes) -> ShortZ:
        return cls(*(int(v) for v in _unpack(cls._FMT, data, "short data base+6")))


Message = Request | LongPair | LongStatus | ShortXY | ShortZ


def _unpack(fmt: struct.Struct, data: bytes, what: str) -> tuple[int, ...]:
    if len(data) != fmt.size:
        raise ProtocolError(f"Net F/T {what}: {len(data)} bytes, expected {fmt.size}")
    return tuple(fmt.unpack(data))


def decode(base: int, arbitration_id: int, data: bytes) -> Message:
    """The message of frame ``arbitration_id`` (``base`` .. ``base + 6``).

    Raises
    ------
    ProtocolError
        Not one of the Net F/T's identifiers, or a payload of the wrong length.
    """
    off = arbitration_id - base
    if off == 0:
        return Request.decode(data)
    if off in (1, 2, 3):
        return LongPair.decode(off - 1, data)
    if off == 4:
        return LongStatus.decode(data)
    if off == 5:
        return ShortXY.decode(data)
    if off == 6:
        return ShortZ.decode(data)
    raise ProtocolError(
        f"CAN id {arbitration_id:#x} is not a Net F/T message of base {base:#x} (base..base+6)"
    )


_PAIR = struct.Struct("<ii")
_STATUS = struct.Struct("<II")


def decode_long(offset: int, data: bytes) -> tuple[int, int]:
    """The two values of long answer ``base + offset`` (1..3: force, torque counts; 4: status
    word, sample number) without building a message object: the stream's fast path.

    Raises
    ------
    ProtocolError
        ``offset`` not 1..4, or not 8 bytes.
    """
    if len(data) != 8 or not 1 <= offset <= 4:
        raise ProtocolError(f"Net F/T long answer base+{offset} of {len(data)} bytes")
    a, b = (_STATUS if offset == 4 else _PAIR).unpack(data)
    return int(a), int(b)


def long_payloads(
    counts: NDArray[np.int64], status: int, samples: NDArray[np.int64]
) -> NDArray[np.uint8]:
    """The four long answers of ``n`` samples at once: shape (n, 4, 8) bytes, answer ``j`` of
    sample ``i`` is base + 1 + j (``counts`` shape (n, 6) in :data:`AXES` order)."""
    n = counts.shape[0]
    words = np.empty((n, 4, 2), dtype="<u4")
    c = counts.astype(np.int64) & 0xFFFFFFFF
    words[:, 0, 0], words[:, 0, 1] = c[:, 0], c[:, 3]
    words[:, 1, 0], words[:, 1, 1] = c[:, 1], c[:, 4]
    words[:, 2, 0], words[:, 2, 1] = c[:, 2], c[:, 5]
    words[:, 3, 0] = status & 0xFFFFFFFF
    words[:, 3, 1] = np.asarray(samples, dtype=np.int64) & 0xFFFFFFFF
    return words.view(np.uint8).reshape(n, 4, 8)


def long_frames(counts: Sequence[int], status: int, sample: int) -> list[tuple[int, bytes]]:
    """The four long-data answers ``(offset, payload)`` of one sample: ``counts`` in
    :data:`AXES` order (Fx Fy Fz Tx Ty Tz)."""
    fx, fy, fz, tx, ty, tz = (int(c) for c in counts)
    return [
        (1, LongPair(0, fx, tx).encode()),
        (2, LongPair(1, fy, ty).encode()),
        (3, LongPair(2, fz, tz).encode()),
        (4, LongStatus(status, sample).encode()),
    ]


@dataclass(frozen=True)
class CalibrationInfo:
    """The sensor's counts per unit (Read Calibration Info; or its configuration page).

    Attributes
    ----------
    force_unit, torque_unit : int
        Unit codes (:data:`FORCE_UNITS`, :data:`TORQUE_UNITS`).
    counts_per_force, counts_per_torque : int
        Counts per force unit and per torque unit.
    scale_factors : tuple of 6 int
        Further scaling of the 16-bit (short) counts.
    """

    force_unit: int
    torque_unit: int
    counts_per_force: int
    counts_per_torque: int
    scale_factors: tuple[int, ...] = (1, 1, 1, 1, 1, 1)

    HEADER = 0x1234
    READCALINFO = 1
    SIZE = 24
    _RESPONSE = struct.Struct(">HBBII6H")

    def __post_init__(self) -> None:
        if self.force_unit not in FORCE_UNITS or self.torque_unit not in TORQUE_UNITS:
            raise SetupError(
                f"Net F/T units {self.force_unit}/{self.torque_unit}: give a force unit code "
                f"of {sorted(FORCE_UNITS)} and a torque unit code of {sorted(TORQUE_UNITS)}"
            )
        if self.counts_per_force <= 0 or self.counts_per_torque <= 0:
            raise SetupError(
                f"Net F/T counts per unit {self.counts_per_force}/{self.counts_per_torque}: "
                "give the sensor's positive counts per force and per torque unit"
            )

    @classmethod
    def command(cls) -> bytes:
        return bytes([cls.READCALINFO]) + bytes(19)

    def encode(self) -> bytes:
        return self._RESPONSE.pack(
            self.HEADER,
            self.force_unit,
            self.torque_unit,
            self.counts_per_force,
            self.counts_per_torque,
            *self.scale_factors,
        )

    @classmethod
    def decode(cls, data: bytes) -> CalibrationInfo:
        v = _unpack(cls._RESPONSE, data, "Read Calibration Info response")
        if v[0] != cls.HEADER:
            raise ProtocolError(f"Net F/T calibration info header {v[0]:#06x}, not 0x1234")
        return cls(v[1], v[2], v[3], v[4], tuple(v[5:11]))

    def si_per_count(self) -> NDArray[np.float64]:
        """N per count (Fx Fy Fz) and N·m per count (Tx Ty Tz), shape (6,)."""
        f = FORCE_UNITS[self.force_unit][1] / self.counts_per_force
        t = TORQUE_UNITS[self.torque_unit][1] / self.counts_per_torque
        return np.array([f, f, f, t, t, t])

    def matrix(self) -> NDArray[np.float64]:
        """The 6×6 ``F = C g`` of counts ``g`` in :data:`AXES` order (diagonal)."""
        return np.diag(self.si_per_count())


#: the Net F/T's RDT UDP port
RDT_PORT = 49152
#: its TCP command port (Read Calibration Info; manual §11.1)
TCP_PORT = 49151


class RdtCommand(IntEnum):
    STOP = 0x0000
    START_REALTIME = 0x0002
    START_BUFFERED = 0x0003
    SET_BIAS = 0x0042


@dataclass(frozen=True)
class RdtRequest:
    """An RDT request datagram (8 bytes)."""

    command: RdtCommand
    sample_count: int = 0

    HEADER = 0x1234
    _FMT = struct.Struct(">HHI")

    def encode(self) -> bytes:
        return self._FMT.pack(self.HEADER, int(self.command), self.sample_count)

    @classmethod
    def decode(cls, data: bytes) -> RdtRequest:
        header, command, count = _unpack(cls._FMT, data, "RDT request")
        if header != cls.HEADER:
            raise ProtocolError(f"RDT request header {header:#06x}, not 0x1234")
        try:
            return cls(RdtCommand(command), int(count))
        except ValueError as err:
            raise ProtocolError(f"RDT command {command:#06x} is not known") from err


@dataclass(frozen=True)
class RdtRecord:
    """One RDT record (36 bytes); ``counts`` in :data:`AXES` order."""

    rdt_sequence: int
    ft_sequence: int
    status: int
    counts: tuple[int, int, int, int, int, int]

    SIZE = 36
    _FMT = struct.Struct(">III6i")

    def encode(self) -> bytes:
        return self._FMT.pack(
            self.rdt_sequence & 0xFFFFFFFF,
            self.ft_sequence & 0xFFFFFFFF,
            self.status & 0xFFFFFFFF,
            *self.counts,
        )

    @classmethod
    def decode_all(cls, datagram: bytes) -> list[RdtRecord]:
        """The records of one datagram (one in real-time mode, several when buffered).

        Raises
        ------
        ProtocolError
            A length that is not a whole number of records.
        """
        if not datagram or len(datagram) % cls.SIZE:
            raise ProtocolError(
                f"RDT datagram of {len(datagram)} bytes is not a whole number of "
                f"{cls.SIZE}-byte records"
            )
        out = []
        for off in range(0, len(datagram), cls.SIZE):
            v = cls._FMT.unpack_from(datagram, off)
            out.append(cls(int(v[0]), int(v[1]), int(v[2]), tuple(int(x) for x in v[3:9])))  # type: ignore[arg-type]
        return out


#: one RDT record as a numpy record (big endian): the stream's fast path
RDT_DTYPE = np.dtype(
    [("rdt_sequence", ">u4"), ("ft_sequence", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))]
)


@dataclass(frozen=True, eq=False)
class RdtBlock:
    """The records of one or more datagrams as arrays (``n`` records).

    Attributes
    ----------
    rdt_sequence, ft_sequence, status : ndarray of int64, shape (n,)
    counts : ndarray of int64, shape (n, 6)
        In :data:`AXES` order.
    """

    rdt_sequence: NDArray[np.int64]
    ft_sequence: NDArray[np.int64]
    status: NDArray[np.int64]
    counts: NDArray[np.int64]


def decode_rdt(datagram: bytes) -> RdtBlock:
    """The records of one datagram at once (the same bytes as :meth:`RdtRecord.decode_all`).

    Raises
    ------
    ProtocolError
        A length that is not a whole number of 36-byte records.
    """
    if not datagram or len(datagram) % RdtRecord.SIZE:
        raise ProtocolError(
            f"RDT datagram of {len(datagram)} bytes is not a whole number of "
            f"{RdtRecord.SIZE}-byte records"
        )
    a = np.frombuffer(datagram, dtype=RDT_DTYPE)
    return RdtBlock(
        a["rdt_sequence"].astype(np.int64),
        a["ft_sequence"].astype(np.int64),
        a["status"].astype(np.int64),
        a["counts"].astype(np.int64),
    )


def encode_rdt(
    rdt_sequence: NDArray[np.int64],
    ft_sequence: NDArray[np.int64],
    status: int,
    counts: NDArray[np.int64],
) -> bytes:
    """``n`` records as one buffered datagram (``counts`` shape (n, 6), :data:`AXES` order)."""
    a = np.zeros(len(rdt_sequence), dtype=RDT_DTYPE)
    a["rdt_sequence"] = np.asarray(rdt_sequence, dtype=np.int64) & 0xFFFFFFFF
    a["ft_sequence"] = np.asarray(ft_sequence, dtype=np.int64) & 0xFFFFFFFF
    a["status"] = status & 0xFFFFFFFF
    a["counts"] = counts
    return a.tobytes()
