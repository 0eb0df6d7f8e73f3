"""The residual delay of a load cell on its own clock, fitted per input and removed
(:mod:`dimacq.services.acquisition.data_alignment`): against FRFs of the supports' mass-line model with a
known delay (closed form), the refusal naming the fit, and only the cells that ask for it."""

from __future__ import annotations

import re

import numpy as np
import pytest

from dimacq.errors import SetupError
from dimacq.pipeline.stream_alignment import DelayBudget
from dimacq.services.acquisition import data_alignment
from dimacq.services.acquisition.data_alignment import DataAligner, align_rows, force_share

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
    """Equation (1): the first cell delayed 300 µs and aligned against the responses at the
    end of the run (one input: its own fit), the second (on the DAQ's clock) left alone, the
    responses untouched."""
    rng = np.random.default_rng(4)
    H, coh, acc, cells = _input(rng, 3e-4)
    aligner = DataAligner([_Cell(BUDGET), _Cell(None)], [6, 6], 3)
    msgs = aligner.align(0, F, H, coh, "input 7")
    assert len(msgs) == 1 and "input 7: own delay fit +300.0 us" in msgs[0]
    assert np.array_equal(H[:, 3:9], _input(np.random.default_rng(4), 3e-4)[0][:, 3:9])
    (msg,) = aligner.finish(F, H[:, :, None], coh[:, :, None])
    assert "input 7: each input's own delay fit removed" in msg
    np.testing.assert_allclose(H[:, 3:9], cells[0], rtol=1e-4)
    assert np.array_equal(H[:, :3], acc) and np.array_equal(H[:, 9:], cells[1])


class _Wandering(_Cell):
    """A cell that says how far its alignment was off at each input's records (s)."""

    def __init__(self, budget: DelayBudget, offsets: list[float]) -> None:
        super().__init__(budget)
        self.offsets = offsets
        self.asked: list[list[tuple[int, int]]] = []

    def alignment_offsets_s(self, records: list[list[tuple[int, int]]]) -> np.ndarray:
        self.asked = records
        return np.array(self.offsets)


def _run(
    rng: np.random.Generator, cell: _Cell, taus: list[float], noises: list[float]
) -> tuple[DataAligner, np.ndarray, np.ndarray, list[str], list[np.ndarray]]:
    aligner = DataAligner([cell], [6], 3)
    H_all = np.zeros((F.size, 9, len(taus)), dtype=complex)
    coh_all = np.zeros(H_all.shape)
    msgs, truth = [], []
    for j, (tau, noise) in enumerate(zip(taus, noises, strict=True)):
        H, coh, _, cells = _input(rng, tau, noise)
        msgs += aligner.align(j, F, H[:, :9], coh[:, :9], f"input {j}", [(1000 * j, 512)])
        H_all[:, :, j], coh_all[:, :, j] = H[:, :9], coh[:, :9]
        truth.append(cells[0])
    return aligner, H_all, coh_all, msgs, truth


def test_every_input_takes_the_runs_delay_fitted_on_all_of_them_at_once() -> None:
    """Six inputs with one delay (300 µs) but for the offsets the cell knows its alignment had
    at their records (−20 .. +30 µs), two of them too weak for their own fit: the joint fit
    recovers the delay (at the offsets' mean) within its stated uncertainty, every input is
    aligned by it and its own offset, and the run's halves agree (no drift)."""
    rng = np.random.default_rng(8)
    offsets = [10e-6, -20e-6, 30e-6, 0.0, -5e-6, 3e-6]
    cell = _Wandering(BUDGET, offsets)
    taus, noises = [300e-6 + o for o in offsets], [0.05, 0.05, 3.0, 0.05, 3.0, 0.05]
    aligner, H_all, coh_all, msgs, _ = _run(rng, cell, taus, noises)
    assert [("takes the run's delay" in m) for m in msgs] == [
        False,
        False,
        True,
        False,
        True,
        False,
    ]
    before = H_all.copy()
    (msg,) = aligner.finish(F, H_all, coh_all)
    assert cell.asked == [[(1000 * j, 512)] for j in range(6)]
    got = float(msg.split("the run's delay ")[1].split(" us")[0]) * 1e-6
    u = float(msg.split("within ")[1].split(" us")[0]) * 1e-6
    drift = float(msg.split("between the run's halves ")[1].split(" us")[0]) * 1e-6
    assert "fitted on 6 inputs at once" in msg and drift < 1e-6
    assert "offset at its records (-23.0 .. +27.0 us" in msg
    assert u < 2e-6 and abs(got - 303e-6) < max(u, 0.2e-6)
    # every input's cell rows multiplied by the one delay and its offset, nothing else touched
    turn = np.exp(2j * np.pi * F[:, None, None] * (got + np.array(offsets) - 3e-6))
    np.testing.assert_allclose(H_all[:, 3:9], before[:, 3:9] * turn, rtol=1e-3)
    assert np.array_equal(H_all[:, :3], before[:, :3])
    # offsets the data do not carry (every input truly at 300 µs): the fit without them is
    # the better one, and every input takes the one delay
    cell = _Wandering(BUDGET, offsets)
    aligner, H_all, coh_all, _, _ = _run(rng, cell, [300e-6] * 6, noises)
    (msg,) = aligner.finish(F, H_all, coh_all)
    assert "fit the data worse" in msg
    got = float(msg.split("the run's delay ")[1].split(" us")[0]) * 1e-6
    assert abs(got - 300e-6) < 0.5e-6


