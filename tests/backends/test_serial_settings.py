"""The digitizer's serial line as settings (issue 23): baud rate, reply timeout and read poll
reach the port and the driver (``loop://``: pyserial's own loopback, no device); a bad value is
one line naming the setting."""

from __future__ import annotations

from pathlib import Path

import pytest

from dimacq.backends import lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import load_settings
from dimacq.errors import SetupError


def test_baud_rate_and_timeouts_reach_the_port(tmp_path: Path) -> None:
    settings = load_settings(
        data_dir=tmp_path,
        token="t",
        digitizer="serial",
        digitizer_url="loop://",
        digitizer_baudrate=9600,
        digitizer_timeout_s=0.7,
        digitizer_poll_s=0.05,
    )
    with DeviceContext(settings) as ctx:
        drv = lookup("digitizer", "serial")(ctx)
        port = drv._port_or_raise()
        assert port.baudrate == 9600 and port.timeout == 0.05
        assert drv.timeout_s == 0.7
    assert load_settings(data_dir=tmp_path, token="t").digitizer_baudrate == 115200


def test_a_bad_baud_rate_names_the_setting(tmp_path: Path) -> None:
    with pytest.raises(SetupError, match="configuration item 'digitizer_baudrate'"):
        load_settings(data_dir=tmp_path, token="t", digitizer_baudrate=0)


def test_real_backends_with_the_simulated_rig_file_warn(tmp_path: Path) -> None:
    from dimacq.backends.base import simulated_rig_warning

    sim = load_settings(data_dir=tmp_path, token="t")
    assert simulated_rig_warning(sim) is None  # the simulated lab on its own rig file
    real = load_settings(data_dir=tmp_path, token="t", daq="dimacq-usb", loadcell="netft-udp")
    msg = simulated_rig_warning(real)
    assert msg is not None and "\n" not in msg
    assert "daq = 'dimacq-usb', loadcell = 'netft-udp'" in msg and "give your own" in msg
    own = tmp_path / "rig.toml"
    own.write_text(real.rig_path.read_text().replace("tests/scripts/simulated_rig_files.py", "us"))
    mine = load_settings(data_dir=tmp_path, token="t", daq="dimacq-usb", rig_file=str(own))
    assert simulated_rig_warning(mine) is None
