"""The wire vocabulary of a generic CiA 404 measuring amplifier on CANopen (CiA 301).

Shared by the driver (:mod:`dimacq.drivers.cia404.driver`), the simulator
(:mod:`dimacq.simulators.cia404`) and the tests; the object dictionary itself is the device's EDS
(CiA 306, e.g. ``config/canopen/cia404-generic.eds``), read by ``canopen`` on both sides.

CiA 301 frames (11-bit identifiers; ``n`` the node id)::

    NMT          0x000       [command, node]  01 start, 02 stop, 80 pre-operational, 81/82 reset
    SYNC         0x080       []  (or [counter] when 0x1019 > 0)
    EMCY         0x080 + n   [error code U16, error register U8, 5 manufacturer bytes]
    TPDO1..4     0x180 / 0x280 / 0x380 / 0x480 + n  (predefined connection set)
    SDO request  0x600 + n   expedited download: [0x23 | (4 − size) << 2, index U16, sub, data]
    SDO answer   0x580 + n   download confirmed: [0x60, index U16, sub, 0, 0, 0, 0]
    heartbeat    0x700 + n   [state]  00 boot-up, 04 stopped, 05 operational, 7F pre-operational

CiA 301 objects used: 0x1000 device type (CiA 404 in its low word, 404 = 0x194), 0x1017 producer heartbeat time, 0x1018 identity (vendor, product, revision, serial),
0x1800 + k TPDO communication (sub 1 COB-ID, bit 31 = PDO not valid; sub 2 transmission type,
1 = synchronous, every SYNC), 0x1A00 + k TPDO mapping (sub 0 count, subs 1..8 entries
``index << 16 | sub << 8 | bits``: analogue input 1 as REAL32 is ``0x61300120``).

CiA 404 objects (analogue inputs, one sub-index per channel): 0x6130 AI input process value
REAL32, 0x7130 AI input process value INTEGER16 (value = integer / 10^decimal digits, 0x6132);
0x6110 AI sensor type (U16), 0x6114 AI ADC sample rate (U32; its unit is the device's: the
generic EDS declares Hz), 0x6126 AI scaling factor and 0x6127 AI scaling offset (REAL32:
process value = factor × input + offset), 0x6131 AI physical unit of the process value (U32,
CiA 303-2 coding: prefix exponent in byte 3, SI unit in byte 2, :data:`UNIT_CODES`), 0x61A0 AI
filter type (U8; 1 read here as a moving average) and 0x61A1 AI filter constant (U8: samples
averaged). The indices are as CiA 404 lists them; the codes of 0x6110 and 0x61A0 and the unit
of 0x6114 vary by device and are taken from the EDS, not interpreted.

**Mapping procedure** (CiA 301 §7.5.2.35, by SDO while the node is PRE-OPERATIONAL), per TPDO:
disable it (COB-ID with bit 31 set), set its mapping count to 0, write the entries, write the
count, set the transmission type, enable it (COB-ID with bit 31 clear). :func:`mapping_writes`
lists those SDO downloads in that order.

**Bus load.** A classic data frame with an 11-bit identifier and ``L`` data bytes is
``47 + 8 L`` bits, of which the ``34 + 8 L`` from the start of frame to the CRC are
bit-stuffed: at worst one stuff bit per 4 after the first, ``⌊(34 + 8 L − 1) / 4⌋`` (Davis et
al., *Controller Area Network schedulability analysis*, 2007). One sample of a node costs its
TPDO frames, plus one SYNC (``L = 0``) per sample on the bus::

    load = rate × (bits(SYNC) + Σ_nodes Σ_TPDOs bits(L)) / bitrate
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
    "AI_ADC_SAMPLE_RATE",
    "AI_DECIMAL_DIGITS",
    "AI_FILTER_CONSTANT",
    "AI_FILTER_TYPE",
    "AI_PHYSICAL_UNIT",
    "AI_SCALING_FACTOR",
    "AI_SCALING_OFFSET",
    "AI_SENSOR_TYPE",
    "COB_ID_INVALID",
    "DEVICE_TYPE",
    "FILTER_MOVING_AVERAGE",
    "HEARTBEAT_TIME",
    "IDENTITY",
    "INT16_PV",
    "NMT_STATES",
    "REAL32_PV",
    "SYNC_COB_ID",
    "TPDO_COMM",
    "TPDO_MAP",
    "TRANSMISSION_SYNCHRONOUS",
    "UNIT_CODES",
    "NmtCommand",
    "ProcessValue",
    "TpdoPlan",
    "bus_load",
    "decode_tpdo",
    "emcy_cob_id",
    "encode_tpdo",
    "frame_bits",
    "mapping_entry",
    "mapping_writes",
    "nmt_frame",
    "plan_tpdos",
    "process_value",
    "sdo_download_answer",
    "sdo_expedited_download",
    "sync_frame",
    "tpdo_cob_id",
]

SYNC_COB_ID = 0x080
DEVICE_TYPE = 0x1000
HEARTBEAT_TIME = 0x1017
IDENTITY = 0x1018
TPDO_COMM = 0x1800
TPDO_MAP = 0x1A00
AI_DECIMAL_DIGITS = 0x6132
AI_SENSOR_TYPE = 0x6110
AI_ADC_SAMPLE_RATE = 0x6114
AI_SCALING_FACTOR = 0x6126
AI_SCALING_OFFSET = 0x6127
AI_PHYSICAL_UNIT = 0x6131
AI_FILTER_TYPE = 0x61A0
AI_FILTER_CONSTANT = 0x61A1
#: 0x61A0 filter type read as a moving average of 0x61A1 samples (0: no filter)
FILTER_MOVING_AVERAGE = 1
#: CiA 303-2 physical unit codes of the process values a bridge amplifier gives, by the
#: calibration file's ``gauge_unit``: volt (SI code 0x26), millivolt (prefix −3), and mV/V as a
#: dimensionless ratio with prefix −3 (our reading of CiA 303-2 for a ratio)
UNIT_CODES: dict[str, int] = {"V": 0x00260000, "mV": 0xFD260000, "mV/V": 0xFD000000}
#: COB-ID bit 31: the PDO does not exist / is not valid
COB_ID_INVALID = 1 << 31
#: transmission type 1: synchronous, sent after every SYNC (sampled at the SYNC)
TRANSMISSION_SYNCHRONOUS = 1
#: most entries one mapping parameter holds (CiA 301: 0x40; generic EDS files give 8)
_MAX_ENTRIES = 8


class NmtCommand(IntEnum):
    START = 0x01
    STOP = 0x02
    PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


#: heartbeat / boot-up byte → NMT state
NMT_STATES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}


def nmt_frame(command: NmtCommand, node_id: int) -> tuple[int, bytes]:
    """``(0x000, [command, node])``; node 0 addresses every node."""
    return 0x000, bytes([int(command), node_id & 0x7F])


def sync_frame(counter: int | None = None) -> tuple[int, bytes]:
    """``(0x080, [])``, or with the SYNC counter byte (1..240)."""
    return SYNC_COB_ID, b"" if counter is None else bytes([counter])


def emcy_cob_id(node_id: int) -> int:
    return 0x080 + node_id


def sdo_expedited_download(
    node_id: int, index: int, subindex: int, data: bytes
) -> tuple[int, bytes]:
    """The SDO request frame writing 1..4 bytes: ``(0x600 + n, [0x23 | (4 − size) << 2 ...])``
    (command: ccs 1, expedited, size indicated; data little endian, unused bytes 0)."""
    if not 1 <= len(data) <= 4:
        raise ValueError(f"expedited download of {len(data)} bytes: give 1..4")
    cmd = 0x23 | ((4 - len(data)) << 2)
    return 0x600 + node_id, bytes([cmd]) + struct.pack("<HB", index, subindex) + data.ljust(
        4, b"\0"
    )


def sdo_download_answer(node_id: int, index: int, subindex: int) -> tuple[int, bytes]:
    """The server's confirmation of a download: ``(0x580 + n, [0x60, index, sub, 0 × 4])``."""
    return 0x580 + node_id, bytes([0x60]) + struct.pack("<HB", index, subindex) + bytes(4)


