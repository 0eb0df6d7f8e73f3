"""The CANopen load cell amplifier's wire vocabulary: object dictionary entries, PDO layout, EMCY.

Shared by the driver (:mod:`dimacq.drivers.canopen_loadcell.driver`), the simulator
(:mod:`dimacq.simulators.canopen_loadcell`) and the tests; the object dictionary itself is the
EDS file ``config/canopen/loadcell.eds`` (CiA 306), read by ``canopen`` on both sides.

Objects (CiA 301 communication, measuring-device objects after CiA 404)::

    0x1000        device type            U32   0x194 (CiA 404)
    0x1017        producer heartbeat     U16   ms
    0x1018:04     serial number          U32
    0x1800+n      TPDO n communication   COB-ID, transmission type 254 (event: each sample)
    0x1A00+n      TPDO n mapping         [0x2105 counter low word U16, gauge I24, gauge I24]
    0x2100        sample clock source    U8    0 internal, 1 the DAQ's SYNC input
    0x2101        sample rate            U32   Hz
    0x2102        sample counter         U32   SYNC pulses counted since NMT start
    0x2103        status                 U8    bit0 overload, bit1 SYNC input missing
    0x2104        tare                   U16   samples averaged (write: tare now)
    0x2105        counter low word       U16   PDO-mapped with every sample
    0x2200        calibration matrix     DOMAIN 288 bytes: 6×12 REAL32, row-major, F = C g
    0x2201/2202   calibration serial / date   VISIBLE_STRING
    0x6100:01..12 gauge inputs           INTEGER24 counts (PDO-mapped)
    0x6101        gauge full scale       REAL32 V at 2²³ counts
    0x6130:01..06 computed load C g      REAL32 N, N·m (read by SDO, mappable)

A sample is the amplifier's count ``k`` of the DAQ's SYNC pulses (the DAQ's sample ``k``, as
with the CAN FD amplifier); every TPDO of that sample carries ``k mod 2¹⁶``, so a frame is
filed by its own label and a lost frame makes only its sample incomplete. EMCY frames carry
the sample counter at which the error was seen in their manufacturer bytes
(:data:`EMCY_DATA`: ``<I`` counter, one spare byte).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dimacq.drivers.loadcell.protocol import matrix_from_blob, matrix_to_blob
from dimacq.errors import ProtocolError, SetupError

__all__ = [
    "CALIBRATION_DATE",
    "CALIBRATION_MATRIX",
    "CALIBRATION_SERIAL",
    "CLOCK_SOURCE",
    "COUNTER",
    "COUNTER_LOW",
    "EMCY_BUS_OFF_RECOVERED",
    "EMCY_DATA",
    "EMCY_HARDWARE",
    "EMCY_SYNC_MISSING",
    "FULL_SCALE",
    "GAUGES",
    "HEARTBEAT_TIME",
    "IDENTITY",
    "LOADS",
    "N_GAUGES",
    "SAMPLE_RATE",
    "STATUS",
    "TARE",
    "MappedEntry",
    "PdoLayout",
    "TpdoLayout",
    "emcy_counter",
    "emcy_data",
    "matrix_from_blob",
    "matrix_to_blob",
    "object_name",
]

N_GAUGES = 12
HEARTBEAT_TIME = 0x1017
IDENTITY = 0x1018
CLOCK_SOURCE = 0x2100
SAMPLE_RATE = 0x2101
COUNTER = 0x2102
STATUS = 0x2103
TARE = 0x2104
COUNTER_LOW = 0x2105
CALIBRATION_MATRIX = 0x2200
CALIBRATION_SERIAL = 0x2201
CALIBRATION_DATE = 0x2202
GAUGES = 0x6100
FULL_SCALE = 0x6101
LOADS = 0x6130
STATUS_OVERLOAD = 1
STATUS_SYNC_MISSING = 2

#: EMCY codes the amplifier sends (CiA 301 classes)
EMCY_HARDWARE = 0x5000  # device hardware (e.g. bridge excitation)
EMCY_SYNC_MISSING = 0x8100  # monitoring / communication: the SYNC input lost
EMCY_BUS_OFF_RECOVERED = 0x8140  # recovered from bus-off
#: manufacturer bytes of an EMCY: the sample counter then, and a spare byte
EMCY_DATA = struct.Struct("<IB")

_NAMES = {
    0x1000: "device type",
    0x1017: "producer heartbeat time",
    0x1018: "identity",
    CLOCK_SOURCE: "sample clock source",
    SAMPLE_RATE: "sample rate",
    COUNTER: "sample counter",
    STATUS: "status",
    TARE: "tare",
    COUNTER_LOW: "sample counter low word",
    CALIBRATION_MATRIX: "calibration matrix",
    CALIBRATION_SERIAL: "calibration serial number",
    CALIBRATION_DATE: "calibration date",
    GAUGES: "gauge input",
    FULL_SCALE: "gauge full scale",
    LOADS: "computed load",
}


def object_name(index: int, subindex: int = 0) -> str:
    """``"calibration matrix (0x2200:00)"``: how errors name an object."""
    if 0x1800 <= index < 0x1A00:
        name = f"TPDO{index - 0x1800 + 1} communication parameter"
    elif 0x1A00 <= index < 0x1C00:
        name = f"TPDO{index - 0x1A00 + 1} mapping parameter"
    else:
        name = _NAMES.get(index, "object")
    return f"{name} (0x{index:04X}:{subindex:02X})"


def emcy_data(counter: int) -> bytes:
    """The 5 manufacturer bytes of an EMCY raised at sample ``counter``."""
    return EMCY_DATA.pack(counter & 0xFFFFFFFF, 0)


def emcy_counter(data: bytes) -> int:
    """The sample counter an EMCY's manufacturer bytes carry."""
    if len(data) < EMCY_DATA.size:
        raise ProtocolError(f"EMCY manufacturer data {bytes(data).hex()}: expected 5 bytes")
    return int(EMCY_DATA.unpack_from(data)[0])


