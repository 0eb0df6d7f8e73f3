"""Opening the CAN bus of a real load cell backend, as python-can users expect.

:func:`open_can_bus` is the one place the real CAN backends (``dimacq-can``, ``canopen``,
``netft-can``, ``cia404``) call ``can.Bus``:

============================== =============================================================
setting                         what reaches ``can.Bus``
============================== =============================================================
``loadcell_interface``          ``interface=``; ``""``: python-can's own configuration
                                (``~/.canrc`` / ``~/.can`` / ``/etc/can.conf``, the
                                ``CAN_INTERFACE`` / ``CAN_CHANNEL`` / ``CAN_BITRATE``
                                environment), as ``can.Bus()`` alone reads it
``loadcell_channel`` (or the    ``channel=`` (``""`` with an empty interface: python-can's)
rig file entry's ``channel``)
``loadcell_can_options``        every key as given (``device_id``, ``accept_virtual``,
                                ``receive_own_messages``, ``serial``, ``app_name`` ...)
``loadcell_can_bit_timing``     ``timing=can.BitTiming(f_clock, brp, tseg1, tseg2, sjw,
                                nof_samples)`` in place of ``bitrate=`` (classic CAN)
``loadcell_virtual_ok``         ``"virtual"`` (python-can's in-process bus, where no device is)
                                is refused with a real backend unless true (tests that put a
                                simulator on it)
============================== =============================================================

Errors are one line naming the setting and the fix: an unknown interface, the adapter's library
missing (python-can raises ``CanInterfaceNotImplementedError``, ``NameError`` or
``ImportError`` then), a channel that does not open.

**One bus per channel.** An adapter channel is opened once per process however many cells are
on it (PCAN allows one client per channel; a second ``can.Bus`` on it fails, and two
``can.Notifier`` on one bus are refused by python-can). :class:`CanBusRegistry` keys the open
buses by ``(interface, channel)`` and counts their users: each user gets its own
:class:`SharedBusHandle`, a ``can.BusABC`` with its own receive queue and its own filters, fed
by one reader thread of the real bus; the last handle shut down shuts the bus down. A second
user asking the same channel with other bus options (another bit rate, CAN FD on a classic
channel) is refused. :func:`shared_can_bus` is :func:`open_can_bus` through the process's
registry (:data:`BUSES`). Frames a handle sends are not received by the other handles of the
same channel (as an adapter does not receive its own frames).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

import can

from dimacq.config import Settings
from dimacq.errors import DeviceNotFoundError, SetupError

__all__ = [
    "BUSES",
    "CanBusRegistry",
    "SharedBusHandle",
    "open_can_bus",
    "resolved_interface",
    "shared_can_bus",
]

log = logging.getLogger(__name__)

#: how long the reader thread waits on the real bus before looking for a shutdown, s
_READ_S = 0.05

_TIMING_KEYS = ("f_clock", "brp", "tseg1", "tseg2", "sjw", "nof_samples")


def resolved_interface(settings: Settings) -> tuple[str, str | None]:
    """``(interface, channel)`` of the setting, or of python-can's own configuration when the
    setting is empty ("" when python-can has none either)."""
    if settings.loadcell_interface:
        return settings.loadcell_interface, None
    import can

    try:
        cfg = can.util.load_config()
    except can.CanInterfaceNotImplementedError as err:
        raise DeviceNotFoundError(
            f"loadcell_interface is empty and python-can's configuration (~/.canrc, "
            f"CAN_INTERFACE) names an unknown python-can interface ({err}); correct it or set "
            "loadcell_interface (DIMACQ_LOADCELL_INTERFACE)"
        ) from err
    ch = cfg.get("channel")
    return str(cfg.get("interface") or ""), None if ch is None else str(ch)


def _bit_timing(settings: Settings) -> Any:
    import can

    t: dict[str, Any] = dict(settings.loadcell_can_bit_timing)
    unknown = sorted(set(t) - set(_TIMING_KEYS))
    missing = [k for k in _TIMING_KEYS[:5] if k not in t]
    if unknown or missing:
        raise SetupError(
            f"loadcell_can_bit_timing = {t}: "
            + (f"unknown keys {unknown}" if unknown else f"missing {missing}")
            + "; give f_clock, brp, tseg1, tseg2, sjw (and optionally nof_samples)"
        )
    try:
        return can.BitTiming(**t)
    except ValueError as err:
        raise SetupError(
            f"loadcell_can_bit_timing = {t}: {err}; give segments valid for the adapter's clock"
        ) from err


def open_can_bus(
    settings: Settings,
    *,
    backend: str,
    channel: str,
    bitrate: int | None = None,
    **kwargs: Any,
) -> Any:
    """``can.Bus`` of a real load cell backend (see the module docstring); ``kwargs`` are the
    backend's own (``fd``, ``timing``, ``can_filters``). A classic backend gives ``bitrate``:
    replaced by ``loadcell_can_bit_timing`` when that is set.

    Raises
    ------
    SetupError
        ``virtual`` with a real backend, no interface configured anywhere, bad bit timing.
    DeviceNotFoundError
        The bus does not open (unknown interface, missing adapter library, channel absent).
    """
    import can

    interface, rc_channel = resolved_interface(settings)
    src = "loadcell_interface" if settings.loadcell_interface else "python-can's configuration"
    if not interface:
        raise SetupError(
            f"loadcell = {backend!r}: no CAN interface configured (loadcell_interface is empty "
            "and python-can's ~/.canrc / CAN_INTERFACE give none); set loadcell_interface "
            "(DIMACQ_LOADCELL_INTERFACE: pcan, socketcan, kvaser, ...)"
        )
    if interface == "virtual" and not settings.loadcell_virtual_ok:
        raise SetupError(
            f"loadcell = {backend!r} is a real device but {src} gives interface 'virtual' "
            "(python-can's in-process bus: no device there); set loadcell_interface to your "
            f"adapter's (pcan, socketcan, kvaser, ...) or use loadcell = '{backend}-simulated' "
            "(a test putting a simulator on 'virtual': loadcell_virtual_ok = true)"
        )
    kw: dict[str, Any] = dict(kwargs)
    if bitrate is not None:
        if settings.loadcell_can_bit_timing:
            kw["timing"] = _bit_timing(settings)
        else:
            kw["bitrate"] = bitrate
    kw.update(settings.loadcell_can_options)
    chan = channel or rc_channel or ""
    where = f"loadcell = {backend!r}, loadcell_interface = {interface!r}, channel {chan!r}"
    if interface not in can.interfaces.VALID_INTERFACES:
        raise DeviceNotFoundError(
            f"{where}: unknown python-can interface {interface!r}; set loadcell_interface to one "
            f"of {', '.join(sorted(can.interfaces.VALID_INTERFACES))}"
        )
    try:
        return can.Bus(interface=interface, channel=chan, **kw)
    except Exception as err:  # python-can raises anything without the vendor library
        why = f"{type(err).__name__}: {err}".replace("\n", " ")
        if isinstance(err, (NameError, ImportError, AttributeError)) or (
            isinstance(err, can.CanInterfaceNotImplementedError)
        ):
            raise DeviceNotFoundError(
                f"{where}: the vendor library of interface {interface!r} is missing ({why}); "
                "install the adapter's driver and library (e.g. PCAN-Basic for pcan, CANlib for "
                "kvaser) or set loadcell_interface (DIMACQ_LOADCELL_INTERFACE)"
            ) from err
        raise DeviceNotFoundError(
            f"{where}: cannot open the CAN bus ({why}); check the adapter is plugged in and "
            "loadcell_interface/loadcell_channel (DIMACQ_LOADCELL_INTERFACE/_CHANNEL), "
            "loadcell_can_options and the bit rate"
        ) from err


class SharedBusHandle(can.BusABC):
    """One user's end of a shared channel: its own receive queue and filters; ``send`` goes to
    the real bus; ``shutdown`` releases it (:class:`CanBusRegistry`)."""

    def __init__(self, hub: _Hub, can_filters: Any = None) -> None:
        self._hub = hub
        self._q: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        super().__init__(channel=hub.key[1], can_filters=can_filters)
        self.channel_info = f"shared {hub.key[0]}:{hub.key[1]}"

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            if timeout is not None and timeout <= 0:
                return self._q.get_nowait(), True
            return self._q.get(timeout=timeout), True
        except queue.Empty:
            return None, True

    def _put(self, msg: can.Message) -> None:
        if self._matches_filters(msg):  # filtered here: a handle queues only its own frames
            self._q.put(msg)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._hub.send(msg, timeout)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self._hub.release(self)


class _Hub:
    """The real bus of one channel, its reader thread and its users' handles."""

    def __init__(self, key: tuple[str, str], bus: Any, options: str, registry: CanBusRegistry):
        self.key = key
        self.bus = bus
        self.options = options
        self.registry = registry
        self.handles: list[SharedBusHandle] = []
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name=f"can-hub-{key[0]}:{key[1]}")
        self._thread.daemon = True
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(_READ_S)
            except can.CanError as err:
                log.warning("CAN %s:%s: receive failed: %s", *self.key, err)
                continue
            except Exception:  # the bus shut down under the thread
                if self._stop.is_set():
                    return
                raise
            if msg is None:
                continue
            for h in list(self.handles):
                h._put(msg)

    def send(self, msg: can.Message, timeout: float | None) -> None:
        with self._send_lock:
            self.bus.send(msg, timeout)

    def release(self, handle: SharedBusHandle) -> None:
        self.registry._release(self, handle)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.bus.shutdown()


