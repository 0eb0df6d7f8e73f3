"""Real devices configured but absent: the API answers 503 naming the setting, over HTTP."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from _api_support import TOKEN, make_settings
from _lab_rig_support import IMPULSE_SETUP

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.io.setup_file import dump_setup_dict


@pytest.fixture
def real_api(tmp_path: Path, database_url: str) -> Iterator[httpx.Client]:
    # A USB id no device has: the real pyusb path finds nothing (whatever libusb is installed).
    settings = make_settings(
        tmp_path,
        database_url=database_url,
        daq_backend="libusb",
        daq_vendor_id=0xFFFE,
        daq_product_id=0xFFFE,
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,  # a simulator on python-can's in-process bus
        loadcell_channel=f"absent-{tmp_path.name}",
    )
    with (
        BackgroundServer(create_app(settings)) as srv,
        httpx.Client(
            base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c,
    ):
        yield c


@pytest.mark.slow
def test_acquisition_on_absent_real_daq_is_503_naming_the_setting(real_api: httpx.Client) -> None:
    status = real_api.get("/api/status")
    assert status.status_code == 200
    assert status.json()["devices"]["daq"]["connected"] is False
    sid = real_api.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
    r = real_api.post("/api/acquisitions", json={"setup_id": sid, "averages_per_input": 1})
    assert r.status_code == 503, r.text
    assert "daq_" in r.text  # names daq_backend or daq_vendor_id/daq_product_id
