"""The virtual lab's truth beside the measured data, for the commands and scripts that play the
virtual lab (``dimacq acquire``, ``tests/scripts``): the scenarios' true articles
(:func:`scenario_model`), their true FRFs consistent with the exponential window
(:func:`model_frf`) and the agreement of measured FRFs with them (:func:`frf_agreement`).

Every acquisition and calibration builds its devices with the one rig builder,
:func:`dimacq.services.acquisition.rig.build_rig`, from the backend tables; nothing here opens a device.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.model.frf import FrfData
from dimacq.simulators.lab.forward import ForwardModel, calibration_mass, x38_like
from dimacq.simulators.lab.timedomain import state_space

__all__ = [
    "DIM_BAND_HZ",
    "SCENARIOS",
    "FrfAgreement",
    "frf_agreement",
    "model_frf",
    "scenario_model",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


# ---------------------------------------------------------------------------------------------
# Scenarios
# ---------------------------------------------------------------------------------------------
#: Extra scenario names (aliases and variants) beside the versioned files in ``config/scenarios/``,
#: which take precedence (:func:`dimacq.simulators.lab.scenarios.build_scenario`).
SCENARIOS: dict[str, Callable[[int], ForwardModel]] = {
    "calibration-mass": lambda seed: calibration_mass(seed, support="bungee"),
    "calibration-mass-bungee": lambda seed: calibration_mass(seed, support="bungee"),
    "calibration-mass-air-ride": lambda seed: calibration_mass(seed, support="air-ride"),
    "calibration-mass-ground": lambda seed: calibration_mass(seed, support="ground"),
    "x38": lambda seed: x38_like(seed),
    "x38-flexible": lambda seed: x38_like(seed, flexible=True),
}


def scenario_model(name: str, seed: int = 0) -> ForwardModel:
    """The true article of scenario ``name``: a file of ``config/scenarios/`` or an alias of
    :data:`SCENARIOS`."""
    from dimacq.simulators.lab.scenarios import build_scenario, list_scenarios

    files = list_scenarios()
    if name in files:
        return build_scenario(name, seed).model
    try:
        build = SCENARIOS[name]
    except KeyError as err:
        raise SetupError(
            f"scenario {name!r} is unknown; use one of {', '.join(sorted({*files, *SCENARIOS}))}"
        ) from err
    return build(seed)


#: DIM band of the simulated calibration-mass tests: above the bungee/air-ride suspension modes
#: (≤ 2 Hz) and below where the hammer pulse's spectrum has fallen by 13 dB (400 Hz at the
#: lab's default pulse width σ = 1.4/fs, fs = 2048 Hz).
DIM_BAND_HZ = (20.0, 400.0)


# ---------------------------------------------------------------------------------------------
# Results as FRF data, and the model to compare with
# ---------------------------------------------------------------------------------------------
def model_frf(
    model: ForwardModel, frequencies_hz: FloatArray, exponential_tau_s: float | None = None
) -> ComplexArray:
    """True FRFs ``H(s) = C (sE − A)⁻¹ B + D`` at ``s = i2πf + 1/τ``, shape (L, n_out, n_in).

    The exponential window ``e^{−t/τ}`` applied to input and output turns the measured FRF into
    ``H(iω + 1/τ)``; ``exponential_tau_s=None`` gives ``H(iω)``. Outputs in
    :meth:`ForwardModel.frf` order (accelerometers, then 6 loads per load cell).
    """
    A, B, C, D, _ = state_space(model)
    s = 2j * np.pi * np.asarray(frequencies_hz, float)
    if exponential_tau_s:
        s = s + 1.0 / exponential_tau_s
    n = A.shape[0]
    if n == 0:
        return np.broadcast_to(D.astype(complex), (s.size, *D.shape)).copy()
    # Batched (sE − A) X = B: complex solve over small systems (n ≤ a few dozen).
    Msys = s[:, None, None] * np.eye(n)[None] - A[None]
    X = np.linalg.solve(Msys, np.broadcast_to(B.astype(complex), (s.size, *B.shape)))
    # C X with real arithmetic (complex GEMM is slow on this machine's BLAS).
    H = np.einsum("on,lni->loi", C, X.real) + 1j * np.einsum("on,lni->loi", C, X.imag)
    return np.asarray(H + D[None], dtype=complex)


@dataclass(frozen=True)
class FrfAgreement:
    """Measured vs true FRFs on the lines where the coherence exceeds a threshold.

    Attributes
    ----------
    max_rel_error : float
        ``max |H_meas − H_true| / |H_true|`` over the kept (line, output, input) entries,
        per kind ``"acceleration"`` / ``"reaction"`` in ``by_kind``.
    p99_rel_error, median_rel_error : float
    fraction_kept : float
        Kept entries / all entries.
    n_kept : int
    """

    max_rel_error: float
    p99_rel_error: float
    median_rel_error: float
    fraction_kept: float
    n_kept: int
    coherence_threshold: float | None
    band_hz: tuple[float, float]
    by_kind: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "max_rel_error": self.max_rel_error,
            "p99_rel_error": self.p99_rel_error,
            "median_rel_error": self.median_rel_error,
            "fraction_kept": self.fraction_kept,
            "n_kept": self.n_kept,
            "coherence_threshold": self.coherence_threshold,
            "band_hz": list(self.band_hz),
            "max_rel_error_by_kind": self.by_kind,
        }


def frf_agreement(
    frf: FrfData,
    model: ForwardModel,
    *,
    exponential_tau_s: float | None = None,
    coherence_threshold: float | None = 0.99,
    band_hz: tuple[float, float] | None = None,
    inputs: list[int] | None = None,
) -> FrfAgreement:
    """Compare measured FRFs with :func:`model_frf` where ``coherence > coherence_threshold``
    (``None``: every value, e.g. noise-free single-average FRFs, whose coherence is undefined).
    ``inputs``: the model's input columns the FRFs hold, in their order (an acquisition whose
    incomplete inputs have no FRF); default all."""
    if frf.coherence is None and coherence_threshold is not None:
        raise DataError("the FRFs carry no coherence; compare FRFs from an impact session")
    f = frf.frequencies_hz
    sel = np.ones(f.size, bool)
    if band_hz is not None:
        sel = (f >= band_hz[0]) & (f <= band_hz[1])
    H_true = model_frf(model, f[sel], exponential_tau_s)
    if inputs is not None:
        H_true = H_true[:, :, inputs]
    H = frf.H[sel]
    keep = (
        np.ones(H.shape, bool)
        if coherence_threshold is None or frf.coherence is None
        else frf.coherence[sel] > coherence_threshold
    )
    rel = np.abs(H - H_true) / np.maximum(np.abs(H_true), np.finfo(float).tiny)
    kept = rel[keep]
    if kept.size == 0:
        raise DataError(f"no FRF value has coherence above {coherence_threshold}")
    kinds = np.array(frf.output_kinds)
    by_kind = {}
    for kind in ("acceleration", "reaction"):
        m = keep & (kinds == kind)[None, :, None]
        if m.any():
            by_kind[kind] = float(rel[m].max())
    return FrfAgreement(
        max_rel_error=float(kept.max()),
        p99_rel_error=float(np.quantile(kept, 0.99)),
        median_rel_error=float(np.median(kept)),
        fraction_kept=float(keep.mean()),
        n_kept=int(kept.size),
        coherence_threshold=coherence_threshold,
        band_hz=(float(f[sel][0]), float(f[sel][-1])),
        by_kind=by_kind,
    )
