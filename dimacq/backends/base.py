"""What a backend factory is given: :class:`DeviceContext`."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dimacq.config import Settings
from dimacq.errors import SetupError

if TYPE_CHECKING:
    from dimacq.devices.daq import Daq
    from dimacq.io.rig_file import RigFile
    from dimacq.model.setup import TestSetup

__all__ = ["DeviceContext", "Operator"]

log = logging.getLogger(__name__)

#: ``operator(input_index, daq_sample)``: strike input ``input_index`` of the setup at that DAQ
#: sample (a person is asked; a simulated lab's hand strikes exactly then).
Operator = Callable[[int, int], None]


@dataclass
class DeviceContext:
    """The devices of one rig (or one connection check) while they are open.

    Attributes
    ----------
    settings : Settings
    setup : TestSetup or None
        The test the rig is built for (None when only checking the devices).
    seed : int or None
        Seed of a simulated world (an acquisition request's ``seed``); None: the scenario's.
    noise_scale : float
        Factor on a simulated world's noise and drift levels (a request's ``noise_scale``;
        1: the scenario's, 0: noise-free). Real devices ignore it.
    calibration_bench : int or None
        Node of the load cell being calibrated on the inertial bench (the calibration mass on
        this cell, struck on the cell's support side): its amplifier opens without needing a
        calibration file (gauge outputs are read), and a simulated world puts its article on
        that bench. None: an ordinary test.
    operator : Operator or None
        Set by a backend whose world strikes by itself (the simulated lab); None: a person
        strikes when asked.
    fixed : dict
        Impact settings the devices impose (e.g. how far ahead the simulated lab can be struck).
    shared : dict
        State backends of one context share (e.g. the simulated lab behind the DAQ and the load
        cells: one physics, one sample clock).
    closers : list of callables
        Called in reverse order by :meth:`close`.
    daq : Daq or None
        The rig's DAQ task once opened (:func:`dimacq.services.acquisition.rig.build_rig` sets it). A load
        cell backend whose signals are DAQ inputs (``"daq-channels"``) reads through it and may
        replace it by a wrapper that hands those inputs to the cell: the rig uses ``ctx.daq``.
    """

    settings: Settings
    setup: TestSetup | None = None
    seed: int | None = None
    noise_scale: float = 1.0
    calibration_bench: int | None = None
    operator: Operator | None = None
    fixed: dict[str, Any] = field(default_factory=dict)
    shared: dict[str, Any] = field(default_factory=dict)
    closers: list[Callable[[], None]] = field(default_factory=list)
    daq: Daq | None = None
    _rig_file: RigFile | None = None

    @property
    def rig_file(self) -> RigFile:
        """The rig file of ``settings.rig_file`` (read once)."""
        if self._rig_file is None:
            from dimacq.io.rig_file import load_rig_file

            self._rig_file = load_rig_file(self.settings.rig_path)
            warning = simulated_rig_warning(self.settings)
            if warning:
                log.warning("%s", warning)
        return self._rig_file

    def on_close(self, fn: Callable[[], None]) -> None:
        self.closers.append(fn)

    def close(self) -> None:
        while self.closers:
            fn = self.closers.pop()
            try:
                fn()
            except Exception:  # closing must go on for the others
                log.exception("closing a device failed")

    def __enter__(self) -> DeviceContext:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def require_setup(ctx: DeviceContext, what: str) -> TestSetup:
    if ctx.setup is None:
        raise SetupError(f"{what} needs the test setup; build the rig for a setup")
    return ctx.setup


#: the line every rig file of the simulated lab carries (tests/scripts/simulated_rig_files.py)
SIMULATED_RIG_MARK = "written by tests/scripts/simulated_rig_files.py"


def simulated_rig_warning(settings: Settings) -> str | None:
    """A warning when a real DAQ or load cell backend runs with a rig file of the simulated lab
    (its sensitivities and calibrations are the virtual transducers', not yours), else None."""
    from dimacq.backends import is_simulated

    real = [
        f"{k} = {getattr(settings, k)!r}"
        for k in ("daq", "loadcell")
        if not is_simulated(k, getattr(settings, k))
        and not (k == "loadcell" and settings.loadcell == "daq-channels")
    ]
    if not real:
        return None
    path = settings.rig_path
    try:
        head = path.read_text(encoding="utf-8", errors="replace")[:2000]
    except OSError:
        return None
    if SIMULATED_RIG_MARK not in " ".join(head.replace("#", " ").split()):  # comment lines
        return None
    return (
        f"{', '.join(real)} with the simulated lab's rig file {path}: its sensitivities and load "
        "cell calibrations are the virtual transducers', not your rig's; give your own (rig_file, "
        "DIMACQ_RIG_FILE)"
    )
