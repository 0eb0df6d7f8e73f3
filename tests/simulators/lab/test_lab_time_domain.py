"""Time data of the virtual lab against its frequency-domain model.

With one strike and an exponential window ``e^{−t/τ}`` on force and responses that has decayed
by the record's end, the DFT ratio equals the model at ``s = iω + 1/τ`` exactly (no leakage):
:meth:`ForwardModel.transfer` is the independent reference.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dimacq.simulators.lab.impact import impact_test, virtual_lab
from dimacq.simulators.lab.scenarios import LoadCellSpec, build_scenario
from dimacq.simulators.lab.source import SampleSource


@pytest.mark.parametrize(
    ("name", "gauges"),
    [
        ("calibration-mass-bungee", "piezo"),
        ("calibration-mass-bungee", "strain-gauge"),
        ("x38", "piezo"),
    ],
)
def test_windowed_single_strike_equals_the_model_at_shifted_s(name: str, gauges: str) -> None:
    b = build_scenario(name)
    # strain-gauge bridges without nonlinearity: linear about their static level, which the
    # samples before the strike give exactly (noise-free, no temperature ramp)
    spec = b.spec.model_copy(
        update={"loadcell": LoadCellSpec(kind=gauges, nonlinearity_pct_fs=0.0)}  # type: ignore[arg-type]
    )
    b = replace(b, spec=spec)
    lab = virtual_lab(b, noise_scale=0.0)
    assert isinstance(lab, SampleSource)
    fs = lab.sample_rate_hz
    N, at, tau = 2**14 if name != "x38" else 2**13, 50, (0.2 if name != "x38" else 1.5)
    lab.excite(3, at)
    ch = np.arange(len(lab.channel_names))
    rec = lab.read(ch, 0, N)
    assert np.array_equal(rec, lab.read(ch, 0, N))  # reading twice gives the same world
    dc = np.array([u == "mV/V" for u in lab.channel_units])
    assert dc.any() == (gauges == "strain-gauge")
    if dc.any():
        rec[dc] -= rec[dc, :1]
        assert np.abs(rec[dc, :at]).max() < 1e-12
    w = np.exp(-np.clip((np.arange(N) - at) / fs, 0, None) / tau)
    F = np.fft.rfft(rec[lab.channel_index("hammer")] * w)
    Y = np.fft.rfft(rec * w, axis=1)
    f = np.arange(N // 2 + 1) * fs / N
    sel = (f > 0) & (f < 0.25 * fs)
    ref = b.model.transfer(2j * np.pi * f[sel] + 1 / tau)[:, :, 3]  # (L, n_out)
    n_acc = len(b.setup.responses)
    acc = (Y[:n_acc, sel] / F[sel]).T
    assert np.abs(acc - ref[:, :n_acc]).max() < 1e-8 * np.abs(ref[:, :n_acc]).max()
    for c, lc in enumerate(b.setup.load_cells):
        g0 = lab.channel_index(f"LC{lc.node} g01")
        loads = np.linalg.pinv(lab.gauge_matrix(lc.node)) @ (Y[g0 : g0 + 12, sel] / F[sel])
        r = ref[:, n_acc + 6 * c : n_acc + 6 * c + 6].T
        assert np.abs(loads - r).max() < 1e-8 * np.abs(r).max()


def test_impact_test_on_the_free_cube_returns_the_mass_line() -> None:
    b = build_scenario("cube-2")
    run = impact_test(b, noise_scale=0.0, averages=2)
    frf = run.frf
    ref = b.model.transfer(2j * np.pi * frf.frequencies_hz)
    assert np.abs(frf.H - ref).max() < 1e-9 * np.abs(ref).max()
    assert frf.coherence is not None and frf.coherence.min() > 0.999999
    assert run.n_strikes == 2 * len(b.setup.excitations)


def test_impact_test_with_noise_agrees_with_the_model_where_coherent() -> None:
    b = build_scenario("calibration-mass-ground")
    run = impact_test(b, averages=3, settle_samples=4096)
    frf = run.frf
    s = 2j * np.pi * frf.frequencies_hz + 1 / run.exponential_tau_s
    ref = b.model.transfer(s)
    band = (frf.frequencies_hz >= 10) & (frf.frequencies_hz <= 60)
    n_acc = len(b.setup.responses)
    h, r = frf.H[band, :n_acc], ref[band, :n_acc]
    level = np.sqrt(np.mean(np.abs(r) ** 2, axis=0, keepdims=True))  # each FRF's rms level
    coherent = frf.coherence[band, :n_acc] > 0.99
    assert coherent.mean() > 0.9
    assert np.abs(h - r)[coherent].max() < 0.01 * level.max()
    assert np.median((np.abs(h - r) / level)[coherent]) < 5e-3


def test_skipping_unread_blocks_gives_the_same_samples_as_reading_them() -> None:
    b = build_scenario("calibration-mass-bungee")
    labs = [virtual_lab(b), virtual_lab(b)]
    ch = np.arange(len(labs[0].channel_names))
    strikes = [(0, 512), (5, 40_960), (7, 90_112)]  # block boundaries (512-sample blocks)
    records = []
    for k, lab in enumerate(labs):
        got = []
        for j, at in strikes:
            if k == 0:  # read every sample up to the strike
                lab.read(ch, 0, at)
            lab.excite(j, at)
            got.append(lab.read(ch, at - 10, 2048))
        records.append(np.array(got))
    assert np.array_equal(records[0], records[1]) or np.allclose(
        records[0], records[1], rtol=0, atol=1e-12 * np.abs(records[0]).max()
    )
    assert np.abs(records[0][1]).max() > 0