class CanBusRegistry:
    """The open CAN channels of a process, keyed by ``(interface, channel)``, reference
    counted by their handles (see the module docstring)."""

    def __init__(self) -> None:
        self._hubs: dict[tuple[str, str], _Hub] = {}
        self._lock = threading.Lock()

    def acquire(
        self,
        interface: str,
        channel: str,
        opener: Callable[[], Any],
        *,
        options: str = "",
        can_filters: Any = None,
        where: str = "",
    ) -> SharedBusHandle:
        """A new handle on channel ``(interface, channel)``, opening it with ``opener()`` when
        no handle holds it. ``options`` describes how it is opened (bit rate, FD): a user
        asking other options of an open channel is refused.

        Raises
        ------
        SetupError
            The channel is open with other options.
        """
        key = (str(interface), str(channel))
        with self._lock:
            hub = self._hubs.get(key)
            if hub is None:
                hub = _Hub(key, opener(), options, self)
                self._hubs[key] = hub
            elif hub.options != options:
                raise SetupError(
                    f"{where or 'CAN'}: channel {key[1]!r} of interface {key[0]!r} is already "
                    f"open with {hub.options or 'other options'}, not {options or 'these'}; give "
                    "every cell on one channel the same bit rate and frame format, or put them "
                    "on another channel"
                )
            h = SharedBusHandle(hub, can_filters)
            hub.handles.append(h)
            return h

    def _release(self, hub: _Hub, handle: SharedBusHandle) -> None:
        with self._lock:
            if handle in hub.handles:
                hub.handles.remove(handle)
            last = not hub.handles
            if last:
                self._hubs.pop(hub.key, None)
        if last:
            hub.close()

    def users(self, interface: str, channel: str) -> int:
        """How many handles hold the channel (0: closed)."""
        hub = self._hubs.get((str(interface), str(channel)))
        return 0 if hub is None else len(hub.handles)


