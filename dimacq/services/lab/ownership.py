"""One owner per device: which job holds the DAQ, the load cells and the digitizer.

An acquisition, a load cell calibration run and a connect/identify each *claim* the devices
they use before they touch them; a claim of a device someone holds raises
:class:`~dimacq.errors.DeviceStateError` (HTTP 409) naming the holder. The check and the claim
are one step under one lock, so of three acquisition requests sent together one starts and two
are refused, whatever the timing. A claim is released by whoever took it, when its work ends
(the job's last step, or the request that failed before its job started).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

from dimacq.errors import DeviceStateError

__all__ = ["Claim", "DeviceOwners"]


@dataclass(eq=False)
class Claim:
    """Devices held by one owner (``owner`` says who, for the refusals of the others)."""

    devices: tuple[str, ...]
    owner: str
    released: bool = field(default=False)


class DeviceOwners:
    """The devices' owners (thread-safe; in memory: a stand's devices are its own)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._held: dict[str, Claim] = {}

    def claim(self, devices: Sequence[str], owner: str) -> Claim:
        """Hold every device of ``devices`` for ``owner``, or none of them.

        Raises
        ------
        DeviceStateError
            A device is held: the message names it and its owner.
        """
        names = tuple(dict.fromkeys(devices))
        with self._lock:
            busy = [(n, self._held[n]) for n in names if n in self._held]
            if busy:
                what = "; ".join(f"{n} is in use by {c.owner}" for n, c in busy)
                raise DeviceStateError(f"{what}: wait for it to end or cancel it, then ask again")
            c = Claim(names, owner)
            for n in names:
                self._held[n] = c
            return c

    def rename(self, claim: Claim, owner: str) -> None:
        """Name the owner better once it is known (the job id of a started acquisition)."""
        with self._lock:
            claim.owner = owner

    def release(self, claim: Claim) -> None:
        """Give the claim's devices back (idempotent)."""
        with self._lock:
            if claim.released:
                return
            claim.released = True
            for n in claim.devices:
                if self._held.get(n) is claim:
                    del self._held[n]

    @contextmanager
    def hold(self, devices: Sequence[str], owner: str) -> Iterator[Claim]:
        """Claim for the length of a ``with`` block (connect, identify)."""
        c = self.claim(devices, owner)
        try:
            yield c
        finally:
            self.release(c)

    def owners(self) -> dict[str, str]:
        """Device → owner, now."""
        with self._lock:
            return {n: c.owner for n, c in self._held.items()}
