"""The simulated digitizer on a real pseudo-terminal (POSIX only).

:class:`PtyServer` opens a pty pair, puts the slave in raw mode and serves a
:class:`SimulatedDigitizer` on the master side. Any serial program can open :attr:`PtyServer.path`
(``python -m serial.tools.miniterm /dev/pts/N 115200``; type ``*IDN?`` and Enter), and so can
:func:`serial.serial_for_url`. Run it with ``python -m dimacq.simulators.digitizer --pty``.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import tty

from dimacq.simulators.digitizer.device import SimulatedDigitizer

__all__ = ["PtyServer"]

log = logging.getLogger(__name__)


class PtyServer:
    """Serve ``device`` on a new pseudo-terminal until :meth:`stop`.

    Use as a context manager (``with PtyServer(dev) as srv: srv.path``) or call :meth:`start` and
    :meth:`stop`. :meth:`stop` closes both ends: a client then sees the port vanish.
    """

    def __init__(self, device: SimulatedDigitizer, poll_s: float = 0.002) -> None:
        self.device = device
        self.poll_s = poll_s
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pending = bytearray()

    def serve_forever(self) -> None:
        """Pump bytes between the pty and the device until :meth:`stop` is called."""
        master = self._master
        while not self._stop.is_set():
            wlist = [master] if self._pending else []
            try:
                readable, writable, _ = select.select([master], wlist, [], self.poll_s)
            except (OSError, ValueError):
                break
            if readable:
                try:
                    data = os.read(master, 4096)
                except BlockingIOError:
                    data = b""
                except OSError:
                    break
                if data:
                    self.device.receive(data)
            if not self.device.plugged:
                continue
            self._pending += self.device.poll()
            if self._pending and (writable or not wlist):
                try:
                    n = os.write(master, bytes(self._pending))
                    del self._pending[:n]
                except BlockingIOError:
                    pass
                except OSError:
                    break

    def start(self) -> PtyServer:
        """Serve in a daemon thread."""
        self._thread = threading.Thread(
            target=self.serve_forever, name=f"pty-digitizer {self.path}", daemon=True
        )
        self._thread.start()
        log.info("simulated digitizer on %s", self.path)
        return self

    def stop(self) -> None:
        """Stop serving and close both ends of the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self._master = self._slave = -1

    def __enter__(self) -> PtyServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
