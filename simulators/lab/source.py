"""Interface between the virtual lab's time-domain physics and the device simulators.

One :class:`SampleSource` stands for the analogue world behind the lab's shared sample clock:
every DAQ channel (accelerometers, force transducers) and every load cell gauge is sampled on the
same clock, so the DAQ simulator and the load cell simulator read their own channels from the
same source and their sample counters agree, as in the real lab where the load cell amplifier
counts the DAQ's sample clock.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray


@runtime_checkable
class SampleSource(Protocol):
    """Blocks of physical signals on the lab's shared sample clock.

    Attributes
    ----------
    sample_rate_hz : float
        The shared sample clock.
    channel_names : tuple of str
        One name per channel, e.g. ``"1103+Y"`` for an accelerometer axis, ``"21+X force"``
        for the hammer or shaker load cell, ``"LC501 g07"`` for load cell gauge 7.
    channel_units : tuple of str
        Physical unit of each channel at the transducer: ``"m/s^2"``, ``"N"``, ``"V"`` (gauges).
    """

    sample_rate_hz: float
    channel_names: tuple[str, ...]
    channel_units: tuple[str, ...]

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> NDArray[np.float64]:
        """Samples ``start .. start+n-1`` (sample counter) of the given channels.

        Returns an array of shape ``(len(channels), n)`` in each channel's physical unit.
        Reading the same counter range twice gives the same samples, so two devices that read
        the same range see one consistent world.
        """
        ...

    def excite(self, input_index: int, at_sample: int) -> None:
        """The virtual operator: strike (or drive) input ``input_index`` from sample ``at_sample`` on."""
        ...