def mapping_entry(index: int, subindex: int, bits: int) -> int:
    """``index << 16 | subindex << 8 | bits`` (0x6130 sub 1 as 32 bits: ``0x61300120``)."""
    return (index << 16) | (subindex << 8) | bits


def tpdo_cob_id(node_id: int, k: int) -> int:
    """COB-ID of TPDO ``k`` (0-based): the predefined connection set's ``0x180 + 0x100 k + n``
    for TPDO1..4; TPDO5..8 take ``0x1C0 + 0x100 (k − 4) + n`` (node ids 1..63, so that they
    do not collide with another node's TPDO1..4)."""
    if k < 4:
        return 0x180 + 0x100 * k + node_id
    if k < 8 and node_id <= 63:
        return 0x1C0 + 0x100 * (k - 4) + node_id
    raise SetupError(
        f"CANopen node {node_id}: TPDO{k + 1} needs a node id of 1..63 (its COB-ID "
        "0x1C0 + 0x100·(k−4) + node would take another node's); renumber the node or map fewer "
        "channels"
    )


@dataclass(frozen=True)
class ProcessValue:
    """One CiA 404 process value object: its index, bits per channel and wire dtype."""

    index: int
    bits: int
    dtype: str
    name: str

    @property
    def size(self) -> int:
        return self.bits // 8


