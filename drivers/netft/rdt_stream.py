"""One RDT stream's records and arrivals, as :class:`~dimacq.drivers.netft.udp_driver.NetFtUdp`
keeps them: the records by index ``j = rdt_sequence − 1`` (NaN where lost), each window's
least-waiting arrival (the lower envelope the clock fit rests on), and the positions each
delivered block of DAQ samples was given."""

from __future__ import annotations

import numpy as np

from dimacq.pipeline.stream_alignment import ClockFit, fit_lower_envelope

__all__ = ["MIN_WINDOWS", "WINDOW_S", "RdtRun"]

#: host seconds per window of the lower-envelope fit
WINDOW_S = 0.2
#: windows of arrivals before the DAQ starts (3 s of the host: the envelope's slope, fitted
#: from then on, rests on two datagrams that waited least, a span apart: ~1 ppm at 3 s)
MIN_WINDOWS = 15


class RdtRun:
    """One stream's records by index ``j = rdt_sequence − 1`` (NaN where lost) and its
    datagrams' arrivals."""

    def __init__(self, rdt_rate_hz: float, nominal_slope: float) -> None:
        self.rdt_rate_hz = rdt_rate_hz
        self.ft0: int | None = None  # ft_sequence of record 0
        self._vals = np.full((4096, 6), np.nan)
        self._bad = np.zeros((4096, 1))
        self.end = 0  # one past the highest index received
        self._n = 0  # datagrams
        # the lowest arrival of each window (host s) against its record's sensor time: the
        # lower envelope, kept as the datagrams come (the fit never looks at every arrival)
        self._slope = nominal_slope
        self._t_first: float | None = None
        self._w: list[int] = []
        self._t: list[float] = []
        self._s: list[float] = []
        self.next_sample = 0
        self.checked = False
        self.last_bad_status = 0
        self._fit: ClockFit | None = None
        self._fit_key: tuple[int, float] | None = None
        #: records added to the clock fit's positions: what keeps them continuous from block
        #: to block (see :meth:`~dimacq.drivers.netft.udp_driver.NetFtUdp.read_until`)
        self.corr = 0.0
        #: the position the last block's mapping gives sample ``next_sample`` (None: no block yet)
        self.u_next: float | None = None
        #: each delivered block's first sample, its position and its positions' step per sample
        #: (linear within a block): what :meth:`~dimacq.drivers.netft.udp_driver.NetFtUdp.alignment_offsets_s` compares
        self.blocks: list[tuple[int, float, float]] = []

    @property
    def n_arrivals(self) -> int:
        return self._n

    def put(
        self, j: np.ndarray, counts: np.ndarray, status: np.ndarray, t: float, s_last: float
    ) -> None:
        top = int(j.max()) + 1
        if top > self._vals.shape[0]:
            n = max(top, 2 * self._vals.shape[0])
            vals = np.full((n, 6), np.nan)
            vals[: self._vals.shape[0]] = self._vals
            bad = np.zeros((n, 1))
            bad[: self._bad.shape[0]] = self._bad
            self._vals, self._bad = vals, bad
        self._vals[j] = counts
        self._bad[j, 0] = status != 0
        if np.any(status != 0):
            self.last_bad_status = int(status[status != 0][-1])
        self.end = max(self.end, top)
        self._n += 1
        if self._t_first is None:
            self._t_first = t
        w = int((t - self._t_first) / WINDOW_S)
        if self._w and self._w[-1] == w:
            if t - self._slope * s_last < self._t[-1] - self._slope * self._s[-1]:
                self._t[-1], self._s[-1] = t, s_last
        else:
            self._w.append(w)
            self._t.append(t)
            self._s.append(s_last)

    def values(self) -> np.ndarray:
        return self._vals[: self.end]

    def flags(self) -> np.ndarray:
        return self._bad[: self.end]

    @property
    def n_windows(self) -> int:
        return len(self._w)

    def fit(self, nominal_slope: float) -> ClockFit:
        """The clock fit of the windows' minima (refitted when one of them changed)."""
        key = (len(self._w), self._t[-1] - self._slope * self._s[-1]) if self._w else (0, 0.0)
        if self._fit is None or self._fit_key != key:
            self._fit = fit_lower_envelope(
                np.asarray(self._s),
                np.asarray(self._t),
                nominal_slope=nominal_slope,
                window_s=WINDOW_S,
                min_windows=MIN_WINDOWS,
            )
            self._fit_key = key
        return self._fit
