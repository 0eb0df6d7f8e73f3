"""The digitizer device interface: what services, the CLI and the API import.

A digitizer fires its probe emitters and calibration bar and returns raw counter values
(:class:`ShotRecord`); turning them into positions is the pipeline's job
(:mod:`dimacq.pipeline.digitizing.triangulation`). The wire-level implementation is
:class:`dimacq.drivers.digitizer.SerialDigitizer`; its protocol is documented in
:mod:`dimacq.drivers.digitizer.protocol`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["DeviceIdentity", "Digitizer", "DigitizerSettings", "ShotRecord"]


@dataclass(frozen=True)
class DeviceIdentity:
    """Answer to the identify command."""

    vendor: str
    model: str
    serial: str
    firmware: str
    n_microphones: int


@dataclass(frozen=True)
class DigitizerSettings:
    """Acquisition settings of the device.

    Attributes
    ----------
    emitters : int
        Probe emitters fired per shot (1 or 2; 2 for tip extrapolation).
    microphones : int
        Microphones used (the first ``microphones`` of the array).
    averaging : int
        Firings per emitter summed into one counter value (1..16).
    bar_repeats : int
        Calibration bar firings per shot (1..8).
    clock_hz : float
        Counter clock (read only).
    delay_counts : int
        Fixed electronic delay in counter periods (read only).
    """

    emitters: int = 2
    microphones: int = 4
    averaging: int = 1
    bar_repeats: int = 4
    clock_hz: float = 10e6
    delay_counts: int = 500


@dataclass(frozen=True)
class ShotRecord:
    """One shot as the device reports it.

    Attributes
    ----------
    seq : int
        Sequence number (0..65535, wraps), increments per shot since reset.
    status : int
        Status flags, see :class:`dimacq.drivers.digitizer.protocol.Status`.
    averaging : int
        Firings summed into each counter value.
    counts : ndarray of int64, shape (E, M)
        Summed counter values per emitter × microphone.
    bar_counts : ndarray of int64, shape (B,)
        Counter value of each calibration bar firing.
    """

    seq: int
    status: int
    averaging: int
    counts: NDArray[np.int64]
    bar_counts: NDArray[np.int64]

    @property
    def n_emitters(self) -> int:
        return int(self.counts.shape[0])

    @property
    def n_microphones(self) -> int:
        return int(self.counts.shape[1])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ShotRecord):
            return NotImplemented
        return (
            self.seq == other.seq
            and self.status == other.status
            and self.averaging == other.averaging
            and np.array_equal(self.counts, other.counts)
            and np.array_equal(self.bar_counts, other.bar_counts)
        )

    __hash__ = None  # type: ignore[assignment]


@runtime_checkable
class Digitizer(Protocol):
    """A 3D sonic digitizer.

    Every method raises :class:`dimacq.errors.DeviceTimeoutError` when the device does not answer,
    :class:`dimacq.errors.ProtocolError` for malformed replies, and
    :class:`dimacq.errors.DeviceNotFoundError` when the port has gone; after the latter,
    :meth:`reconnect` reopens the same port.
    """

    def identify(self) -> DeviceIdentity:
        """Who is on the port."""
        ...

    def reset(self) -> None:
        """Reset the device: default settings, sequence number 0, streaming stopped."""
        ...

    def configure(
        self,
        *,
        emitters: int | None = None,
        microphones: int | None = None,
        averaging: int | None = None,
        bar_repeats: int | None = None,
    ) -> DigitizerSettings:
        """Change settings (``None`` keeps a value); return the settings the device reports."""
        ...

    def settings(self) -> DigitizerSettings:
        """Read the present settings."""
        ...

    def fire(self) -> ShotRecord:
        """Fire one shot and return its record."""
        ...

    def stream(self, n_shots: int) -> Iterator[ShotRecord]:
        """Fire ``n_shots`` shots back to back and yield the records as they arrive."""
        ...

    def reconnect(self) -> DeviceIdentity:
        """Reopen the port after it vanished; return who answers."""
        ...

    def close(self) -> None:
        """Close the port."""
        ...
