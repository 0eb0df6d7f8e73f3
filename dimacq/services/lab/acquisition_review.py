"""The operator's side of a running acquisition: decisions on the hit waiting for review, the
review switch, the last hit's view (:class:`AcquisitionReview`, a part of
:class:`~dimacq.services.lab.acquisitions.AcquisitionService`)."""

from __future__ import annotations

import logging
from typing import Any

from sqlalchemy import select

from dimacq.errors import (
    DeviceStateError,
    SetupError,
)
from dimacq.persistence import models as m
from dimacq.services.acquisition.impact_result import unusable_reasons
from dimacq.services.lab.acquisition_records import AcquisitionInfo, ServiceParts
from dimacq.services.lab.acquisition_views import Decision, LiveReview

log = logging.getLogger("dimacq.services.lab.acquisitions")


class AcquisitionReview(ServiceParts):
    """Methods of :class:`~dimacq.services.lab.acquisitions.AcquisitionService` (its state: see
    there)."""

    def _require_live(self, acq_id: int) -> LiveReview:
        cur = self.get(acq_id)
        if cur is None:
            raise KeyError(acq_id)
        live = self._live.get(acq_id)
        if live is None or cur.state != "running":
            raise DeviceStateError(
                f"acquisition {acq_id} is {cur.state}: only a running acquisition of this stand "
                "takes decisions; start one (review = true to decide every hit)"
            )
        return live

    def decide(
        self, acq_id: int, number: int, decision: Decision, override: bool = False
    ) -> AcquisitionInfo | None:
        """The operator's accept / reject / redo (the input again) of the hit waiting for review.

        A hit the checks rejected (double hit, overload, clock drift) is accepted only with
        ``override`` (it is kept with the checks' reasons and
        :data:`~dimacq.services.acquisition.impact_result.OPERATOR_OVERRIDE`); a hit with samples lost never
        (its record has no data there).

        Raises
        ------
        DeviceStateError
            Not running here, not in review mode, ``number`` is not the hit that waits, or an
            accept the checks refuse (the message names them).
        SetupError
            ``override`` with a decision other than accept.
        """
        if override and decision != "accept":
            raise SetupError(
                f"override: only with decision 'accept' (an accept over the checks), not "
                f"{decision!r}; leave it out"
            )
        try:
            live = self._require_live(acq_id)
        except KeyError:
            return None
        if not live.review:
            raise DeviceStateError(
                f"acquisition {acq_id} is not reviewing its hits: its checks decide each hit; "
                f"switch review on (PATCH /api/acquisitions/{acq_id} with review: true) "
                "to decide them"
            )
        with live.lock:  # one decision per hit: the hit stops waiting as soon as it is given
            pending = live.pending
            if pending is None or pending["number"] != number:
                waiting = "no hit waits" if pending is None else f"hit {pending['number']} waits"
                raise DeviceStateError(
                    f"hit {number} of acquisition {acq_id} is not waiting for a decision "
                    f"({waiting}); decide the hit that waits (pending_review.number)"
                )
            reasons = list(pending["reasons"])
            if decision == "accept" and reasons:
                holes = unusable_reasons(reasons)
                if holes:
                    raise DeviceStateError(
                        f"hit {number} cannot be accepted: the checks found {'; '.join(holes)} "
                        "(the record has no data there, even an override cannot use it); "
                        "reject it or redo the input"
                    )
                if not override:
                    raise DeviceStateError(
                        f"hit {number} failed the checks: {'; '.join(reasons)}; reject it, "
                        "redo the input, or accept it anyway with override: true"
                    )
                decision = "override"
            live.pending = None
            live.answered = number
            live.decisions.put((number, decision))
        return self.get(acq_id)

    def set_review(self, acq_id: int, review: bool) -> AcquisitionInfo | None:
        """Switch "review every hit" of a running acquisition: on, the next hit waits for the
        operator; off, the checks decide from now on, the hit waiting too (None: unknown).

        Raises
        ------
        DeviceStateError
            Not running on this stand.
        """
        try:
            live = self._require_live(acq_id)
        except KeyError:
            return None
        with live.lock:
            live.review = review
        log.info("acquisition %d: review every hit %s", acq_id, "on" if review else "off")
        return self.get(acq_id)

    def hit(self, acq_id: int) -> dict[str, Any] | None:
        """The hit waiting for review, else the last decided one: force and strongest response
        traces and their spectra (see :func:`hit_view`); None when there is none."""
        if self.get(acq_id) is None:
            return None
        live = self._live.get(acq_id)
        if live is None:
            return None
        return live.current_hit()

    def _supersede(self, acq_id: int, input_index: int) -> None:
        """Redo of an input: its averages accepted so far no longer count."""
        from dimacq.services.acquisition.session import OPERATOR_REDO

        chain = self._chain(acq_id)  # a resumed one: the kept averages are redone too

        def mark(s: Any) -> None:
            for a in s.scalars(
                select(m.Average).where(
                    m.Average.acquisition_id.in_(chain),
                    m.Average.input_index == input_index,
                    m.Average.accepted.is_(True),
                )
            ):
                a.accepted, a.reason = False, OPERATOR_REDO
            r = s.get(m.Acquisition, acq_id)
            kept = dict((r.config or {}).get("kept_per_input") or {}) if r is not None else {}
            if r is not None and kept.get(str(input_index)):
                kept[str(input_index)] = 0  # the kept ones were dropped with the rest
                r.config = {**r.config, "kept_per_input": kept}

        self.outbox.flush(self.db)
        if not self.outbox.write(self.db, f"acquisition {acq_id} redo input {input_index}", mark):
            log.warning("redo of input %d kept until the database is back", input_index)
