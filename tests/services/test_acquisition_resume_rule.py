"""The one resume rule (:func:`dimacq.services.lab.acquisition_recovery.kept_averages`): what is kept, what is next."""

from __future__ import annotations

from dimacq.services.lab.acquisition_recovery import kept_averages


def test_accepted_averages_of_struck_inputs_are_kept_in_order_and_the_rest_is_missing() -> None:
    # input 4 is not struck now; input 2's second average was rejected
    decided = [(2, True, "a"), (0, True, "b"), (2, False, "c"), (4, True, "d"), (2, True, "e")]
    loaded: list[str] = []

    def load(item: str) -> str:
        loaded.append(item)
        return item.upper()

    kept = kept_averages(decided, [2, 0, 7], load)
    assert kept.per_input == [["A", "E"], ["B"], []]
    assert loaded == ["a", "b", "e"]  # only what is kept is read, oldest first
    assert kept.missing(3) == [1, 2, 3]
    assert kept.missing(1) == [0, 0, 1]
    assert not kept.nothing_to_strike(1)
    assert kept_averages(decided[:2], [2, 0], load).nothing_to_strike(1)
    assert kept.missing(0) == [0, 0, 0]
