"""Shaker excitation and hammer line-of-action errors in the virtual lab.

Independent references: numerical quadrature for the first-order-hold coefficients,
:func:`scipy.signal.lsim` (matrix exponential of the augmented system, linear interpolation of the
input) on a fine grid for the time response, :meth:`ForwardModel.transfer` for the FRFs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.signal import butter, lsim, sosfilt

from dimacq.errors import SetupError
from dimacq.model.setup import Excitation
from dimacq.simulators.lab.forward import ForwardModel
from dimacq.simulators.lab.scenarios import Scenario, build_scenario, load_scenario
from dimacq.simulators.lab.shaker import shaker_test
from dimacq.simulators.lab.timedomain import (
    Hammer,
    ShakerSignal,
    VirtualLab,
    foh_coefficients,
    state_space,
)


@pytest.mark.parametrize("lam", [-3.0 + 40j, -0.02 + 2.5j, -1e-3 + 1e-2j, -900.0 + 5000j])
def test_foh_coefficients_equal_the_integrals(lam: complex) -> None:
    T = 1 / 2048
    b0, b1 = foh_coefficients(np.array([lam]), T)

    def integral(weight: object) -> complex:
        def re(s: float) -> float:
            return float(np.real(np.exp(lam * (T - s)) * weight(s)))  # type: ignore[operator]

        def im(s: float) -> float:
            return float(np.imag(np.exp(lam * (T - s)) * weight(s)))  # type: ignore[operator]

        return (
            quad(re, 0, T, epsabs=0, epsrel=1e-11)[0]
            + 1j * quad(im, 0, T, epsabs=0, epsrel=1e-11)[0]
        )

    ref0 = integral(lambda s: 1 - s / T)  # weight of u_n
    ref1 = integral(lambda s: s / T)  # weight of u_{n+1}
    assert abs(b0[0] - ref0) < 1e-10 * abs(ref0) and abs(b1[0] - ref1) < 1e-10 * abs(ref1)


def _fine_lsim(model: ForwardModel, j: int, u: np.ndarray, fs: float, K: int) -> np.ndarray:
    """Outputs at the lab's samples of the continuous response to the linear interpolation of
    ``u`` (lsim on a grid K times finer), shape (n_out, n, K) at all fine instants."""
    A, B, C, D, _ = state_space(model)
    n = np.arange(u.size)
    tf = np.arange((u.size - 1) * K + 1) / (K * fs)
    uf = np.interp(tf, n / fs, u)
    _, y, _ = lsim((A, B[:, j : j + 1], C, D[:, j : j + 1]), uf, tf)
    return np.asarray(y.T)


def _drive_samples(sig: ShakerSignal, start: int, stop: int, N: int, fs: float) -> np.ndarray:
    n = np.arange(N)
    u = np.zeros(N)
    on = (n > start) & (n < stop)
    u[on] = sig.samples(n[on] - start, fs)
    return u


@pytest.mark.parametrize("name", ["calibration-mass-bungee", "x38"])
def test_unfiltered_shaker_response_equals_lsim(name: str) -> None:
    model = build_scenario(name).model
    fs = 2048.0
    lab = VirtualLab(model, fs, n_shakers=1, oversample=1, anti_alias=False, block_samples=256)
    sig = ShakerSignal("random", level_n=10.0, seed=3)
    lab.drive(0, 2, sig, 100, until_sample=1500)  # stops: later blocks carry its free decay
    N = 3000
    rec = lab.read(np.arange(len(lab.channel_names)), 0, N)
    u = _drive_samples(sig, 100, 1500, N, fs)
    assert np.array_equal(rec[lab.channel_index("shaker1")], u)
    ref = lab._mix @ _fine_lsim(model, 2, u, fs, 8)[:, ::8]
    got = rec[lab._phys_rows]
    assert np.abs(got - ref).max() < 1e-10 * np.abs(ref).max()


def test_anti_aliased_shaker_response_equals_filtered_fine_lsim() -> None:
    """oversample 4 + low-pass: the lab equals lsim at 4 fs, filtered and decimated."""
    model = build_scenario("calibration-mass-bungee").model
    fs, K = 2048.0, 4
    lab = VirtualLab(model, fs, n_shakers=2, oversample=K, block_samples=256)
    sig = ShakerSignal("burst-random", level_n=5.0, record_samples=512, seed=9)
    lab.drive(1, 4, sig, 300, until_sample=1300)
    N = 3500
    rec = lab.read(np.arange(len(lab.channel_names)), 0, N)
    u = _drive_samples(sig, 300, 1300, N, fs)
    fine = _fine_lsim(model, 4, u, fs, K)  # (n_out, (N-1)K+1)
    uf = np.interp(np.arange(fine.shape[1]) / (K * fs), np.arange(N) / fs, u)
    sos = butter(8, 0.45 * fs, fs=K * fs, output="sos")
    yf = sosfilt(sos, fine, axis=-1)[:, ::K]
    ref = lab._mix @ yf
    assert np.abs(rec[lab._phys_rows] - ref).max() < 1e-9 * np.abs(ref).max()
    f_ref = sosfilt(sos, uf)[::K]
    assert np.abs(rec[lab.channel_index("shaker2")] - f_ref).max() < 1e-12 * np.abs(u).max()
    assert np.abs(rec[lab.channel_index("shaker1")]).max() == 0.0


@pytest.mark.slow
def test_periodic_random_in_steady_state_gives_y_equal_h_f_per_line() -> None:
    b = build_scenario("calibration-mass-bungee")
    fs, Nr = 2048.0, 2048
    lab = VirtualLab(b.model, fs, n_shakers=2, block_samples=512)
    for k, j in enumerate((1, 5)):
        sig = ShakerSignal("random", level_n=10.0, periodic=True, record_samples=Nr, seed=k)
        lab.drive(k, j, sig, 0)
    rec = lab.read(np.arange(len(lab.channel_names)), 200 * Nr, Nr)  # suspension settled
    F = np.fft.rfft(rec[lab._shaker_rows], axis=-1)  # (2, L)
    Y = np.fft.rfft(rec[lab._phys_rows], axis=-1)
    f = np.arange(Nr // 2 + 1) * fs / Nr
    sel = (f > 0) & (f <= 400)
    H = lab._mix @ b.model.transfer(2j * np.pi * f[sel])[:, :, [1, 5]]  # (L, n_phys, 2)
    pred = np.einsum("lcj,jl->cl", H, F[:, sel])
    err = np.abs(Y[:, sel] - pred).max(axis=1) / np.abs(pred).max(axis=1)
    assert err.max() < 1e-4  # aliasing of the hold's images above 4 fs: ~(f / 4fs)² ≈ 1e-5


def test_reads_are_repeatable_after_the_cache_forgets() -> None:
    b = build_scenario("calibration-mass-bungee")
    lab = VirtualLab(b.model, 2048.0, n_shakers=2, block_samples=256, cache_blocks=2)
    lab.drive(0, 0, ShakerSignal("random", seed=1), 10, 3000)
    lab.drive(1, 7, ShakerSignal("swept-sine", record_samples=1024, f_hi_hz=300.0), 500)
    ch = np.arange(len(lab.channel_names))
    first = lab.read(ch, 0, 6000)
    lab.read(ch, 6000, 4000)
    assert np.array_equal(lab.read(ch, 0, 6000), first)
    assert np.abs(first[lab.channel_index("shaker2")]).max() > 0.9 * 20.0
    with pytest.raises(ValueError, match="already read"):
        lab.drive(0, 3, ShakerSignal(), 9000)
    with pytest.raises(ValueError, match="n_shakers"):
        lab.drive(2, 3, ShakerSignal(), 20_000)


def test_signals_are_seeded_band_limited_and_refuse_bad_items() -> None:
    fs = 2048.0
    n = np.arange(1, 2**16)
    a = ShakerSignal(seed=1, band_limited=True, f_lo_hz=10.0, f_hi_hz=400.0).samples(n, fs)
    assert np.array_equal(a, ShakerSignal(seed=1, band_limited=True, f_lo_hz=10.0).samples(n, fs))
    assert not np.array_equal(
        a, ShakerSignal(seed=2, band_limited=True, f_lo_hz=10.0).samples(n, fs)
    )
    seg = a[2000:]
    P = np.abs(np.fft.rfft(seg * np.hanning(seg.size))) ** 2
    f = np.fft.rfftfreq(a.size - 2000, 1 / fs)
    inband = P[(f > 20) & (f < 380)].mean()
    assert P[(f > 0.3) & (f < 3)].mean() < 1e-4 * inband and P[f > 480].mean() < 1e-4 * inband
    assert abs(np.std(a[2000:]) / 20.0 - 1) < 0.05
    with pytest.raises(SetupError, match="burst_fraction"):
        ShakerSignal(burst_fraction=1.5)


def test_hammer_line_of_action_errors_per_strike() -> None:
    b = build_scenario("calibration-mass-bungee")
    model, fs, tau = b.model, 2048.0, 0.2
    sigma_deg = 4.0
    lab = VirtualLab(model, fs, hammer=Hammer(line_of_action_error_deg=sigma_deg))
    plain = VirtualLab(model, fs)
    N, at, j = 2**14, 50, 3
    lab.excite(j, at)
    plain.excite(j, at)
    ch = np.arange(len(lab.channel_names))
    rec = lab.read(ch, 0, N)
    d_hit = lab.hit_directions[0]
    d0 = np.asarray(model.setup.excitations[j].direction_gcs)
    angle = np.degrees(np.arccos(np.clip(d_hit @ d0, -1, 1)))
    assert 0 < angle < 5 * sigma_deg
    assert np.abs(rec - plain.read(ch, 0, N)).max() > 1e-3 * np.abs(rec).max()  # it matters
    # Reference: the model with input j's line of action turned to the strike's direction.
    ex = list(model.setup.excitations)
    ex[j] = Excitation(
        node=ex[j].node,
        direction=ex[j].direction,
        position_m=ex[j].position_m,
        direction_gcs=tuple(float(x) for x in d_hit),  # type: ignore[arg-type]
    )
    turned = ForwardModel(
        model.properties,
        model.setup.model_copy(update={"excitations": tuple(ex)}),
        model.supports,
        model.modes,
    )
    w = np.exp(-np.clip((np.arange(N) - at) / fs, 0, None) / tau)
    F = np.fft.rfft(rec[lab.channel_index("hammer")] * w)
    Y = np.fft.rfft(rec * w, axis=1)
    f = np.arange(N // 2 + 1) * fs / N
    sel = (f > 0) & (f < 0.25 * fs)
    ref = turned.transfer(2j * np.pi * f[sel] + 1 / tau)[:, :, j]
    n_acc = len(b.setup.responses)
    acc = (Y[:n_acc, sel] / F[sel]).T
    assert np.abs(acc - ref[:, :n_acc]).max() < 1e-8 * np.abs(ref[:, :n_acc]).max()
    # The angles scatter with the configured spread.
    for _ in range(400):
        lab.excite(j, 10 * N)
    ang = np.array([np.arccos(np.clip(d @ d0, -1, 1)) for d in lab.hit_directions])
    rms_deg = np.degrees(np.sqrt(np.mean(ang**2)))
    assert abs(rms_deg / sigma_deg - 1) < 0.15


def test_no_line_of_action_error_leaves_the_lab_unchanged() -> None:
    model = build_scenario("x38").model
    a, c = VirtualLab(model, 2048.0), VirtualLab(model, 2048.0, hammer=Hammer())
    a.excite(4, 100)
    c.excite(4, 100)
    ch = np.arange(len(a.channel_names))
    assert np.array_equal(a.read(ch, 0, 3000), c.read(ch, 0, 3000))


def _with_shaker(name: str, **changes: object) -> Scenario:
    scn = load_scenario(name)
    return scn.model_copy(update={"shaker": scn.shaker.model_copy(update=changes)})


@pytest.mark.parametrize("kind", ["random", "burst-random", "swept-sine"])
def test_noise_free_shaker_tests_on_the_free_cube_give_the_mass_line(kind: str) -> None:
    b = build_scenario(_with_shaker("cube-2", inputs=(0, 4, 5), record_samples=1024))
    run = shaker_test(b, excitation=kind, n_shakers=2, averages=6, noise_scale=0.0)
    ref = b.model.frf(run.frf.frequencies_hz).H[:, :, [0, 4, 5]]
    assert run.groups == ((0, 4), (5,))
    assert run.frf.H.shape == ref.shape
    assert np.abs(run.frf.H - ref).max() < 1e-4 * np.abs(ref).max()


def test_random_two_shakers_agree_with_the_model_where_coherent() -> None:
    b = build_scenario(_with_shaker("calibration-mass-bungee", inputs=(2, 9, 14, 21)))
    run = shaker_test(b, n_shakers=2, averages=24)
    frf = run.frf
    ref = b.model.frf(frf.frequencies_hz).H[:, :, [2, 9, 14, 21]]
    band = (frf.frequencies_hz >= 20) & (frf.frequencies_hz <= 100)
    n_acc = len(b.setup.responses)
    h, r = frf.H[band, :n_acc], ref[band, :n_acc]
    assert frf.coherence is not None
    coherent = frf.coherence[band, :n_acc] > 0.99
    assert coherent.mean() > 0.95
    row = np.sqrt(np.sum(np.abs(r) ** 2, axis=2, keepdims=True))  # output's level over inputs
    assert (np.abs(h - r) / row)[coherent].max() < 0.01
    assert np.median((np.abs(h - r) / np.abs(r))[coherent]) < 2e-3
    assert run.input_condition.max() < 10


def test_shaker_section_is_checked_item_by_item(tmp_path: Path) -> None:
    head = (
        'schema_version = 1\nname = "s"\n[article]\nmodel = "cube"\nhalf_size_m = 2.0\n'
        "[band]\nlo_hz = 20\nhi_hz = 60\n[shaker]\n"
    )
    for line, words in (
        ('kind = "sinus"', ("item 'shaker.kind'", "random, burst-random or swept-sine")),
        ("shakers = 0", ("item 'shaker.shakers'", "1–8")),
        ("f_hi_hz = 5000.0", ("shaker sweep", "Nyquist", "fix:")),
        ("shaker_count = 2", ("item 'shaker.shaker_count'", "remove it")),
    ):
        bad = tmp_path / "s.toml"
        bad.write_text(head + line + "\n", encoding="utf-8")
        with pytest.raises(SetupError) as err:
            load_scenario(bad)
        assert all(w in str(err.value) for w in words), str(err.value)
    b = build_scenario(_with_shaker("cube-2", inputs=(0, 99)))
    with pytest.raises(SetupError, match=r"shaker\.inputs \[99\]"):
        shaker_test(b)
    with pytest.raises(SetupError, match="averages"):
        shaker_test(build_scenario("cube-2"), n_shakers=3, averages=2)
