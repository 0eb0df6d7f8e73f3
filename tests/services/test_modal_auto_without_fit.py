"""Modal correction ``auto``: deformation peaks whose modal fit cannot be made are no evidence
of an elastic mode; the solve goes on as measured instead of failing (it failed with HTTP 400
"0 lines above 1.18e+03 Hz (clear of the suspension modes) are too few for the modal fit" on
acquired 1 Hz-line FRFs of the rigid calibration mass: a noise pole near Nyquist read as a
suspension mode left no line above it)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from dimacq.errors import DataError
from dimacq.services.solve import modal_correction as mc


def test_deformation_peaks_without_a_possible_fit_are_no_contamination(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[int] = []

    def no_fit(*_a: object, **_k: object) -> None:
        calls.append(1)
        raise DataError(
            "0 lines above 1.18e+03 Hz (clear of the suspension modes) are too few for the "
            "modal fit; measure a wider span or a finer resolution"
        )

    monkeypatch.setattr(mc, "modal_fit", no_fit)
    report = SimpleNamespace(
        band_suggestion=SimpleNamespace(qualified=True, reason="", deformation_peaks_hz=[612.0]),
        verdict_reasons=[],
    )
    cache: dict[str, object] = {}
    assert mc.contamination(report, object(), object(), cache) is None  # type: ignore[arg-type]
    assert calls == [1] and "fit" not in cache
