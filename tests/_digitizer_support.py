"""Shared helpers of the sonic digitizer tests: scripted transport, simulator fixtures, leak check."""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Iterator, Sequence

from _exchange import expected_exchange

import dimacq.simulators.digitizer as simdig
from dimacq.drivers.digitizer import SerialDigitizer
from dimacq.simulators.digitizer.device import SimulatedDigitizer, lab_from_config
from dimacq.simulators.digitizer.pty import PtyServer

# Deterministic exchanges (sent, answered) shared by the scripted-transport test and the pty test.
# The answers are literal bytes: NMEA XOR checksums, the device serial is "SIM-T".
SCRIPT: list[tuple[bytes, bytes]] = [
    (b"*IDN?\r", b"$IDN,DIMACQ,SD-3-SIM,SIM-T,1.0,4*3A\r\n"),
    (b"RST\r", b"$OK,RST*7D\r\n"),
    (b"CFG?\r", b"$CFG,2,4,1,4,10000000,500*75\r\n"),
    (b"CFG A=3,B=2\r", b"$CFG,2,4,3,2,10000000,500*71\r\n"),
    (b"BOGUS\r", b"$ERR,1,unknown command BOGUS*37\r\n"),
    (b"SIM:ECHOES?\r", b"$SIM,ECHOES,0*70\r\n"),
    (b"RST\r", b"$OK,RST*7D\r\n"),
]


@contextlib.contextmanager
def expected_protocol(
    pairs: Sequence[tuple[bytes, bytes | None]], timeout_s: float = 0.05, **kw: object
) -> Iterator[SerialDigitizer]:
    """A driver on a scripted serial port (:func:`_exchange.expected_exchange`); leftover pairs
    or answers left unread, on the port or in the driver's line buffer, fail the test."""
    with expected_exchange(
        "serial",
        pairs,
        connect=lambda port: SerialDigitizer(port, timeout_s=timeout_s, name="scripted"),
        **kw,
    ) as driver:
        yield driver
        assert not driver._buf, f"answers left unread: {bytes(driver._buf)!r}"
    driver.close()


_names = itertools.count()


def make_device(seed: int = 0, **env: float) -> SimulatedDigitizer:
    lab = lab_from_config()
    for k, v in env.items():
        setattr(lab.environment, k, v)
    return SimulatedDigitizer(lab, seed=seed, serial="SIM-T")


@contextlib.contextmanager
def url_backend(device: SimulatedDigitizer) -> Iterator[tuple[str, SerialDigitizer]]:
    name = f"t{next(_names)}"
    simdig.register_device(name, device)
    url = f"simdigitizer://{name}"
    driver = SerialDigitizer.from_url(url, timeout_s=1.0)
    try:
        yield url, driver
    finally:
        driver.close()
        simdig.unregister_device(name)


@contextlib.contextmanager
def pty_backend(device: SimulatedDigitizer) -> Iterator[tuple[PtyServer, SerialDigitizer]]:
    server = PtyServer(device).start()
    driver = None
    try:
        driver = SerialDigitizer.from_url(server.path, timeout_s=1.0)
        yield server, driver
    finally:
        if driver is not None:
            driver.close()
        server.stop()