@pytest.fixture
def carrying(monkeypatch: pytest.MonkeyPatch) -> None:
    """The cell carries the article (its share of the force balance 1: the budget applies to
    its own phase, :func:`force_share`)."""
    monkeypatch.setattr(data_alignment, "force_share", lambda *a: 1.0)


def test_inputs_whose_delays_truly_differ_are_refused(carrying: None) -> None:
    """Delays 40 µs apart (10° at 655 Hz): the jackknife over inputs says so, the run's delay
    does not meet the budget; the inputs strong enough keep their own fits, and the run is
    refused when one is too weak for its own — naming it; so too with a drift over the run."""
    rng = np.random.default_rng(9)
    taus = [280e-6, 320e-6, 280e-6, 320e-6]
    aligner, H_all, coh_all, _, truth = _run(rng, _Cell(BUDGET), taus, [0.02] * 4)
    (msg,) = aligner.finish(F, H_all, coh_all)
    assert "each input's own delay fit removed (the run's delay" in msg
    np.testing.assert_allclose(
        H_all[:, 3:9, 1], truth[1], rtol=0.2, atol=0.2 * np.abs(truth[1]).max()
    )
    aligner, H_all, coh_all, _, _ = _run(rng, _Cell(BUDGET), taus + [300e-6], [0.02] * 4 + [3.0])
    with pytest.raises(
        SetupError,
        match=r"input 4: the data align .*the run.s delay .* fitted on 5 inputs at once: jackknife",
    ):
        aligner.finish(F, H_all, coh_all)
    # a drift over the run (285 .. 315 µs): the halves' delays are 15 µs apart, the inputs
    # ~9 µs from the run's mean, beyond the budget
    taus = list(np.linspace(285e-6, 315e-6, 6))
    aligner, H_all, coh_all, _, _ = _run(rng, _Cell(BUDGET), taus, [0.02] * 5 + [3.0])
    with pytest.raises(SetupError, match=r"input 5: .*drift between the run's halves (8|9)\."):
        aligner.finish(F, H_all, coh_all)
    # one input, too weak for its own fit: nothing to pool
    aligner, H_all, coh_all, _, _ = _run(rng, _Cell(BUDGET), [300e-6], [3.0])
    with pytest.raises(SetupError, match="no input's own fit met the budget"):
        aligner.finish(F, H_all, coh_all)


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


def test_the_budget_weighs_the_cells_share_of_the_force_balance() -> None:
    """``s = median ‖F‖/(1 + ‖F‖)`` (moments at 0.1 m): closed form on constant loads; a cell
    carrying 1e-3 of the hammer's force (a soft suspension) costs the balance 1e-3 of its phase
    error, so the run whose delays differ by 40 µs (refused on a cell that carries the article,
    above) takes the one delay, the message naming the share; refused again when the drift is
    beyond that (a cell carrying more than half the force, an input too weak for its own)."""
    H = np.zeros((F.size, 6, 2), dtype=complex)
    H[:, 0, 0], H[:, 4, 1] = 3.0, 0.05 * 1j  # 3 N/N; 0.05 N·m/N = 0.5 at 0.1 m
    assert force_share(F, H, BUDGET, [0]) == pytest.approx(0.75)
    assert force_share(F, H, BUDGET, [0, 1]) == pytest.approx(0.75)
    assert force_share(F, H, BUDGET, [1]) == pytest.approx(1 / 3)
    assert force_share(F, H[:, :5], BUDGET, [0]) == 1.0  # not six loads: counts as carrying
    rng = np.random.default_rng(9)
    taus = [280e-6, 320e-6, 280e-6, 320e-6]
    aligner, H_all, coh_all, _, _ = _run(rng, _Cell(BUDGET), taus, [0.02] * 4)
    H_all[:, 3:9] *= 1e-3 / np.abs(H_all[:, 3:9]).max()
    (msg,) = aligner.finish(F, H_all, coh_all)
    assert "fitted on 4 inputs at once" in msg and "removed from every input" in msg
    share = float(msg.split("share of the force balance ")[1].split(":")[0])
    assert 1e-5 < share < 0.03  # loads at most 1e-3 N/N (moments: 1e-2 at 0.1 m)
    aligner, H_all, coh_all, _, _ = _run(rng, _Cell(BUDGET), taus + [300e-6], [0.02] * 4 + [3.0])
    H_all[:, 3:9] *= 30.0 / np.abs(H_all[:, 3:9]).max()
    with pytest.raises(SetupError, match=r"input 4: .*share of the force balance 0\.[5-9]"):
        aligner.finish(F, H_all, coh_all)


def test_an_input_whose_alignment_jumped_keeps_its_own_fit(carrying: None) -> None:
    """Four inputs at 300 µs and one whose coarse alignment jumped by 1 ms (seen through RDT on
    the article bolted to the cell: own fits within 0.1–0.3 µs, one of them 2.5 ms off): the
    run's delay is fitted, but the input it does not describe keeps its own fit, named."""
    rng = np.random.default_rng(11)
    taus = [300e-6, 300e-6, 300e-6, 300e-6, 1300e-6]
    aligner, H_all, coh_all, _, truth = _run(rng, _Cell(BUDGET), taus, [0.02] * 5)
    (msg,) = aligner.finish(F, H_all, coh_all)
    assert re.search(r"input 4 \(\+1(299\.9|300\.\d) us\) took their own fits", msg), msg
    for j in (0, 4):
        np.testing.assert_allclose(
            H_all[:, 3:9, j], truth[j], rtol=0.2, atol=0.2 * np.abs(truth[j]).max()
        )
