"""``dimacq demo``'s parts (:mod:`dimacq.cli.demo_steps`): what its acquisitions ask for (the
demo's cut and ``--full``), the host lag of step 0's process added to the test's, and an error
of step 0 raised in the demo as the same error class (exit 2, the reason named)."""

from __future__ import annotations

import argparse
import secrets
from pathlib import Path

import pytest

from dimacq.backends.time_lapse import HostLag
from dimacq.cli.demo_steps import QUICK, QUICK_CHAIN, ChainCheck, acquisition_plan
from dimacq.cli.main import build_parser
from dimacq.errors import DimacqError


def _args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["demo", *argv])


def test_the_demo_asks_less_than_the_rig_file_and_full_asks_the_rig_files() -> None:
    assert acquisition_plan(_args()) == QUICK == {"averages_per_input": 3, "record_samples": 2048}
    chain = acquisition_plan(_args(), chain=True)
    assert chain == QUICK_CHAIN and chain["min_averages"] == 2 == chain["averages_per_input"]
    # --full: nothing asked, the rig file's [acquisition] (5 averages of 4096 samples) applies
    assert acquisition_plan(_args("--full")) == {}
    assert acquisition_plan(_args("--full"), chain=True) == {}
    # the flags win over both; fewer averages than the chain check's least lowers that least
    got = acquisition_plan(_args("--averages", "1", "--record-samples", "4096"), chain=True)
    assert got == {"averages_per_input": 1, "min_averages": 1, "record_samples": 4096}
    assert acquisition_plan(_args("--full", "--averages", "7")) == {"averages_per_input": 7}
    assert acquisition_plan(_args("--averages", "4"), chain=True)["min_averages"] == 2


def test_host_lag_of_another_process_is_added() -> None:
    here, there = HostLag(), HostLag()
    here.observe({"device": "loadcell0", "kind": "gap", "n_samples": 1})
    assert here.kept_up
    there.observe({"device": "daq", "kind": "overflow", "n_samples": 256})
    there.observe({"device": "loadcell0", "kind": "gap", "n_samples": 40})
    here.merge(there)
    assert not here.kept_up and (here.overflow_events, here.overflow_samples) == (1, 256)
    assert here.loadcell_gaps == [1, 40]


@pytest.mark.slow
def test_an_error_of_step_0_is_raised_in_the_demo_with_its_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Step 0 runs in a child process; a load cell backend the table does not know stops it
    (the child inherits the environment), and :meth:`ChainCheck.result` raises the child's
    error class with its message (the demo then exits 2 naming it)."""
    monkeypatch.setenv("DIMACQ_LOADCELL", "no-such-cell")
    lines: list[str] = []
    check = ChainCheck(tmp_path, secrets.token_urlsafe(8), _args(), None, lines.append)
    try:
        with pytest.raises(DimacqError, match="no-such-cell") as err:
            check.acquired(HostLag(), [])  # it never acquires: its error, not a hang
    finally:
        check.close()
    assert type(err.value) is not DimacqError  # the child's own class, not the base
    assert "DIMACQ_LOADCELL" in str(err.value)
    assert any(line.startswith("[0/5] chain calibration") for line in lines)
