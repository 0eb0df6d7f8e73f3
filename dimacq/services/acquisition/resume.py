"""Resuming an acquisition that ended short: which averages are kept, and what is left to strike.

The lab service (averages registered in its database) and ``dimacq acquire --resume`` (averages
as files of a folder) continue an acquisition by one rule: every struck input starts with its
accepted averages, oldest first, and only the ones it is short of ``averages_per_input`` are
struck (the session's ``prior``: :class:`~dimacq.services.acquisition.session.ImpactSession`).
Rejected averages and averages of inputs not struck now are left out.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class KeptAverages(Generic[R]):
    """The accepted averages kept, per struck input (in the order of ``inputs``, oldest first)."""

    per_input: list[list[R]]

    def missing(self, averages_per_input: int) -> list[int]:
        """Averages still to strike per input: ``max(0, N - kept_k)`` with N ``averages_per_input``."""
        return [max(0, averages_per_input - len(r)) for r in self.per_input]

    def nothing_to_strike(self, averages_per_input: int) -> bool:
        """True when every input has its ``averages_per_input`` accepted averages."""
        return not any(self.missing(averages_per_input))


def kept_averages(
    averages: Iterable[tuple[int, bool, T]], inputs: Sequence[int], load: Callable[[T], R]
) -> KeptAverages[R]:
    """Group the accepted averages of an ended acquisition by struck input.

    Parameters
    ----------
    averages : iterable of (input index, accepted, item)
        Every average decided, oldest first; ``input index`` as in the setup's excitations.
    inputs : sequence of int
        The setup's input indices struck, in their striking order.
    load : callable (item) -> record
        Reads an average kept; called only for the accepted averages of ``inputs``, in order
        (its errors name the average that cannot be read).

    Returns
    -------
    KeptAverages
        ``per_input[k]``: the records of input ``inputs[k]``, oldest first.
    """
    where = {j: k for k, j in enumerate(inputs)}
    kept: list[list[R]] = [[] for _ in inputs]
    for j, accepted, item in averages:
        if accepted and j in where:
            kept[where[j]].append(load(item))
    return KeptAverages(kept)
