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
"""

from __future__ import annotations

from typing import Any

from dimacq.config import Settings
from dimacq.errors import DeviceNotFoundError, SetupError

__all__ = ["open_can_bus", "resolved_interface"]

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
