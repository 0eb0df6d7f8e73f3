"""FRF values as float32 little-endian arrays behind a small JSON header (what a page draws).

The layout, all little-endian::

    bytes 0..3      b"DFRF"
    bytes 4..7      uint32 L: length of the header
    bytes 8..8+L    UTF-8 JSON header, padded with spaces so the arrays start at a multiple of 4
    then            the arrays the header's ``arrays`` lists, in its order, each ``<f4`` C-order
                    of its ``shape`` at its ``offset`` (bytes from the start of the message)

The header carries everything else (``frequencies_hz`` in full precision, the channels, the
``layout``). A value JSON cannot carry (a coherence of one average: NaN) stays NaN here. Against
JSON (about 20 bytes a value, parsed into nested arrays) a value is 4 bytes read as a typed array:
an X-38-size set (2048 lines × 63 × 22, three arrays) is 34 MB instead of ~170 MB of text.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["MAGIC", "MEDIA_TYPE", "decode_f32", "encode_f32"]

MAGIC = b"DFRF"
MEDIA_TYPE = "application/vnd.dimacq.frf-f32"


def encode_f32(header: Mapping[str, Any], arrays: Mapping[str, ArrayLike]) -> bytes:
    """``header`` (JSON-able) with an ``arrays`` entry added, then ``arrays`` as ``<f4``
    (each converted once, straight into the message's buffer)."""
    parts = {k: np.asarray(v) for k, v in arrays.items()}
    meta: list[dict[str, Any]] = []
    offset = 0
    for name, a in parts.items():
        meta.append({"name": name, "shape": list(a.shape), "offset": offset})
        offset += 4 * a.size
    head = dict(header)
    head["dtype"] = "<f4"
    head["arrays"] = meta
    # two passes: the offsets count from the start of the message, after the header
    text = json.dumps(head, separators=(",", ":"), allow_nan=False).encode()
    start = 8 + len(text) + 64
    start += -start % 4
    for m in meta:
        m["offset"] += start
    text = json.dumps(head, separators=(",", ":"), allow_nan=False).encode()
    if 8 + len(text) > start:  # pragma: no cover - the 64 spare bytes hold the offsets' digits
        raise AssertionError("FRF header outgrew its room")
    out = bytearray(start + offset)
    out[:4] = MAGIC
    out[4:8] = struct.pack("<I", start - 8)
    out[8:start] = text + b" " * (start - 8 - len(text))
    for m, a in zip(meta, parts.values(), strict=True):
        view = np.frombuffer(out, dtype="<f4", count=a.size, offset=m["offset"])
        view.reshape(a.shape)[...] = a
    return bytes(out)


def decode_f32(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The header and arrays of :func:`encode_f32`'s message."""
    if data[:4] != MAGIC:
        raise ValueError(f"not an FRF float32 message: starts {data[:4]!r}, not {MAGIC!r}")
    (n,) = struct.unpack_from("<I", data, 4)
    head = json.loads(data[8 : 8 + n])
    arrays = {
        m["name"]: np.frombuffer(
            data, dtype="<f4", count=int(np.prod(m["shape"])), offset=m["offset"]
        ).reshape(m["shape"])
        for m in head["arrays"]
    }
    return head, arrays
