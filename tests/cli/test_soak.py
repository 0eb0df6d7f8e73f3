"""The soak with faults, short: ``dimacq serve`` as its own process on the simulated lab with
every fault turned up and injected at random (``tests/scripts/soak.py``, 30 minutes on demand)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "soak.py"


def _soak_module():
    spec = importlib.util.spec_from_file_location("dimacq_soak", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_short_soak_loses_nothing_reports_every_fault_and_keeps_answering(tmp_path: Path) -> None:
    soak = _soak_module()
    fig = soak.run_soak(
        0.3, seed=3, n_inputs=1, averages=3, workdir=tmp_path, say=lambda m: None, min_succeeded=1
    )
    assert not fig.errors, fig.errors
    # an acquisition may end refused as incomplete (a starved machine: the faults rejected more
    # averages than its strikes allow; the reasons are in it, nothing is lost), never failed
    assert not fig.acquisitions_failed, fig.acquisitions_failed
    succeeded = fig.acquisitions - len(fig.acquisitions_incomplete)
    assert succeeded >= 1 and fig.averages_accepted >= 3 * succeeded, fig
    assert fig.points_accepted >= 4 and fig.points_lost == 0 and fig.averages_lost == 0
    assert fig.http_500 == 0 and fig.status_calls > 50
    assert sum(fig.injected.values()) >= 3, fig.injected
    for kind, n in fig.injected.items():  # every fault injected is reported
        assert fig.reported.get(kind, 0) >= n, (kind, fig.injected, fig.reported)
