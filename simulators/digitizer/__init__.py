"""Simulated sonic digitizer: the SD-3 protocol over a pyserial URL handler or a real pty.

Importing this package registers the ``simdigitizer://`` URL scheme with pyserial (through
``serial.protocol_handler_packages``), so ``serial.serial_for_url("simdigitizer://lab1?seed=3")``
opens a simulated device. Devices live in a registry by name so that reopening the same URL (a
reconnect) finds the same device, with its sequence number and settings::

    simdigitizer://<name>[?seed=<int>&echo=<p>&temp=<degC>&rate=<shots/s>&config=<array.toml>]

The query parameters are used when the name is first opened; later opens reuse the device.
"""

from __future__ import annotations

import threading
import urllib.parse
from pathlib import Path

import serial

from dimacq.errors import SetupError
from dimacq.simulators.digitizer.device import SimulatedDigitizer, lab_from_config

__all__ = [
    "SCHEME",
    "SimulatedDigitizer",
    "get_device",
    "install_url_handler",
    "register_device",
    "unregister_device",
]

SCHEME = "simdigitizer"
_registry: dict[str, SimulatedDigitizer] = {}
_registry_lock = threading.Lock()


def install_url_handler() -> None:
    """Make pyserial resolve ``simdigitizer://`` URLs (idempotent)."""
    if __name__ not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(__name__)


def register_device(name: str, device: SimulatedDigitizer) -> None:
    """Make ``simdigitizer://<name>`` open ``device``."""
    with _registry_lock:
        _registry[name] = device


def unregister_device(name: str) -> None:
    """Forget a device (tests call this in their teardown)."""
    with _registry_lock:
        _registry.pop(name, None)


def get_device(url: str) -> SimulatedDigitizer:
    """The device behind a ``simdigitizer://`` URL, created from its query on first use."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != SCHEME or not parts.netloc:
        raise SetupError(f"URL {url!r}: expected simdigitizer://<name>[?seed=..&echo=..&temp=..]")
    name = parts.netloc
    with _registry_lock:
        device = _registry.get(name)
        if device is not None:
            return device
        query = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
        unknown = set(query) - {"seed", "echo", "temp", "rate", "config"}
        if unknown:
            raise SetupError(
                f"URL {url!r}: unknown option(s) {sorted(unknown)}; use seed, echo, temp, rate, config"
            )
        try:
            lab = lab_from_config(Path(query["config"]) if "config" in query else None)
            lab.environment.echo_probability = float(query.get("echo", 0.0))
            lab.environment.temperature_c = float(query.get("temp", 20.0))
            device = SimulatedDigitizer(
                lab,
                seed=int(query.get("seed", 0)),
                serial=f"SIM-{name}",
                shot_rate_hz=float(query.get("rate", 0.0)),
            )
        except ValueError as err:
            raise SetupError(f"URL {url!r}: bad option value ({err})") from err
        _registry[name] = device
        return device


install_url_handler()
