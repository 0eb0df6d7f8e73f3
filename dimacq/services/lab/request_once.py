"""One job per request: a second identical request while the first runs is refused, and a
request repeated with the same idempotency key gets the first one's result.

A double-click, or a client that sends again when an answer is slow, must not store the same
result twice. :class:`RequestOnce` keeps, under a lock, the requests now running (by a canonical
text of the request) and, for the last :data:`REMEMBERED_KEYS` idempotency keys, the request each
came with and the id of its stored result.

- An identical request while one runs: :class:`~dimacq.errors.DeviceStateError` (HTTP 409)
  naming the running one (its number, when it started).
- A key sent again with the same request after it ended: the caller returns the stored result
  (``Slot.replay``), nothing is computed again.
- A key sent again with another request: :class:`~dimacq.errors.SetupError` (HTTP 422).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime

from dimacq.errors import DeviceStateError, SetupError

__all__ = ["REMEMBERED_KEYS", "RequestOnce", "Slot"]

#: Idempotency keys remembered (the most recent ones): a retry comes seconds after its request.
REMEMBERED_KEYS = 256


@dataclass
class _Running:
    number: int
    started: float  # time.monotonic()
    started_at: datetime


@dataclass
class Slot:
    """A running request's place: ``replay`` is the id of the result a repeated idempotency
    key already stored (None: compute it); :meth:`done` records the stored result's id."""

    number: int
    replay: int | None = None
    result_id: int | None = None

    def done(self, result_id: int) -> None:
        self.result_id = result_id


class RequestOnce:
    """The running requests of one kind of job and the idempotency keys they came with."""

    def __init__(self, job: str, remember: int = REMEMBERED_KEYS) -> None:
        self.job = job
        self._lock = threading.Lock()
        self._running: dict[str, _Running] = {}
        self._keys: OrderedDict[str, tuple[str, int]] = OrderedDict()
        self._remember = remember
        self._count = 0

    @contextmanager
    def once(self, request: str, key: str | None, what: str, wait_hint: str) -> Iterator[Slot]:
        """Hold ``request`` (canonical text) as running for the ``with`` block.

        Parameters
        ----------
        request : str
            The request as canonical text (identical requests, identical text).
        key : str, optional
            The client's idempotency key.
        what : str
            The request in the user's words ("a solve of FRF set 3 with the same options").
        wait_hint : str
            What to do instead of sending again ("its solution is listed at ...").

        Raises
        ------
        DeviceStateError
            An identical request is running.
        SetupError
            ``key`` came before with another request.
        """
        with self._lock:
            replay = None
            if key is not None and key in self._keys:
                first, result_id = self._keys[key]
                if first != request:
                    raise SetupError(
                        f"Idempotency-Key {key!r} came with another {self.job} request; send a "
                        "new key with each new request"
                    )
                replay = result_id
            run = self._running.get(request)
            if run is not None:
                ago = time.monotonic() - run.started
                raise DeviceStateError(
                    f"{what} is running already ({self.job} {run.number}, started "
                    f"{run.started_at:%H:%M:%S} UTC, {ago:.0f} s ago); {wait_hint}"
                )
            self._count += 1
            slot = Slot(self._count, replay)
            self._running[request] = _Running(slot.number, time.monotonic(), datetime.now(UTC))
        try:
            yield slot
        finally:
            with self._lock:
                del self._running[request]
                if key is not None and slot.result_id is not None:
                    self._keys[key] = (request, slot.result_id)
                    self._keys.move_to_end(key)
                    while len(self._keys) > self._remember:
                        self._keys.popitem(last=False)
