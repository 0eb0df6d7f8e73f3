"""The block every wire-level driver is built on (template method).

After python-can's ``BusABC.recv`` → ``_recv_internal`` and pymeasure's ``Adapter.write`` →
``_write``: the public methods of a driver own the timeouts, the retries, the logging and the
mapping of transport errors to :mod:`dimacq.errors`; a subclass supplies only the wire steps
(send a frame, receive a frame, one control transfer...) and says how its transport's errors
read (:meth:`WireDriver._wire_error`).

:meth:`WireDriver._exchange` runs one request/answer exchange: it checks that the driver is
open, logs the request, gives the exchange a :class:`Deadline`, turns a transport exception into
the matching :class:`~dimacq.errors.DeviceError`, and retries an exchange that timed out when it
is marked idempotent and the driver has ``retries`` left (0 by default: a timeout surfaces at
once). Closing is idempotent and the driver is a context manager.

A new driver (another DAQ, a CANopen load cell, an injected-fault transport) subclasses this,
implements its wire steps and :meth:`WireDriver._close_transport`, and writes its commands as
``self._exchange("NAME", lambda deadline: ...)``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Self, TypeVar

from dimacq.errors import DeviceError, DeviceStateError, DeviceTimeoutError, SetupError

__all__ = ["Deadline", "WireDriver"]

T = TypeVar("T")


class Deadline:
    """A point in time (``time.monotonic``) by which an exchange must be done."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.at = time.monotonic() + timeout_s

    def left(self) -> float:
        """Seconds left (≤ 0 once passed)."""
        return self.at - time.monotonic()

    @property
    def passed(self) -> bool:
        return self.left() <= 0


class WireDriver:
    """Public behaviour shared by the wire-level drivers; subclasses move the bytes.

    Parameters
    ----------
    name : str
        How messages and logs name the device ("load cell amplifier 3", "DAQ USB 1:4").
    timeout_s : float
        Default time an exchange may take.
    retries : int
        Further attempts of an idempotent exchange that timed out (0: none).
    log : logging.Logger
        The driver module's logger.
    """

    #: what the "closed" error tells the user to do
    reopen_hint = "open it again"

    def __init__(
        self,
        name: str,
        *,
        timeout_s: float,
        retries: int = 0,
        log: logging.Logger | None = None,
    ) -> None:
        if not timeout_s > 0:
            raise SetupError(f"{name}: timeout_s = {timeout_s}; give a positive number of seconds")
        if retries < 0:
            raise SetupError(f"{name}: retries = {retries}; give 0 or more")
        self.name = name
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.log = log if log is not None else logging.getLogger(type(self).__module__)
        self._closed = False

    # -- what a subclass supplies ------------------------------------------------------------
    def _wire_error(self, err: Exception, what: str, deadline: Deadline) -> DeviceError | None:
        """The :class:`DeviceError` a transport exception raised during exchange ``what`` means
        (None: not a transport error, let it through)."""
        return None

    def _close_transport(self) -> None:
        """Release the transport (the driver does not own an injected one: do nothing)."""

    # -- the template ----------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def _require_open(self) -> None:
        if self._closed:
            raise DeviceStateError(f"{self.name} is closed; {self.reopen_hint}")

    def _deadline(self, timeout_s: float | None = None) -> Deadline:
        return Deadline(self.timeout_s if timeout_s is None else timeout_s)

    def _exchange(
        self,
        what: str,
        attempt: Callable[[Deadline], T],
        *,
        timeout_s: float | None = None,
        idempotent: bool = False,
    ) -> T:
        """Run ``attempt(deadline)``: one exchange on the wire, its errors mapped, retried on a
        timeout when ``idempotent`` and :attr:`retries` allow."""
        self._require_open()
        tries = 1 + (self.retries if idempotent else 0)
        for k in range(tries):
            self.log.debug("%s: %s", self.name, what)
            deadline = self._deadline(timeout_s)
            try:
                try:
                    return attempt(deadline)
                except DeviceError:
                    raise
                except Exception as err:
                    mapped = self._wire_error(err, what, deadline)
                    if mapped is None:
                        raise
                    raise mapped from err
            except DeviceTimeoutError as err:
                if k + 1 == tries:
                    raise
                self.log.warning(
                    "%s: %s timed out (%s); retry %d of %d", self.name, what, err, k + 1, tries - 1
                )
        raise AssertionError("unreachable")  # pragma: no cover

    def close(self) -> None:
        """Close (idempotent)."""
        if not self._closed:
            self._closed = True
            self._close_transport()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