REAL32_PV = ProcessValue(0x6130, 32, "<f4", "AI input process value REAL32")
INT16_PV = ProcessValue(0x7130, 16, "<i2", "AI input process value INTEGER16")
_PVS = {0x6130: REAL32_PV, 0x7130: INT16_PV}


def process_value(od: object, prefer: str = "auto", *, where: str) -> ProcessValue:
    """The process value object to map, as the EDS ``od`` has it: ``prefer`` ``"auto"`` (0x6130
    when the EDS has it PDO-mappable, else 0x7130), ``"0x6130"`` or ``"0x7130"``.

    Raises
    ------
    SetupError
        The EDS has neither (or not the one asked for), or not PDO-mappable.
    """
    order = [0x6130, 0x7130] if prefer == "auto" else [int(prefer, 16)]
    for index in order:
        if index not in _PVS:
            break
        if index in od:  # type: ignore[operator]
            sub1 = od[index][1]  # type: ignore[index]
            if getattr(sub1, "pdo_mappable", False):
                return _PVS[index]
    raise SetupError(
        f"{where}: the EDS has no PDO-mappable "
        f"{' or '.join(f'0x{i:04X}' for i in order)} (CiA 404 AI input process value); give "
        "the amplifier's own EDS (loadcell_cia404_eds) or set loadcell_cia404_process_value "
        "to 'auto', '0x6130' or '0x7130'"
    )


@dataclass(frozen=True)
class TpdoPlan:
    """TPDO ``number`` (1-based) at ``cob_id`` carrying ``channels`` (0-based) of ``pv``."""

    number: int
    cob_id: int
    pv: ProcessValue
    channels: tuple[int, ...]

    @property
    def length(self) -> int:
        return len(self.channels) * self.pv.size

    @property
    def entries(self) -> tuple[int, ...]:
        return tuple(mapping_entry(self.pv.index, c + 1, self.pv.bits) for c in self.channels)


