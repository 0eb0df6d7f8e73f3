"""Raw acquisition data streamed to HDF5 as it arrives (a crash loses at most the last second).

Layout (``schema_version`` 1)::

    /                       attrs: schema_version, sample_rate_hz, created
    /daq/data               float64 (n_channels, n) resizable along samples, chunked
    /daq/valid              bool (n,)      False where samples were lost
    /daq/overload           bool (n_channels, n)
    /daq                    attrs: channel_names, units, first_sample
    /loadcell<k>/gauges_v   float64 (n_gauges, n) (12 usually);   /loadcell<k>/valid  bool (n,)
    /events                 variable-length UTF-8 strings, one JSON object per event
    /averages               variable-length UTF-8 strings, one JSON object per average
                            (input, first_sample, n_samples, accepted, reasons)

Every append is followed by ``flush()`` when more than ``flush_interval_s`` passed since the
last one (default 1 s) and at close, so the file on disk is never more than that behind.
"""

from __future__ import annotations

import datetime as _dt
import json
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

__all__ = ["AcquisitionWriter"]

SCHEMA_VERSION = 1


class AcquisitionWriter:
    """Append-only HDF5 writer; use as a context manager."""

    def __init__(
        self,
        path: str | Path,
        *,
        sample_rate_hz: float,
        daq_channels: tuple[str, ...],
        daq_units: tuple[str, ...],
        n_loadcells: int = 0,
        flush_interval_s: float = 1.0,
    ) -> None:
        self.path = Path(path)
        self.flush_interval_s = flush_interval_s
        self._f = h5py.File(self.path, "w")
        self._f.attrs["schema_version"] = SCHEMA_VERSION
        self._f.attrs["sample_rate_hz"] = sample_rate_hz
        self._f.attrs["created"] = _dt.datetime.now(_dt.UTC).isoformat()
        n_ch = len(daq_channels)
        g = self._f.create_group("daq")
        g.attrs["channel_names"] = list(daq_channels)
        g.attrs["units"] = list(daq_units)
        chunk = 4096
        g.create_dataset("data", (n_ch, 0), maxshape=(n_ch, None), dtype="f8", chunks=(n_ch, chunk))
        g.create_dataset("valid", (0,), maxshape=(None,), dtype=bool, chunks=(chunk,))
        g.create_dataset(
            "overload", (n_ch, 0), maxshape=(n_ch, None), dtype=bool, chunks=(n_ch, chunk)
        )
        for k in range(n_loadcells):
            lc = self._f.create_group(f"loadcell{k}")
            lc.create_dataset(
                "gauges_v", (12, 0), maxshape=(12, None), dtype="f8", chunks=(12, chunk)
            )
            lc.create_dataset("valid", (0,), maxshape=(None,), dtype=bool, chunks=(chunk,))
        s = h5py.string_dtype()
        self._f.create_dataset("events", (0,), maxshape=(None,), dtype=s, chunks=(64,))
        self._f.create_dataset("averages", (0,), maxshape=(None,), dtype=s, chunks=(64,))
        self._last_flush = time.monotonic()
        self._first: int | None = None

    @staticmethod
    def _append(ds: h5py.Dataset, arr: NDArray[Any]) -> None:
        n = arr.shape[-1]
        old = ds.shape[-1]
        if ds.ndim == 2:
            ds.resize((ds.shape[0], old + n))
            ds[:, old:] = arr
        else:
            ds.resize((old + n,))
            ds[old:] = arr

    def append_daq(
        self,
        first_sample: int,
        data: NDArray[np.float64],
        valid: NDArray[np.bool_],
        overload: NDArray[np.bool_],
    ) -> None:
        g = self._f["daq"]
        if self._first is None:
            self._first = first_sample
            g.attrs["first_sample"] = first_sample
        self._append(g["data"], np.asarray(data))
        self._append(g["valid"], np.asarray(valid))
        self._append(g["overload"], np.asarray(overload))
        self._maybe_flush()

    def append_loadcell(
        self, k: int, gauges_v: NDArray[np.float64], valid: NDArray[np.bool_]
    ) -> None:
        g = self._f[f"loadcell{k}"]
        gauges = np.asarray(gauges_v)
        ds = g["gauges_v"]
        if ds.shape[0] != gauges.shape[0] and ds.shape[1] == 0:
            # a cell with another number of gauges (or six conditioned outputs): its rows
            del g["gauges_v"]
            n = gauges.shape[0]
            g.create_dataset("gauges_v", (n, 0), maxshape=(n, None), dtype="f8", chunks=(n, 4096))
        self._append(g["gauges_v"], gauges)
        self._append(g["valid"], np.asarray(valid))
        self._maybe_flush()

    def log_event(self, event: dict[str, Any]) -> None:
        self._append(self._f["events"], np.array([json.dumps(event)], dtype=object))
        self._maybe_flush()

    def log_average(self, record: dict[str, Any]) -> None:
        self._append(self._f["averages"], np.array([json.dumps(record)], dtype=object))
        self._maybe_flush()

    def _maybe_flush(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.flush()

    def flush(self) -> None:
        self._f.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        if self._f.id.valid:
            self._f.flush()
            self._f.close()

    def __enter__(self) -> AcquisitionWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