@dataclass(frozen=True)
class MappedEntry:
    """One object mapped in a PDO: ``index:subindex``, ``bits`` long at bit ``offset``."""

    index: int
    subindex: int
    bits: int
    offset: int


@dataclass(frozen=True)
class TpdoLayout:
    """What one TPDO carries, as read from its mapping parameter: the byte offset of the
    counter low word and, per gauge carried, (gauge 0-based, byte offset) of its INTEGER24."""

    cob_id: int
    length: int
    counter_at: int
    gauges: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class PdoLayout:
    """The TPDOs of one amplifier that carry its samples (built by :meth:`from_mappings`)."""

    tpdos: tuple[TpdoLayout, ...]
    full_scale_v: float

    @classmethod
    def from_mappings(
        cls,
        mappings: Sequence[tuple[int, bool, Sequence[MappedEntry]]],
        *,
        full_scale_v: float,
        where: str,
    ) -> PdoLayout:
        """``mappings``: per TPDO (COB-ID, enabled, mapped entries), as read from the node.

        Raises
        ------
        SetupError
            A gauge is unmapped or mapped twice, a TPDO maps gauges without the counter low
            word, an entry is not byte-aligned or has the wrong length; names the TPDO.
        """
        tpdos: list[TpdoLayout] = []
        seen: dict[int, int] = {}
        for k, (cob_id, enabled, entries) in enumerate(mappings):
            if not enabled:
                continue
            counter_at = -1
            gauges: list[tuple[int, int]] = []
            length = 0
            for e in entries:
                length = max(length, (e.offset + e.bits + 7) // 8)
                if e.index == COUNTER_LOW:
                    if e.bits != 16 or e.offset % 8:
                        raise SetupError(
                            f"{where}: TPDO{k + 1} maps {object_name(e.index, e.subindex)} with "
                            f"{e.bits} bits at bit {e.offset}; map it as 16 bits on a byte boundary"
                        )
                    counter_at = e.offset // 8
                elif e.index == GAUGES:
                    if e.bits != 24 or e.offset % 8 or not 1 <= e.subindex <= N_GAUGES:
                        raise SetupError(
                            f"{where}: TPDO{k + 1} maps {object_name(e.index, e.subindex)} with "
                            f"{e.bits} bits at bit {e.offset}; map gauges 1..12 as 24 bits on "
                            "byte boundaries"
                        )
                    if e.subindex in seen:
                        raise SetupError(
                            f"{where}: gauge {e.subindex} is mapped in TPDO{seen[e.subindex]} "
                            f"and TPDO{k + 1}; map each gauge once"
                        )
                    seen[e.subindex] = k + 1
                    gauges.append((e.subindex - 1, e.offset // 8))
            if gauges and counter_at < 0:
                raise SetupError(
                    f"{where}: TPDO{k + 1} (COB-ID 0x{cob_id:03X}) maps gauges without the sample "
                    f"counter {object_name(COUNTER_LOW)}; map it in every TPDO that carries gauges"
                )
            if gauges:
                tpdos.append(TpdoLayout(cob_id, length, counter_at, tuple(gauges)))
        missing = [g for g in range(1, N_GAUGES + 1) if g not in seen]
        if missing:
            raise SetupError(
                f"{where}: gauges {missing} are not mapped in any enabled TPDO; map all 12 "
                f"gauge inputs ({object_name(GAUGES, 1)} ...) in the node's TPDO mapping"
            )
        if not full_scale_v > 0:
            raise SetupError(f"{where}: {object_name(FULL_SCALE)} = {full_scale_v}; must be > 0")
        return cls(tuple(tpdos), float(full_scale_v))

    @property
    def cob_ids(self) -> tuple[int, ...]:
        return tuple(t.cob_id for t in self.tpdos)

    def encode(self, counters: NDArray[np.int64], counts: NDArray[np.int64]) -> list[list[bytes]]:
        """Frames of ``n`` samples: per TPDO a list of ``n`` payloads (``counts`` shape (n, 12),
        INTEGER24 counts; ``counters`` the samples' counters)."""
        n = counts.shape[0]
        low = (np.asarray(counters, np.int64) & 0xFFFF).astype("<u2").view(np.uint8).reshape(n, 2)
        c32 = np.ascontiguousarray(counts, dtype="<i4").view(np.uint8).reshape(n, N_GAUGES, 4)
        out = []
        for t in self.tpdos:
            buf = np.zeros((n, t.length), dtype=np.uint8)
            buf[:, t.counter_at : t.counter_at + 2] = low
            for g, at in t.gauges:
                buf[:, at : at + 3] = c32[:, g, :3]
            raw = buf.tobytes()
            out.append([raw[i * t.length : (i + 1) * t.length] for i in range(n)])
        return out

    def counts_of(self, volts: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Gauge volts (n, 12) → INTEGER24 counts (clipped) and per-sample overload."""
        fs = 2**23 - 1
        counts = np.rint(np.asarray(volts, float) / self.full_scale_v * 2**23)
        over = np.any(np.abs(counts) > fs, axis=1)
        np.clip(counts, -fs, fs, out=counts)
        return counts.astype(np.int64), over

    def decode(
        self, tpdo: int, payloads: Sequence[bytes]
    ) -> tuple[NDArray[np.int64], list[int], NDArray[np.float64]]:
        """Payloads of TPDO number ``tpdo`` (in :attr:`tpdos`) → (counter low words (n,),
        gauges carried (0-based), volts (n, len(gauges)))."""
        t = self.tpdos[tpdo]
        bad = [i for i, d in enumerate(payloads) if len(d) < t.length]
        if bad:
            raise ProtocolError(
                f"TPDO COB-ID 0x{t.cob_id:03X}: frame of {len(payloads[bad[0]])} bytes, the "
                f"mapping needs {t.length}"
            )
        buf = np.frombuffer(b"".join(bytes(d[: t.length]) for d in payloads), np.uint8)
        buf = buf.reshape(-1, t.length)
        low = buf[:, t.counter_at : t.counter_at + 2].copy().view("<u2").reshape(-1)
        words = np.zeros((buf.shape[0], len(t.gauges), 4), dtype=np.uint8)
        for j, (_g, at) in enumerate(t.gauges):
            words[:, j, 1:] = buf[:, at : at + 3]
        counts = words.view("<i4").reshape(buf.shape[0], len(t.gauges)) >> 8
        volts = np.multiply(counts, self.full_scale_v / 2**23, dtype=np.float64)
        return np.asarray(low, dtype=np.int64), [g for g, _ in t.gauges], volts

    def overload(self, volts: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Samples (n, 12 volts) at the clipping count of any gauge."""
        fs = (2**23 - 1) * self.full_scale_v / 2**23
        out: NDArray[np.bool_] = np.any(np.abs(volts) >= fs * (1 - 1e-9), axis=1)
        return out


def frames_per_second(layout: PdoLayout, rate_hz: float) -> float:
    """TPDO frames per second the amplifier sends at ``rate_hz``."""
    return len(layout.tpdos) * rate_hz


def bus_load(layout: PdoLayout, rate_hz: float, bitrate: int) -> float:
    """Fraction of a classic CAN bus at ``bitrate`` the sample stream takes: each frame
    ``47 + 8 L`` bits plus worst-case stuffing ``⌊(34 + 8 L − 1) / 4⌋`` (L data bytes, 11-bit
    identifier), summed over the TPDOs per sample, times the rate."""
    bits = sum(47 + 8 * t.length + (34 + 8 * t.length - 1) // 4 for t in layout.tpdos)
    return bits * rate_hz / bitrate
