"""The sample stream of an impact session: DAQ and load cell blocks read, written to disk and
aligned by the sample counter in sliding windows; the trigger search; the gaps' kinds
(:class:`ImpactStream`, a part of :class:`~dimacq.services.acquisition.session.ImpactSession`)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.daq import Daq, DaqBlock
from dimacq.devices.loadcell import LoadCell, LoadCellBlock
from dimacq.errors import DeviceTimeoutError
from dimacq.io.acquisition_hdf5 import AcquisitionWriter
from dimacq.model.impact import ImpactSettings
from dimacq.services.acquisition.sample_window import SampleWindow

log = logging.getLogger("dimacq.services.acquisition.session")


class StrikeLost(Exception):
    """Samples were lost while waiting for a strike: it may have been among them."""


class ImpactStream:
    """Methods of :class:`~dimacq.services.acquisition.session.ImpactSession` (its state: see there)."""

    if TYPE_CHECKING:  # the state of the ImpactSession it is a part of
        daq: Daq
        loadcells: list[LoadCell]
        loadcell_outputs: Literal["forces", "gauges"]
        settings: ImpactSettings
        writer: AcquisitionWriter | None
        on_event: Callable[[dict[str, object]], None] | None
        input_rows: list[int]
        input_names: tuple[str, ...]
        _daq_buf: SampleWindow
        _lc_bufs: list[SampleWindow]
        _lc_zero: list[NDArray[np.float64] | None]
        _gaps: list[tuple[int, int, str]]
        _zero_samples: int

    def _read_block(self) -> None:
        n = self.settings.block_samples
        for attempt in range(3):
            try:
                block = self.daq.read(n)
                break
            except DeviceTimeoutError as err:
                self._event({"kind": "daq_timeout", "message": str(err)})
                if attempt == 2:
                    self._event(
                        {"device": "daq", "kind": "lost", "message": f"3 reads timed out: {err}"}
                    )
                    raise
        self._ingest_daq(block)
        for k, lc in enumerate(self.loadcells):
            self._ingest_lc(k, lc.read_until(block.first_sample + block.n_samples))

    def _ingest_daq(self, block: DaqBlock) -> None:
        if self._daq_buf.n_samples == 0:
            self._daq_buf.first = block.first_sample
        self._daq_buf.append(block.data, block.valid, block.overload)
        if self.writer is not None:
            self.writer.append_daq(block.first_sample, block.data, block.valid, block.overload)
        for e in block.events:
            if e.n_samples and e.kind in ("overflow", "lost_transfer"):
                self._gaps.append((e.first_sample, e.first_sample + e.n_samples, e.kind))
            self._event({"device": "daq", **asdict(e)})

    def _ingest_lc(self, k: int, block: LoadCellBlock) -> None:
        buf = self._lc_bufs[k]
        if buf.n_samples == 0:
            buf.first = block.first_sample
        if self.loadcell_outputs == "forces":
            assert block.forces is not None
            rows = block.forces
        else:
            rows = block.gauges_v
        if self._lc_zero[k] is None:
            # DC-coupled strain-gauge bridges read their zero and the static load at rest: the
            # first samples of the run (before the first strike is asked for) are the zero,
            # subtracted from everything after (AC-coupled gauges: about 0).
            n0 = min(self._zero_samples, rows.shape[1])
            ok = block.valid[:n0]
            if ok.any():
                self._lc_zero[k] = rows[:, :n0][:, ok].mean(axis=1)
        zero = self._lc_zero[k]
        if zero is not None:
            rows = rows - zero[:, None]
        buf.append(rows, block.valid, np.broadcast_to(block.overload, rows.shape))
        if self.writer is not None:
            self.writer.append_loadcell(k, block.gauges_v, block.valid)
        for e in block.events:
            if e.kind == "drift":
                buf.drift.append((e.first_sample, e.first_sample + e.n_samples))
            elif e.kind == "device_error" and e.n_samples > 0:
                # an EMCY or an NMT state naming its samples (a heartbeat note names none: the
                # samples that arrived are good)
                buf.errors.append((e.first_sample, e.first_sample + e.n_samples, e.message))
            self._event({"device": f"loadcell{k}", **asdict(e)})

    def _event(self, ev: dict[str, object]) -> None:
        log.info("acquisition event: %s", ev)
        if self.writer is not None:
            self.writer.log_event(ev)
        if self.on_event is not None:
            self.on_event(ev)

    def _trim(self, keep_from: int) -> None:
        self._daq_buf.trim(keep_from)
        for buf in self._lc_bufs:
            buf.trim(keep_from)

    def _until(self, end: int) -> None:
        while self._daq_buf.end < end:
            self._read_block()

    def _wait_trigger(self, input_index: int, armed_from: int) -> int:
        s = self.settings
        row = self.input_rows[input_index]
        search_from = armed_from
        limit = armed_from + s.trigger_timeout_samples
        while True:
            buf = self._daq_buf
            if buf.end > search_from:
                seg = buf.data[row, search_from - buf.first :]
                hits = np.flatnonzero(np.abs(np.nan_to_num(seg)) >= s.trigger_level_n)
                if hits.size:
                    return search_from + int(hits[0])
                if np.isnan(seg).any():
                    # samples lost while waiting (FIFO overflow, lost transfer): the strike may
                    # be among them; ask for it again rather than wait for one that never comes
                    raise StrikeLost(self._gap_kinds(search_from, buf.end))
                search_from = buf.end
                # keep only the pre-trigger history while waiting: O(1) memory and work per block
                self._trim(search_from - s.pretrigger_samples)
            if search_from > limit:
                raise DeviceTimeoutError(
                    f"input {self.input_names[input_index]}: no hammer force above "
                    f"{s.trigger_level_n} N within {s.trigger_timeout_samples} samples; strike "
                    "harder or lower trigger_level_n"
                )
            self._read_block()

    def _gap_kinds(self, first: int, end: int) -> str:
        """``"DAQ samples lost (FIFO overflow)"``: what lost samples in ``first .. end - 1``."""
        kinds = sorted(
            {
                "FIFO overflow" if k == "overflow" else "transfer lost"
                for a, b, k in self._gaps
                if a < end and b > first
            }
        )
        return "DAQ samples lost" + (f" ({', '.join(kinds)})" if kinds else "")