def plan_tpdos(
    n_channels: int, pv: ProcessValue, node_id: int, n_tpdos: int, *, where: str
) -> tuple[TpdoPlan, ...]:
    """Channels 1..n packed in channel order, ``8 // size`` per TPDO (REAL32: 2, INTEGER16: 4).

    Raises
    ------
    SetupError
        More TPDOs needed than the EDS has.
    """
    per = 8 // pv.size
    need = -(-n_channels // per)
    if need > n_tpdos:
        raise SetupError(
            f"{where}: {n_channels} channels of 0x{pv.index:04X} need {need} TPDOs, the EDS has "
            f"{n_tpdos}; map 0x7130 (INTEGER16, 4 per TPDO) or fewer channels"
        )
    chans = list(range(n_channels))
    return tuple(
        TpdoPlan(k + 1, tpdo_cob_id(node_id, k), pv, tuple(chans[k * per : (k + 1) * per]))
        for k in range(need)
    )


def mapping_writes(
    plans: Sequence[TpdoPlan], n_tpdos: int, node_id: int
) -> list[tuple[int, int, bytes]]:
    """The SDO downloads ``(index, sub, data)`` of the CiA 301 mapping procedure, in order: for
    each planned TPDO disable, clear the count, entries, count, transmission type 1, enable; each
    other TPDO of the EDS disabled (no frame of it on the bus)."""
    u32 = struct.Struct("<I").pack

    def u8(v: int) -> bytes:
        return bytes([v])

    out: list[tuple[int, int, bytes]] = []
    for k in range(n_tpdos):
        comm, mapping = TPDO_COMM + k, TPDO_MAP + k
        plan = next((p for p in plans if p.number == k + 1), None)
        if plan is None:
            cob = tpdo_cob_id(node_id, k) if k < 4 or (k < 8 and node_id <= 63) else 0
            out.append((comm, 1, u32(COB_ID_INVALID | cob)))
            continue
        if len(plan.entries) > _MAX_ENTRIES:
            raise SetupError(f"TPDO{k + 1}: {len(plan.entries)} entries; at most 8")
        out.append((comm, 1, u32(COB_ID_INVALID | plan.cob_id)))
        out.append((mapping, 0, u8(0)))
        out.extend((mapping, s + 1, u32(e)) for s, e in enumerate(plan.entries))
        out.append((mapping, 0, u8(len(plan.entries))))
        out.append((comm, 2, u8(TRANSMISSION_SYNCHRONOUS)))
        out.append((comm, 1, u32(plan.cob_id)))
    return out


def frame_bits(n_bytes: int) -> int:
    """Bits of a classic data frame (11-bit id) with ``n_bytes`` data, worst-case stuffing."""
    return 47 + 8 * n_bytes + (34 + 8 * n_bytes - 1) // 4


def bus_load(frame_bytes_per_sample: Sequence[int], rate_hz: float, bitrate: int) -> float:
    """Fraction of the bus: one SYNC plus the given frames per sample, at ``rate_hz``."""
    bits = frame_bits(0) + sum(frame_bits(n) for n in frame_bytes_per_sample)
    return bits * rate_hz / bitrate


def decode_tpdo(
    plan: TpdoPlan, payloads: Sequence[bytes], scale: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Payloads of one TPDO → values, shape (n, len(plan.channels)); INTEGER16 values times
    ``scale`` (per channel of the plan: 10^−decimal digits).

    Raises
    ------
    ProtocolError
        A payload shorter than the mapping.
    """
    n, L = len(payloads), plan.length
    if any(len(d) < L for d in payloads):
        bad = next(d for d in payloads if len(d) < L)
        raise ProtocolError(
            f"TPDO{plan.number} (COB-ID 0x{plan.cob_id:03X}): frame of {len(bad)} bytes, its "
            f"mapping needs {L}"
        )
    raw = b"".join(bytes(d[:L]) for d in payloads)
    vals = np.frombuffer(raw, dtype=plan.pv.dtype).reshape(n, len(plan.channels))
    out = vals.astype(np.float64)
    if scale is not None:
        out *= scale
    return out


def encode_tpdo(plan: TpdoPlan, values: NDArray[np.float64]) -> list[bytes]:
    """Values (n, len(plan.channels)) in process-value units → payloads (the node's side; the
    INTEGER16 ones already scaled to integers)."""
    if plan.pv is INT16_PV:
        arr = np.clip(np.rint(values), -32768, 32767).astype(plan.pv.dtype)
    else:
        arr = np.ascontiguousarray(values, dtype=plan.pv.dtype)
    raw = arr.tobytes()
    L = plan.length
    return [raw[i * L : (i + 1) * L] for i in range(arr.shape[0])]
