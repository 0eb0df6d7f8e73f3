"""Devices: the configured digitizer, DAQ and load cells, their state and identities.

:class:`DeviceService` opens and closes the devices, records each one's state in a
:class:`DeviceInfo` (failures are recorded, not raised, when everything is opened at start, so the
service starts without hardware) and holds the open digitizer driver and its digitizing session
(:class:`~dimacq.services.geometry.digitizing.DigitizingSession`, built by the geometry service).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from dimacq.backends import is_simulated
from dimacq.backends.base import DeviceContext
from dimacq.config import Settings
from dimacq.errors import DeviceStateError, DimacqError, SetupError
from dimacq.services.lab.common import identity_dict
from dimacq.services.lab.ownership import DeviceOwners

if TYPE_CHECKING:
    from dimacq.drivers.digitizer import SerialDigitizer
    from dimacq.services.geometry.digitizing import DigitizingSession

__all__ = ["DeviceInfo", "DeviceService", "SessionFactory"]

log = logging.getLogger(__name__)

#: Builds the digitizing session around a freshly opened digitizer driver.
SessionFactory = Callable[["SerialDigitizer"], "DigitizingSession"]


@dataclass
class DeviceInfo:
    """State of one configured device."""

    name: str
    kind: Literal["digitizer", "daq", "loadcell"]
    address: str
    simulated: bool
    connected: bool = False
    identity: dict[str, Any] = field(default_factory=dict)
    error: str = ""
    #: why the device was last seen lost by the worker using it ("" = working), and when its
    #: state last changed (UNIX time, s): what ``/api/status`` reports without touching it
    lost: str = ""
    since: float = field(default_factory=time.time)


class DeviceService:
    """The configured devices (digitizer, DAQ, load cells).

    Parameters
    ----------
    settings : Settings
    open_session : callable (driver) -> DigitizingSession
        Called each time the digitizer is (re)opened.
    """

    def __init__(self, settings: Settings, open_session: SessionFactory) -> None:
        self.settings = settings
        self._open_session = open_session
        #: held while the digitizer driver or its session is used (one caller at a time)
        self.lock = threading.RLock()
        self._digitizer: SerialDigitizer | None = None
        self._article: dict[str, Any] | None = None  # simulated_article, built once
        self._digitizer_ctx: DeviceContext | None = None
        self._session: DigitizingSession | None = None
        #: who holds each device (an acquisition, a calibration run, a connect): one at a time
        self.owners = DeviceOwners()
        # The backend each kind names (dimacq.backends.BACKENDS); "simulated" and
        # "canopen-simulated" are the virtual lab (is_simulated).
        self._devices: dict[str, DeviceInfo] = {
            "digitizer": DeviceInfo(
                "digitizer",
                "digitizer",
                f"{settings.digitizer}:{settings.digitizer_url}",
                is_simulated("digitizer", settings.digitizer),
            ),
            "daq": DeviceInfo(
                "daq",
                "daq",
                f"{settings.daq}:{settings.rig_path.name}",
                is_simulated("daq", settings.daq),
            ),
            "loadcell": DeviceInfo(
                "loadcell",
                "loadcell",
                f"{settings.loadcell}:{settings.rig_path.name}",
                # a cell read as DAQ inputs is simulated when its DAQ is
                is_simulated("loadcell", settings.loadcell)
                or (settings.loadcell == "daq-channels" and is_simulated("daq", settings.daq)),
            ),
        }

    # ------------------------------------------------------------------ the list
    def all(self) -> list[DeviceInfo]:
        return list(self._devices.values())

    def get(self, name: str) -> DeviceInfo | None:
        return self._devices.get(name)

    def mark(self, name: str, lost: str = "") -> None:
        """What a worker using device ``name`` saw: lost (``lost`` says why) or working
        (``""``). Cheap and from any thread: the acquisition and the digitizing session call it
        as they see it, and ``/api/status`` reports it without touching the device."""
        info = self._devices.get(name)
        if info is None or info.lost == lost:
            return
        if lost:
            log.warning("device %s lost: %s", name, lost)
        elif info.lost:
            log.warning("device %s working again", name)
        info.lost, info.since = lost, time.time()

    def on_acquisition_event(self, ev: Mapping[str, object]) -> None:
        """An acquisition session's event (:class:`~dimacq.services.acquisition.session.ImpactSession`
        ``on_event``) → the DAQ's state: lost (the run restarts, or fails when the DAQ stopped
        answering) and found again."""
        if ev.get("device") != "daq":
            return
        if ev.get("kind") == "restart":
            self.mark("daq", "dropped off the bus during the acquisition; reconnecting")
        elif ev.get("kind") == "lost":
            self.mark("daq", "stopped answering during the acquisition (reads timed out)")
        elif ev.get("kind") == "reconnected":
            self.mark("daq", "")

    def require(self, name: str) -> DeviceInfo:
        """The device ``name``; SetupError naming the known ones if there is none."""
        info = self._devices.get(name)
        if info is None:
            raise SetupError(f"device {name!r} is unknown; use one of {sorted(self._devices)}")
        return info

    # ------------------------------------------------------------------ open and close
    def connect_all(self) -> None:
        for name in self._devices:
            try:
                self.connect(name)
            except DimacqError as err:
                log.warning("device %s not connected: %s", name, err)

    def disconnect_all(self) -> None:
        with self.lock:
            self._close_digitizer()
            self._session = None
            for d in self._devices.values():
                d.connected = False

    def connect(self, name: str) -> DeviceInfo:
        """(Re)open one device; the device list records the outcome. Refused (409) while a job
        holds the device: reopening it would cut that job's stream."""
        info = self.require(name)
        with self.owners.hold((name,), f"a connect of {name}"), self.lock:
            try:
                if info.kind == "digitizer":
                    self._connect_digitizer(info)
                else:
                    self._connect_acquisition_device(info)
            except DimacqError as err:
                info.connected = False
                info.error = str(err)
                info.since = time.time()
                raise
            info.error = ""
            info.since = time.time()
            self.mark(name, "")
            return info

    def identify(self, name: str) -> dict[str, Any]:
        info = self.require(name)
        with self.owners.hold((name,), f"an identify of {name}"):
            if not info.connected:
                raise DeviceStateError(
                    f"device {name} is not connected ({info.error or 'closed'}); connect it first"
                )
            if info.kind == "digitizer":
                with self.lock:
                    info.identity = identity_dict(self.digitizer().identify())
            return dict(info.identity)

    # ------------------------------------------------------------------ the digitizer
    def simulated_article(self) -> dict[str, Any] | None:
        """Where the simulated article's sensors, impact points and load cells are (setup-file
        format, GCS metres), the scenario's recommended band and the orientation jig — what the
        engineer's hand knows in the virtual lab — or None when no device is simulated. Reached
        through the backend table's module path, like every simulated device."""
        s = self.settings
        if not any(is_simulated(k, getattr(s, k)) for k in ("daq", "loadcell", "digitizer")):
            return None
        # the scenario is the service's for its whole life: built once (~0.1-0.2 s), then kept
        if self._article is not None:
            return self._article
        from dimacq.backends import import_factory
        from dimacq.services.geometry.digitizer_config import load_jig

        geometry = import_factory("dimacq.backends.simulated:article_geometry", setting="scenario")
        out: dict[str, Any] = geometry(s.scenario)
        jig = load_jig()
        out["jig"] = {
            "labels": list(jig.labels),
            "points_local_m": [[float(v) for v in p] for p in jig.points_local_m],
        }
        self._article = out
        return out

    def simulated_truth(self) -> dict[str, Any] | None:
        """The simulated article's true properties (the simulator's, for showing beside an
        answer), or None when no device is simulated."""
        s = self.settings
        if not any(is_simulated(k, getattr(s, k)) for k in ("daq", "loadcell", "digitizer")):
            return None
        from dimacq.backends import import_factory

        truth = import_factory("dimacq.backends.simulated:article_truth", setting="scenario")
        out: dict[str, Any] = truth(s.scenario)
        return out

    def digitizer(self) -> SerialDigitizer:
        """The open digitizer driver (DeviceStateError if it is not connected)."""
        self.session()
        assert self._digitizer is not None
        return self._digitizer

    def session(self) -> DigitizingSession:
        """The digitizing session of the open digitizer (DeviceStateError if not connected)."""
        info = self._devices["digitizer"]
        if self._session is None or not info.connected:
            raise DeviceStateError(
                f"digitizer is not connected ({info.error or 'closed'}); POST "
                "/api/devices/digitizer/connect first"
            )
        return self._session

    def session_if_open(self) -> DigitizingSession | None:
        """The digitizing session if the digitizer is open, else None (hold :attr:`lock`)."""
        return self._session

    def _close_digitizer(self) -> None:
        """Close the digitizer's port and what its backend opened (logs, never raises: a
        vanished port must not stop the shutdown)."""
        ctx, self._digitizer_ctx = self._digitizer_ctx, None
        self._digitizer = None
        if ctx is not None:
            ctx.close()

    def _connect_digitizer(self, info: DeviceInfo) -> None:
        from dimacq.backends import lookup
        from dimacq.services.geometry.digitizer_config import load_array_config

        self._close_digitizer()
        cfg = load_array_config()
        ctx = DeviceContext(self.settings)
        try:
            driver = lookup("digitizer", self.settings.digitizer)(ctx)
            ident = driver.identify()
        except BaseException:
            ctx.close()
            raise
        self._digitizer_ctx = ctx
        driver.configure(
            emitters=2, microphones=len(cfg.array.microphones_m), averaging=1, bar_repeats=4
        )
        self._digitizer = driver
        self._session = self._open_session(driver)
        self._session.on_device = lambda lost: self.mark("digitizer", lost)
        info.connected = True
        info.identity = identity_dict(ident)

    # ------------------------------------------------------------------ DAQ and load cells
    def _connect_acquisition_device(self, info: DeviceInfo) -> None:
        """Open the DAQ or every load cell of the rig file through its backend, identify,
        close (:func:`dimacq.services.acquisition.rig.build_rig` opens them again for each acquisition)."""
        from dimacq.services.acquisition.rig import check_devices

        kind: Literal["daq", "loadcell"] = "daq" if info.kind == "daq" else "loadcell"
        info.identity = check_devices(self.settings, kind)
        if info.simulated:
            info.identity["scenario"] = self.settings.scenario
        info.connected = True
