"""The residual delay of a load cell on its own clock, fitted per input and removed
(:mod:`dimacq.services.data_alignment`): against FRFs of the supports' mass-line model with a
known delay (closed form), the refusal naming the fit, and only the cells that ask for it."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.errors import SetupError
from dimacq.pipeline.stream_alignment import DelayBudget
from dimacq.services.data_alignment import DataAligner, align_rows, run_delay

F = np.arange(0.5, 1024.0, 0.5)


def _cell_frfs(rng: np.random.Generator, n: int) -> np.ndarray:
    """``c_0 + c_1 (ω0/iω) + c_2 (ω0/iω)²`` with random real ``c_n``: a cell's loads per unit
    hammer force above its suspension (the model of the fit)."""
    w, w0 = 2 * np.pi * F, 2 * np.pi * 100.0
    c = rng.standard_normal((3, n)) * np.array([[1e-3], [1e-2], [1e-1]])
    return sum(c[k][None, :] * ((w0 / (1j * w)) ** k)[:, None] for k in range(3))


class _Cell:
    def __init__(self, budget: DelayBudget | None) -> None:
        self.budget = budget

    def delay_budget(self) -> DelayBudget | None:
        return self.budget


BUDGET = DelayBudget(search_s=2e-3, lo_hz=20.0, band_hz=655.36, max_phase_deg=2.0, label="cell")


def test_the_delay_is_fitted_and_removed_on_every_line() -> None:
    rng = np.random.default_rng(3)
    H0 = _cell_frfs(rng, 6)
    tau = 437.5e-6
    got, fit, phase = align_rows(
        F, H0 * np.exp(-2j * np.pi * F * tau)[:, None], np.full(H0.shape, 0.99), BUDGET, "input 1"
    )
    assert fit.delay_s == pytest.approx(tau, abs=1e-8)
    assert phase < 1e-2
    # below the fit's band too: within 2π f × 10 ns
    np.testing.assert_allclose(got, H0, rtol=1e-4)


def _input(rng: np.random.Generator, tau: float, noise: float = 0.0) -> tuple:
    """One input's FRFs: 3 responses (any complex FRFs), a cell on its own clock delayed by
    ``tau`` (loads real combinations of the responses and a constant, plus ``noise`` × their
    size), a cell on the DAQ's clock; the coherence that noise leaves."""
    acc = rng.standard_normal((F.size, 3)) + 1j * rng.standard_normal((F.size, 3))
    cells = [acc @ rng.standard_normal((3, 6)) + rng.standard_normal(6) for _ in range(2)]
    e = rng.standard_normal((F.size, 6)) + 1j * rng.standard_normal((F.size, 6))
    own = (cells[0] + noise * np.abs(cells[0]) * e) * np.exp(-2j * np.pi * F * tau)[:, None]
    H = np.concatenate([acc, own, cells[1]], axis=1)
    coh = np.full(H.shape, 0.95)
    coh[:, 3:9] = 1 / (1 + noise**2) if noise else 0.95
    return H, coh, acc, cells


def test_only_the_cells_that_ask_are_aligned_in_place_against_the_responses() -> None:
    """Equation (1): the first cell delayed 300 µs and aligned against the responses, the
    second (on the DAQ's clock) left alone, the responses untouched."""
    rng = np.random.default_rng(4)
    H, coh, acc, cells = _input(rng, 3e-4)
    aligner = DataAligner([_Cell(BUDGET), _Cell(None)], [6, 6], 3)
    msgs = aligner.align(0, F, H, coh, "input 7")
    assert len(msgs) == 1 and "input 7: residual delay +300.0 us" in msgs[0]
    np.testing.assert_allclose(H[:, 3:9], cells[0], rtol=1e-4)
    assert np.array_equal(H[:, :3], acc) and np.array_equal(H[:, 9:], cells[1])
    assert aligner.finish(F, H[:, :, None]) == []  # nothing waited


