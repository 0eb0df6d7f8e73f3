"""The DAQ device interface: what services, the CLI and the API import.

A DAQ acquires accelerometer and force channels on one sample clock, in engineering units,
aligned on its sample counter (NI-DAQmx / uldaq model: task → channels → timing → start → read
→ stop). The wire-level implementation is :class:`dimacq.drivers.daq.driver.DaqTask` over
:class:`dimacq.drivers.daq.driver.DaqDevice` (USB, protocol in :mod:`dimacq.drivers.daq.protocol`);
the simulator is a pyusb backend (:mod:`dimacq.simulators.daq.backend`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["ChannelConfig", "Daq", "DaqBlock", "DaqEvent"]


@dataclass(frozen=True)
class ChannelConfig:
    """One task channel.

    Attributes
    ----------
    physical_channel : int
        DAQ input, 0-based.
    name : str
        e.g. ``"1103+Y"`` or ``"21+X force"``.
    units : str
        Engineering unit of the data: ``"m/s^2"``, ``"N"`` or ``"V"``.
    sensitivity_v_per_unit : float
        Transducer sensitivity, V per engineering unit (100 mV/g → 0.1/9.80665 V/(m/s²)).
    range_v, iepe_current_ua, coupling
        Input settings.
    """

    physical_channel: int
    name: str
    units: str
    sensitivity_v_per_unit: float
    range_v: float = 10.0
    iepe_current_ua: int = 0
    coupling: Literal["AC", "DC"] = "DC"


@dataclass(frozen=True)
class DaqEvent:
    """Something the acquisition must know about: ``kind`` in
    ``{"overflow", "lost_transfer", "overload", "timeout"}``, the sample range it concerns
    (``first_sample`` .. ``first_sample + n_samples - 1``) and the channels involved."""

    kind: str
    first_sample: int
    n_samples: int
    channels: tuple[str, ...] = ()
    message: str = ""


@dataclass(frozen=True, eq=False)
class DaqBlock:
    """Samples ``first_sample .. first_sample + n - 1`` of a task, in engineering units.

    Attributes
    ----------
    data : ndarray, shape (n_channels, n_samples)
        NaN where samples were lost (see ``events``).
    overload : ndarray of bool, shape (n_channels, n_samples)
        True in every frame in which that channel clipped.
    valid : ndarray of bool, shape (n_samples,)
        False for samples lost to a FIFO overflow or a lost transfer.
    events : tuple of DaqEvent
    """

    first_sample: int
    sample_rate_hz: float
    channel_names: tuple[str, ...]
    units: tuple[str, ...]
    data: NDArray[np.float64]
    overload: NDArray[np.bool_]
    valid: NDArray[np.bool_]
    events: tuple[DaqEvent, ...] = ()

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[1])


@runtime_checkable
class Daq(Protocol):
    """An acquisition task on one DAQ."""

    sample_rate_hz: float | None
    events: list[DaqEvent]
    #: Samples the DAQ's clock produced in the last run (known after stop(), else None): what
    #: devices counting its SYNC output saw, which can exceed the samples the host received.
    samples_clocked: int | None

    @property
    def channel_names(self) -> tuple[str, ...]: ...

    @property
    def running(self) -> bool: ...

    def add_accel_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_g: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None: ...

    def add_force_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_n: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None: ...

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None: ...

    def identify(self) -> object:
        """Who the DAQ is (a dataclass: model, serial number, firmware, ...)."""
        ...

    def start(self) -> None: ...

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock: ...

    def read_available(self, timeout_s: float | None = None) -> DaqBlock: ...

    def read_buffered(self) -> DaqBlock | None: ...

    def samples_clocked_now(self) -> int | None:
        """Samples the DAQ's clock has produced since start, as of this call (a status query of
        the device), or None when the device cannot say. Ahead of what the host has read when
        the host is behind: a strike asked for now lands at or after it (an impact session
        looks for the hit from there, not from the samples still queued)."""
        ...

    def stop(self) -> None: ...
