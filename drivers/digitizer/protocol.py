"""Wire protocol of the dimacq sonic digitizer (SD-3): the documented codec, no I/O.

No protocol of the original instruments is public, so this one is modelled on serial measuring
instruments (NMEA-style framed replies, SCPI-style identify). Both the driver
(:mod:`dimacq.drivers.digitizer.driver`) and the simulator (:mod:`dimacq.simulators.digitizer`)
use this module and nothing else of each other.

Link
----
RS-232 or USB-CDC, 115200 baud, 8 data bits, no parity, 1 stop bit, no handshake.

Host → device
-------------
One ASCII command per line, terminated by CR (``\\r``); a following LF is ignored, so a serial
terminal works. Commands are case-insensitive, at most 80 characters.

=====================================  =========================================================
command                                reply
=====================================  =========================================================
``*IDN?``                              ``$IDN,<vendor>,<model>,<serial>,<firmware>,<n_mics>``
``RST``                                ``$OK,RST``: defaults, sequence number 0, stream stopped
``CFG?``                               ``$CFG,<E>,<M>,<A>,<B>,<clock_hz>,<delay_counts>``
``CFG E=<e>,M=<m>,A=<a>,B=<b>``        ``$CFG,...`` (the new settings; any subset of the keys)
``SHOT``                               one shot record ``$SHT,...``
``STRM <n>``                           ``n`` shot records (1 ≤ n ≤ 100000), then ``$OK,STRM,<n>``
``STOP``                               ``$OK,STOP``: ends a stream early (records sent stay valid)
=====================================  =========================================================

``E`` emitters fired per shot (1–2), ``M`` microphones used (the first M, 3 ≤ M ≤ installed),
``A`` averaging (1–16 firings per emitter summed into one counter value), ``B`` calibration bar
firings per shot (1–8), ``clock_hz`` the counter clock, ``delay_counts`` the fixed electronic delay
``tau_0`` in counter periods (both read only, from the factory calibration).

Simulator-only commands start with ``SIM:`` (a real unit answers ``$ERR,1``); see
:mod:`dimacq.simulators.digitizer.device`.

Device → host
-------------
Every reply line is framed::

    $<TAG>,<field>,<field>,...*HH\\r\\n

``HH`` is the XOR of all bytes between ``$`` and ``*`` as two upper-case hex digits (the NMEA 0183
checksum). ``$`` never occurs inside a line, so a reader resynchronises after garbage by
discarding bytes up to the next ``$``; a line in which a second ``$`` appears before its end was
truncated (the device restarted the record) and is dropped.

Errors: ``$ERR,<code>,<text>`` with code 1 unknown command, 2 bad argument, 3 busy (streaming),
4 hardware fault.

Shot record
-----------
::

    $SHT,<seq>,<status>,<E>,<M>,<A>,<B>,<n_11>,...,<n_1M>,...,<n_E1>,...,<n_EM>,<b_1>,...,<b_B>*HH

``seq`` decimal 0–65535 (wraps; increments with each shot since reset, so a gap reveals a lost
record), ``status`` four hex digits (:class:`Status`), then the ``E × M`` counter values emitter by
emitter and the ``B`` bar counter values, all decimal. Each counter value ``n`` counts whole clock
periods from firing to arrival, including ``tau_0``, summed over ``A`` firings; a value of
``2**24 - 1`` (summed: ``A * (2**24 - 1)``) means no arrival and sets the overflow flag. The
time of flight is ``t = (n / A + 0.5) / clock_hz - tau_0`` (middle of the counter period).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dimacq.devices.digitizer import DeviceIdentity, DigitizerSettings, ShotRecord
from dimacq.errors import ProtocolError

__all__ = [
    "BAUDRATE",
    "COUNTER_MAX",
    "EOL",
    "START",
    "Command",
    "ErrorCode",
    "Status",
    "checksum",
    "decode_identity",
    "decode_settings",
    "decode_shot",
    "encode_command",
    "encode_identity",
    "encode_settings",
    "encode_shot",
    "frame",
    "parse_command",
    "unframe",
]

BAUDRATE = 115200
START = b"$"
EOL = b"\r\n"
CMD_END = b"\r"
MAX_COMMAND = 80
MAX_LINE = 4096
COUNTER_BITS = 24
COUNTER_MAX = 2**COUNTER_BITS - 1
N_SHOT_HEADER = 6  # seq, status, E, M, A, B


class Status(enum.IntFlag):
    """Status flags of a shot record."""

    OVERFLOW_E1 = 0x0001  #: emitter 1 had no arrival on at least one microphone
    OVERFLOW_E2 = 0x0002  #: emitter 2 had no arrival on at least one microphone
    BAR_OVERFLOW = 0x0010  #: a calibration bar firing had no arrival
    BUTTON = 0x0100  #: the shot was triggered by the probe button, not by a command
    FAULT = 0x8000  #: hardware fault (emitter or counter self-check failed)


class ErrorCode(enum.IntEnum):
    """Codes of ``$ERR`` replies."""

    UNKNOWN_COMMAND = 1
    BAD_ARGUMENT = 2
    BUSY = 3
    HARDWARE = 4


def checksum(body: bytes) -> int:
    """XOR of all bytes of ``body`` (the text between ``$`` and ``*``)."""
    value = 0
    for byte in body:
        value ^= byte
    return value


def frame(tag: str, *fields: object) -> bytes:
    """Frame a reply line: ``$TAG,f1,f2*HH\\r\\n``."""
    body = ",".join([tag, *(str(f) for f in fields)]).encode("ascii")
    if b"$" in body or b"*" in body:
        raise ProtocolError(f"reply field contains '$' or '*': {body!r}; remove them")
    return START + body + b"*" + f"{checksum(body):02X}".encode("ascii") + EOL


def unframe(line: bytes) -> list[str]:
    """Check one framed line (with or without its CR LF) and return ``[TAG, field, ...]``.

    Raises
    ------
    ProtocolError
        The line does not start with ``$``, has no ``*HH`` checksum field, or the checksum does not
        match; the message names the field.
    """
    text = line.rstrip(b"\r\n")
    if not text.startswith(START):
        raise ProtocolError(f"reply line {text[:40]!r}: field 'start' is not '$'")
    star = text.rfind(b"*")
    if star < 0 or len(text) - star != 3:
        raise ProtocolError(
            f"reply line {text[:60]!r}: field 'checksum' missing or not two hex digits "
            "(truncated line?)"
        )
    body = text[1:star]
    try:
        got = int(text[star + 1 :], 16)
    except ValueError as err:
        raise ProtocolError(
            f"reply line {text[:60]!r}: field 'checksum' {text[star + 1 :]!r} is not hex"
        ) from err
    want = checksum(body)
    if got != want:
        raise ProtocolError(
            f"reply line {text[:60]!r}: field 'checksum' is {got:02X}, computed {want:02X}; "
            "bytes were corrupted on the link (check cable, baud rate 115200 8N1)"
        )
    try:
        return body.decode("ascii").split(",")
    except UnicodeDecodeError as err:
        raise ProtocolError(f"reply line {text[:60]!r}: non-ASCII bytes in 'body'") from err


def _int(fields: Sequence[str], index: int, name: str, base: int = 10) -> int:
    try:
        return int(fields[index], base)
    except IndexError as err:
        raise ProtocolError(
            f"{fields[0]} record: field '{name}' missing ({len(fields) - 1} fields; truncated)"
        ) from err
    except ValueError as err:
        raise ProtocolError(
            f"{fields[0]} record: field '{name}' = {fields[index]!r} is not an integer"
        ) from err


# ---------------------------------------------------------------------------- shot record


def encode_shot(record: ShotRecord) -> bytes:
    """Frame a shot record."""
    e, m = record.counts.shape
    return frame(
        "SHT",
        record.seq,
        f"{record.status:04X}",
        e,
        m,
        record.averaging,
        len(record.bar_counts),
        *(int(v) for v in record.counts.ravel()),
        *(int(v) for v in record.bar_counts),
    )


def decode_shot(fields: Sequence[str]) -> ShotRecord:
    """Decode the fields of an unframed ``SHT`` line into a :class:`ShotRecord`."""
    if not fields or fields[0] != "SHT":
        raise ProtocolError(f"expected a shot record 'SHT', got field 'tag' = {fields[:1]!r}")
    seq = _int(fields, 1, "seq")
    status = _int(fields, 2, "status", 16)
    e = _int(fields, 3, "E")
    m = _int(fields, 4, "M")
    a = _int(fields, 5, "A")
    b = _int(fields, 6, "B")
    if not (1 <= e <= 2 and 3 <= m <= 64 and 1 <= a <= 16 and 1 <= b <= 8):
        raise ProtocolError(
            f"SHT record: header fields E={e}, M={m}, A={a}, B={b} out of range "
            "(E 1-2, M 3-64, A 1-16, B 1-8)"
        )
    n_expected = 1 + N_SHOT_HEADER + e * m + b
    if len(fields) != n_expected:
        raise ProtocolError(
            f"SHT record seq {seq}: field 'counts' has {len(fields) - 1 - N_SHOT_HEADER} values, "
            f"expected E*M+B = {e * m + b} (truncated or malformed record)"
        )
    values = np.empty(e * m + b, dtype=np.int64)
    for i in range(e * m + b):
        idx = 1 + N_SHOT_HEADER + i
        name = f"counts[{i // m},{i % m}]" if i < e * m else f"bar[{i - e * m}]"
        v = _int(fields, idx, name)
        if v < 0 or v > a * COUNTER_MAX:
            raise ProtocolError(
                f"SHT record seq {seq}: field '{name}' = {v} outside 0..{a * COUNTER_MAX}"
            )
        values[i] = v
    return ShotRecord(
        seq=seq,
        status=status,
        averaging=a,
        counts=values[: e * m].reshape(e, m),
        bar_counts=values[e * m :].copy(),
    )


# ---------------------------------------------------------------------------- identity, settings


def encode_identity(identity: DeviceIdentity) -> bytes:
    return frame(
        "IDN",
        identity.vendor,
        identity.model,
        identity.serial,
        identity.firmware,
        identity.n_microphones,
    )


def decode_identity(fields: Sequence[str]) -> DeviceIdentity:
    if not fields or fields[0] != "IDN" or len(fields) != 6:
        raise ProtocolError(f"expected 'IDN' with 5 fields, got {list(fields)!r}")
    return DeviceIdentity(
        vendor=fields[1],
        model=fields[2],
        serial=fields[3],
        firmware=fields[4],
        n_microphones=_int(fields, 5, "n_mics"),
    )


def encode_settings(s: DigitizerSettings) -> bytes:
    return frame(
        "CFG",
        s.emitters,
        s.microphones,
        s.averaging,
        s.bar_repeats,
        f"{s.clock_hz:.0f}",
        s.delay_counts,
    )


def decode_settings(fields: Sequence[str]) -> DigitizerSettings:
    if not fields or fields[0] != "CFG" or len(fields) != 7:
        raise ProtocolError(f"expected 'CFG' with 6 fields, got {list(fields)!r}")
    return DigitizerSettings(
        emitters=_int(fields, 1, "E"),
        microphones=_int(fields, 2, "M"),
        averaging=_int(fields, 3, "A"),
        bar_repeats=_int(fields, 4, "B"),
        clock_hz=float(_int(fields, 5, "clock_hz")),
        delay_counts=_int(fields, 6, "delay_counts"),
    )


# ---------------------------------------------------------------------------- commands


@dataclass(frozen=True)
class Command:
    """A parsed host command: upper-case ``name`` (``"CFG?"``, ``"STRM"``) and raw ``args``."""

    name: str
    args: str = ""


def encode_command(name: str, args: str = "") -> bytes:
    """``name [args]`` + CR, checked against the 80-character limit."""
    text = f"{name} {args}".strip() if args else name
    raw = text.encode("ascii") + CMD_END
    if len(raw) > MAX_COMMAND + 1 or b"\r" in raw[:-1] or b"\n" in raw:
        raise ProtocolError(f"command {text!r}: longer than {MAX_COMMAND} characters or has CR/LF")
    return raw


def parse_command(line: bytes) -> Command:
    """Parse one command line (terminator stripped or not) into a :class:`Command`."""
    text = line.strip(b"\r\n \t")
    try:
        decoded = text.decode("ascii")
    except UnicodeDecodeError as err:
        raise ProtocolError(f"command {text[:40]!r}: non-ASCII bytes") from err
    name, _, args = decoded.partition(" ")
    return Command(name=name.upper(), args=args.strip())


def parse_cfg_args(args: str) -> dict[str, int]:
    """Parse ``E=2,M=4,A=1,B=4`` (any subset, any order) into ``{"E": 2, ...}``."""
    out: dict[str, int] = {}
    for item in filter(None, (p.strip() for p in args.split(","))):
        key, sep, value = item.partition("=")
        key = key.strip().upper()
        if not sep or key not in {"E", "M", "A", "B"}:
            raise ProtocolError(f"CFG argument {item!r}: expected KEY=VALUE with KEY in E, M, A, B")
        try:
            out[key] = int(value)
        except ValueError as err:
            raise ProtocolError(f"CFG argument {item!r}: value is not an integer") from err
    return out