#: the process's open CAN channels (an adapter channel opens once per process)
BUSES = CanBusRegistry()


def shared_can_bus(
    settings: Settings,
    *,
    backend: str,
    channel: str,
    bitrate: int | None = None,
    can_filters: Any = None,
    registry: CanBusRegistry | None = None,
    **kwargs: Any,
) -> SharedBusHandle:
    """A handle on the channel :func:`open_can_bus` opens (opened once per channel, shared by
    every cell on it; ``can_filters`` are this handle's own).

    Raises
    ------
    SetupError, DeviceNotFoundError
        As :func:`open_can_bus`; or the channel already open with other options.
    """
    interface, rc_channel = resolved_interface(settings)
    chan = channel or rc_channel or ""
    options = f"bitrate {bitrate}" if bitrate is not None else "default bit rate"
    options += "".join(f", {k}={kwargs[k]!r}" for k in sorted(kwargs) if k != "timing")
    if "timing" in kwargs:
        options += f", timing {kwargs['timing']}"
    reg = BUSES if registry is None else registry
    return reg.acquire(
        interface,
        chan,
        lambda: open_can_bus(settings, backend=backend, channel=chan, bitrate=bitrate, **kwargs),
        options=options,
        can_filters=can_filters,
        where=f"loadcell = {backend!r}",
    )
