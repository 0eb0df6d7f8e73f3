"""The device backend tables, the settings that name their entries, and honest simulation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dimacq.backends import BACKENDS, is_simulated, lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import load_settings
from dimacq.errors import SetupError
from dimacq.io.loadcell_calibration import read_calibration
from dimacq.model.frf import STANDARD_GRAVITY
from dimacq.services.acquisition.rig import build_rig
from dimacq.simulators.lab import transducers as tr
from dimacq.simulators.lab.scenarios import build_scenario


def test_every_kind_has_a_hardware_and_a_simulated_entry() -> None:
    assert set(BACKENDS) == {"daq", "loadcell", "digitizer", "loadcell-bench"}
    for kind, table in BACKENDS.items():
        # the dead-weight bench is simulated only: the real one is the amplifier and a person
        assert "simulated" in table and (len(table) >= 2 or kind == "loadcell-bench"), kind
        for name in table:
            assert callable(lookup(kind, name))  # type: ignore[arg-type]


def test_which_entries_are_simulators() -> None:
    """``canopen-simulated`` is the virtual lab as much as ``simulated`` (issue 17: the status
    said it was not); hardware entries and other factories are devices."""
    assert is_simulated("loadcell", "canopen-simulated") and is_simulated("loadcell", "simulated")
    assert is_simulated("daq", "simulated") and is_simulated("digitizer", "simulated")
    assert not is_simulated("loadcell", "canopen") and not is_simulated("loadcell", "dimacq-can")
    assert not is_simulated("daq", "dimacq-usb") and not is_simulated("digitizer", "serial")
    assert is_simulated("daq", "dimacq.backends.simulated:open_daq")  # by its import path
    assert not is_simulated("daq", "tests._second_daq:open_daq")


def test_unknown_names_are_refused_naming_the_setting() -> None:
    with pytest.raises(SetupError, match=r"daq = 'nidaq'.*'dimacq-usb'.*DIMACQ_DAQ"):
        lookup("daq", "nidaq")
    with pytest.raises(SetupError, match=r"loadcell = 'no_such_module:open'.*cannot import"):
        lookup("loadcell", "no_such_module:open")


def test_settings_names_and_older_aliases(tmp_path: Path) -> None:
    base = {"data_dir": tmp_path, "token": "t"}
    s = load_settings(**base)
    assert (s.daq, s.loadcell, s.digitizer) == ("simulated", "simulated", "simulated")
    s = load_settings(**base, daq_backend="simulated")
    assert (s.daq, s.daq_backend) == ("simulated", "libusb")
    s = load_settings(**base, daq_backend="libusb", digitizer_url="/dev/ttyUSB0")
    assert (s.daq, s.loadcell, s.digitizer) == ("dimacq-usb", "dimacq-can", "serial")
    s = load_settings(**base, daq="my_pkg.daq:open", loadcell="simulated")
    assert (s.daq, s.loadcell) == ("my_pkg.daq:open", "simulated")
    with pytest.raises(SetupError, match=r"'daq'.*backend name"):
        load_settings(**base, daq="not a name")


def test_simulated_devices_learn_their_calibration_from_the_files(tmp_path: Path) -> None:
    """The simulated rig's drivers hold the rig file's calibrated sensitivities and the matrix
    of the calibration file it names; the simulator's transducers are neither (within their
    datasheet tolerance of nominal, and a calibration error apart)."""
    settings = load_settings(data_dir=tmp_path, token="t")
    setup = build_scenario(settings.scenario).model.setup
    rig = build_rig(settings, setup, {})
    try:
        rf = DeviceContext(settings).rig_file
        (entry,) = rf.load_cells
        C_file = read_calibration(rf.calibration_path(entry)).matrix
        (cell,) = rig.loadcells
        assert cell.calibration_matrix is not None
        np.testing.assert_array_equal(cell.calibration_matrix, C_file)
        from dimacq.backends.simulated import world

        ctx = DeviceContext(settings)
        try:
            S_true = world(ctx).lab.gauge_matrix(entry.node)
        finally:
            ctx.close()
        C_true = np.linalg.pinv(S_true)
        err = np.linalg.norm(C_file - C_true) / np.linalg.norm(C_true)
        # a calibration of this cell, not the cell: lc-501.json is the lab's bench calibration
        # (dimacq loadcell calibrate, ~0.03 % off), lc-501-v1.json the maker's certificate (~1 %)
        assert 1e-4 < err < 0.02
        cert = read_calibration(rf.calibration_path(entry).with_name("lc-501-v1.json")).matrix
        err_cert = np.linalg.norm(cert - C_true) / np.linalg.norm(C_true)
        assert 0.002 < err_cert < 0.02 and err < err_cert
        daq_channels = {c.name: c for c in rig.daq.channels}  # type: ignore[attr-defined]
        for r in rf.responses:
            certificate = r.sensitivity_mv_per_g * 1e-3 / STANDARD_GRAVITY
            assert daq_channels[r.key].sensitivity_v_per_unit == pytest.approx(certificate)
            true = tr.true_sensitivity(
                tr.NOMINAL_ACCEL_MV_PER_G,
                tr.ACCEL_TOLERANCE,
                tr.accelerometer_serial(r.physical_channel),
            )
            assert abs(true / tr.NOMINAL_ACCEL_MV_PER_G - 1) <= tr.ACCEL_TOLERANCE
            assert 0 < abs(r.sensitivity_mv_per_g / true - 1) < 0.03
        trues = [
            tr.true_sensitivity(100.0, 0.05, tr.accelerometer_serial(r.physical_channel))
            for r in rf.responses
        ]
        assert np.std(trues) / 100.0 > 0.01  # the transducers differ from each other
    finally:
        rig.close()