def test_an_input_too_weak_for_its_own_fit_takes_the_runs_delay() -> None:
    """Inputs 0, 1 meet the budget on their own (delays 300 and 302 µs); input 2's cell loads
    are lost in noise: it waits, and at the end takes the inverse-variance mean (~301 µs), its
    uncertainty the inputs' wander beyond their fits' errors (noise-free fits: 2 µs apart, an
    ω of √2 µs, 0.41° at 655 Hz with the mean's error)."""
    rng = np.random.default_rng(8)
    H_all = np.zeros((F.size, 15, 3), dtype=complex)
    aligner = DataAligner([_Cell(BUDGET), _Cell(None)], [6, 6], 3)
    truth = []
    for j, (tau, noise) in enumerate([(300e-6, 0.0), (302e-6, 0.0), (301e-6, 3.0)]):
        H, coh, _, cells = _input(rng, tau, noise)
        msgs = aligner.align(j, F, H, coh, f"input {j}")
        assert ("takes the run's delay" in msgs[0]) == (j == 2)
        H_all[:, :, j] = H
        truth.append(cells[0])
    before = H_all[:, 3:9, 2].copy()
    (msg,) = aligner.finish(F, H_all)
    assert "input 2: the run's delay +301.0 us (from 2 inputs, wander 1.4 us" in msg
    np.testing.assert_allclose(H_all[:, 3:9, 2], before * np.exp(2j * np.pi * F * 301e-6)[:, None])
    # a wander the budget does not allow: refused, naming the waiting input
    aligner = DataAligner([_Cell(BUDGET)], [6], 3)
    for j, (tau, noise) in enumerate([(300e-6, 0.0), (340e-6, 0.0), (301e-6, 3.0)]):
        H, coh, _, _ = _input(rng, tau, noise)
        aligner.align(j, F, H[:, :9], coh[:, :9], f"input {j}")
    with pytest.raises(SetupError, match=r"input 2: the data align .*the run's delay and its"):
        aligner.finish(F, H_all[:, :9])
    # no input met it on its own
    aligner = DataAligner([_Cell(BUDGET)], [6], 3)
    H, coh, _, _ = _input(rng, 300e-6, 3.0)
    aligner.align(0, F, H[:, :9], coh[:, :9], "input 0")
    with pytest.raises(SetupError, match="no input's own fit met the budget"):
        aligner.finish(F, H_all[:, :9, :1])


def test_refused_when_the_data_cannot_support_the_budget() -> None:
    rng = np.random.default_rng(5)
    H0 = _cell_frfs(rng, 6)
    noisy = H0 * np.exp(-2j * np.pi * F * 2e-4)[:, None] + 0.7 * np.abs(H0) * (
        rng.standard_normal(H0.shape) + 1j * rng.standard_normal(H0.shape)
    )
    coh = np.full(H0.shape, 0.5)  # what such noise leaves of the coherence
    with pytest.raises(SetupError, match=r"input 2: the data align its loads .*limit netft_max"):
        align_rows(F, noisy, coh, BUDGET, "input 2")
    # the same data within a budget its fit meets
    loose = DelayBudget(2e-3, 20.0, 655.36, 120.0, "cell")
    _, fit, phase = align_rows(F, noisy, coh, loose, "input 2")
    assert abs(fit.delay_s - 2e-4) < 4 * fit.uncertainty_s and phase <= 120.0
    with pytest.raises(SetupError, match=r"no delay fit from the data .* netft_fit_lo_hz"):
        align_rows(F, H0, coh, DelayBudget(2e-3, 700.0, 655.36, 2.0, "cell"), "input 3")


def test_the_runs_wander_is_what_the_fits_own_errors_do_not_explain() -> None:
    """Fits ``τ_i = τ̄ + w_i + e_i`` drawn with known spreads: the wander ``ω`` of the ``w_i`` is
    recovered, not the scatter of the ``τ_i`` (which holds the fits' errors ``σ_i`` too), and is
    ~0 when the inputs differ by their fits' errors alone."""
    rng = np.random.default_rng(3)
    k = 400
    sigma = rng.uniform(2e-6, 6e-6, k)
    for omega in (0.0, 5e-6):
        tau = 20e-6 + omega * rng.standard_normal(k) + sigma * rng.standard_normal(k)
        mean, sem, wander = run_delay(tau, sigma)
        assert wander == pytest.approx(omega, abs=1e-6)
        assert abs(mean - 20e-6) < 4 * sem
        # the scatter of the fits, the old measure, is well above the wander
        assert np.std(tau) > wander + 1e-6
    # one fit: nothing to tell a wander from
    assert run_delay(np.array([1e-6]), np.array([2e-6])) == pytest.approx((1e-6, 2e-6, 0.0))
