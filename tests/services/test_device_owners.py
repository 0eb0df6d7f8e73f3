"""One owner per device (issue 24): the claim is atomic under contention."""

from __future__ import annotations

import threading

import pytest

from dimacq.errors import DeviceStateError
from dimacq.services.lab.ownership import DeviceOwners


def test_of_many_threads_claiming_together_exactly_one_wins_each_round() -> None:
    owners = DeviceOwners()
    for _round in range(50):
        go = threading.Barrier(8)
        won: list[object] = []
        refused: list[str] = []

        def claim(
            k: int,
            go: threading.Barrier = go,
            won: list[object] = won,
            refused: list[str] = refused,
        ) -> None:
            go.wait()
            try:
                won.append(owners.claim(("daq", "loadcell"), f"job {k}"))
            except DeviceStateError as err:
                refused.append(str(err))

        threads = [threading.Thread(target=claim, args=(k,)) for k in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(won) == 1 and len(refused) == 7
        assert all("daq is in use by job" in r for r in refused)
        owners.release(won[0])  # type: ignore[arg-type]
        assert owners.owners() == {}


def test_a_claim_takes_all_its_devices_or_none() -> None:
    owners = DeviceOwners()
    cell = owners.claim(("loadcell",), "a calibration run")
    with pytest.raises(DeviceStateError, match="loadcell is in use by a calibration run"):
        owners.claim(("daq", "loadcell"), "an acquisition")
    assert owners.owners() == {"loadcell": "a calibration run"}  # the DAQ was not taken
    owners.rename(cell, "calibration run 7")
    with owners.hold(("daq",), "a connect of daq"):
        assert owners.owners() == {"loadcell": "calibration run 7", "daq": "a connect of daq"}
    owners.release(cell)
    owners.release(cell)  # idempotent
    assert owners.owners() == {}
