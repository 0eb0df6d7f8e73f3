"""``GET /api/frfs/{id}/data.f32``: the values of ``/data`` as float32 arrays behind a JSON
header (what the page reads), checked value by value against ``/data``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _api_support import Api

from dimacq.io.frf_binary import MEDIA_TYPE, decode_f32, encode_f32

_EXAMPLES = Path(__file__).resolve().parents[2] / "config" / "examples"


def _store(api: Api) -> int:
    setup = api.client.post(
        "/api/setups/import",
        params={"format": "toml"},
        content=(_EXAMPLES / "six_triax_setup.toml").read_bytes(),
    )
    assert setup.status_code == 201, setup.text
    frf = api.client.post(
        "/api/frfs/import",
        params={"setup_id": setup.json()["id"]},
        content=(_EXAMPLES / "six_triax_frf.uff").read_bytes(),
    )
    assert frf.status_code == 201, frf.text
    return int(frf.json()["id"])


@pytest.mark.slow
def test_f32_is_data_in_float32(api: Api) -> None:
    fid = _store(api)
    for params in ({}, {"input": 1, "f_min_hz": 20, "f_max_hz": 60}, {"response": 2}):
        js = api.client.get(f"/api/frfs/{fid}/data", params=params).json()
        r = api.client.get(f"/api/frfs/{fid}/data.f32", params=params)
        assert r.status_code == 200 and r.headers["content-type"] == MEDIA_TYPE
        head, arrays = decode_f32(r.content)
        assert head["frequencies_hz"] == js["frequencies_hz"]
        assert head["responses"] == js["responses"] and head["inputs"] == js["inputs"]
        assert head["layout"] == js["layout"] == "[line][response][input]"
        for name in ("real", "imag"):
            want = np.array(js[name], dtype=np.float64)
            assert arrays[name].shape == want.shape
            # float32 rounding: half an ulp of 2^-24 relative
            np.testing.assert_allclose(arrays[name], want, rtol=2**-23, atol=0)
        if js["coherence"] is None:
            assert "coherence" not in arrays
        else:
            want = np.array(js["coherence"], dtype=np.float64)  # null → nan
            np.testing.assert_allclose(arrays["coherence"], want, rtol=2**-23, atol=0)
    assert api.client.get("/api/frfs/999999/data.f32").status_code == 404
    bad = api.client.get(f"/api/frfs/{fid}/data.f32", params={"f_min_hz": 9, "f_max_hz": 1})
    assert bad.status_code == 422 and "f_min_hz" in bad.text


def test_codec_round_trip_and_alignment() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 3, 2))
    b = np.full((4,), np.nan)
    msg = encode_f32({"x": "é"}, {"a": a, "b": b})
    head, got = decode_f32(msg)
    assert head["x"] == "é" and head["dtype"] == "<f4"
    assert all(m["offset"] % 4 == 0 for m in head["arrays"])
    np.testing.assert_array_equal(got["a"], a.astype("<f4"))
    assert np.isnan(got["b"]).all() and got["b"].shape == (4,)
    with pytest.raises(ValueError, match="not an FRF float32"):
        decode_f32(b"JSON" + msg[4:])
