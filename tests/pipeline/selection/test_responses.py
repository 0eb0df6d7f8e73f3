"""Perimeter response selection: PRESS identity vs explicit refits, forward-model detection, guards."""

from __future__ import annotations

import numpy as np
import pytest
from _selection_support import forward_case

from dimacq.errors import SetupError
from dimacq.pipeline.rigid_body import response_matrix
from dimacq.pipeline.selection._common import response_geometry
from dimacq.pipeline.selection.responses import (
    rigid_body_errors,
    select_responses,
    select_responses_frf,
)


def test_leave_one_out_error_equals_explicit_refit() -> None:
    c = forward_case(5, triax_error_deg=1.0, n_bad_channels=1, bad_channel_deg=20)
    geo = response_geometry(c.frf, c.nominal)
    psi = response_matrix(geo.positions_m, geo.directions, np.zeros(3))
    q = c.frf.H[:, geo.output_index, :]
    active = np.ones(24, bool)
    e = rigid_body_errors(psi, q, active)
    for i in (0, 7, 23):
        others = np.arange(24) != i
        K = np.einsum("ks,lsj->lkj", np.linalg.pinv(psi[others]), q[:, others, :])
        pred = np.einsum("k,lkj->lj", psi[i], K)
        err = np.sqrt(np.sum(np.abs(q[:, i, :] - pred) ** 2) / np.sum(np.abs(pred) ** 2))
        assert e.loo_band[i] == pytest.approx(err, rel=1e-9)
    # Eq. 31 in-sample error from an explicit fit
    K = np.einsum("ks,lsj->lkj", np.linalg.pinv(psi), q)
    qf = np.einsum("ck,lkj->lcj", psi, K)
    eq31 = np.sqrt(np.sum(np.abs(q - qf) ** 2, axis=(0, 2)) / np.sum(np.abs(qf) ** 2, axis=(0, 2)))
    np.testing.assert_allclose(e.eq31_band, eq31, rtol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_removes_exactly_the_two_misoriented_channels(seed: int) -> None:
    c = forward_case(seed, triax_error_deg=0.5, bad_channel_deg=20.0, n_bad_channels=2)
    sel, _ = select_responses_frf(c.frf, c.nominal)
    assert {(x.node, x.direction) for x in sel.excluded} == set(c.bad_channels)
    assert sel.keep.sum() == 22
    assert all(v >= 3 for v in sel.per_direction.values())


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_clean_data_loses_nothing(seed: int) -> None:
    c = forward_case(seed, triax_error_deg=0.5)
    sel, _ = select_responses_frf(c.frf, c.nominal)
    assert sel.excluded == ()
    assert "within the spread" in sel.stop_reason


def test_force_in_and_force_out() -> None:
    c = forward_case(0, triax_error_deg=0.5, bad_channel_deg=20.0, n_bad_channels=2)
    bad0, bad1 = c.bad_channels
    good = next(
        (r.node, r.direction)
        for r in c.nominal.responses
        if (r.node, r.direction) not in c.bad_channels
    )
    sel, _ = select_responses_frf(c.frf, c.nominal, force_in=[bad0], force_out=[good])
    names = {(x.node, x.direction) for x in sel.excluded}
    assert bad0 not in names and bad1 in names and good in names
    assert any("forced out" in v for v in sel.reasons.values())
    with pytest.raises(SetupError, match="both forced in and forced out"):
        select_responses_frf(c.frf, c.nominal, force_in=[good], force_out=[good])


def test_guard_keeps_a_bad_channel_needed_for_three_per_direction() -> None:
    # 6 aligned triaxes on a box, but only three channels measure Z; one of them is bad
    rng = np.random.default_rng(0)
    pos = np.array([[x, y, z] for x in (-0.2, 0.2) for y in (-0.1, 0.1) for z in (-0.1, 0.1)])
    d, p = [], []
    for k, r in enumerate(pos):
        for ax in (0, 1) if k >= 3 else (0, 1, 2):
            d.append(np.eye(3)[ax])
            p.append(r)
    d, p = np.array(d), np.array(p)
    psi_true = response_matrix(p, d, np.zeros(3))
    zbad = 2  # the Z channel of the first triax
    d_bad = d.copy()
    d_bad[zbad] = np.array([0.0, np.sin(0.5), np.cos(0.5)])
    psi_meas = response_matrix(p, d_bad, np.zeros(3))
    K = rng.normal(size=(4, 6, 12)) + 1j * rng.normal(size=(4, 6, 12))
    q = psi_meas @ K
    q = q + 0.002 * np.abs(q).mean() * rng.normal(size=q.shape)
    from dimacq.model.frf import Channel

    chans = tuple(Channel(i + 1, 1) for i in range(len(d)))
    sel = select_responses(psi_true, q, chans)
    assert sel.keep[zbad]
    assert any("channels along Z" in s.reason for s in sel.steps)
