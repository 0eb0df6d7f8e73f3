"""Issue 23's must-show: time data written from a simulated acquisition to TDMS and to UFF 58
time records, imported again, give the live path's FRFs (to 1e-6).

A short impact test runs on the simulated devices (the dimacq USB DAQ, and the USB-1808X
units); the accepted records — the samples that entered the live FRFs, before windows — are
kept through the session's ``on_average``, exported by :func:`~dimacq.services.acquisition.time_frf.
time_records` with :func:`~dimacq.io.time_data.write_tdms_time` / ``write_uff_time``, read back
by ``dimacq frf-from-time``'s readers and estimated with the session's windows and estimator.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dimacq.config import load_settings
from dimacq.io.time_data import (
    read_time_data,
    read_uff_time,
    uff_sample_interval,
    write_tdms_time,
    write_uff_time,
)
from dimacq.services.acquisition import rig as rig_builder
from dimacq.services.acquisition.time_frf import frf_from_time, time_records
from dimacq.simulators.lab.scenarios import build_scenario


def _acquire(tmp_path: Path, daq: str) -> tuple[Any, Any, Any, list[list[dict[str, Any]]], float]:
    settings = load_settings(data_dir=tmp_path / daq, token="t", daq=daq)
    setup = build_scenario(settings.scenario).model.setup
    setup = setup.model_copy(update={"excitations": setup.excitations[:2]})
    cfg = {"averages_per_input": 2, "record_samples": 2048, "seed": 4}
    rig = rig_builder.build_rig(settings, setup, cfg)
    kept: list[list[dict[str, Any]]] = [[] for _ in setup.excitations]

    def on_average(j: int, _a: int, ok: bool, _r: Any, blocks: Any) -> None:
        if ok:
            kept[j].append({k: np.array(v, copy=True) for k, v in blocks.items()})

    try:
        live = rig_builder.run_impact_test(
            rig, setup, cfg, on_average=on_average, on_progress=lambda f, m: None
        )
        settings_used = rig_builder.impact_settings(rig, cfg)
        fs = float(rig.daq.sample_rate_hz or 0.0)
    finally:
        rig.close()
    return setup, live, settings_used, kept, fs


@pytest.mark.slow
@pytest.mark.parametrize("daq", ["simulated", "mcc-usb-simulated"])
def test_time_files_give_the_live_frfs(tmp_path: Path, daq: str) -> None:
    setup, live, s, kept, fs = _acquire(tmp_path, daq)
    assert [len(k) for k in kept] == [2, 2]
    records = time_records(setup, kept, fs)
    assert len(records) == 2 * 2 * (1 + 24 + 6)
    write_uff_time(tmp_path / "t.uff", records, text=f"simulated acquisition, daq = {daq}")
    write_tdms_time(tmp_path / "t.tdms", records)
    scale = np.abs(live.H).max(axis=(0, 2))  # per output
    for name in ("t.uff", "t.tdms"):
        got = frf_from_time(
            read_time_data(tmp_path / name),
            setup,
            pretrigger_samples=s.pretrigger_samples,
            force_window_samples=s.force_window_samples,
            exponential_tau_s=s.exponential_tau_s,
            estimator=s.estimator,
        )
        assert got.outputs == live.outputs and got.inputs == live.inputs
        np.testing.assert_allclose(got.frequencies_hz, live.frequencies_hz, rtol=1e-12)
        err = np.abs(got.H - live.H) / scale[None, :, None]
        assert err.max() < 1e-6, (name, err.max())
        assert got.coherence is not None and live.coherence is not None
        np.testing.assert_allclose(got.coherence, live.coherence, atol=1e-6)


def test_uff_header_precision_is_not_taken_for_the_rate(tmp_path: Path) -> None:
    """E13.5 holds 1/2048 s as 4.88281e-04 (2048.001 Hz): read as 2048 Hz exactly; a rate that
    is not a whole number of Hz is left as written."""
    assert 1.0 / uff_sample_interval(4.88281e-04) == 2048.0
    assert uff_sample_interval(1.0 / 2048.3) == pytest.approx(1.0 / 2048.3)
    from dimacq.io.time_data import TimeRecord

    rec = TimeRecord(1, 2, 1, 2, "force", 1.0 / 2048, np.arange(8.0))
    write_uff_time(tmp_path / "r.uff", [rec])
    (back,) = read_uff_time(tmp_path / "r.uff")
    assert back.dt_s == 1.0 / 2048 and np.array_equal(back.data, rec.data)
