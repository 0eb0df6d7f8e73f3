"""``daq = "uldaq"``: the one-line refusal without MCC's library, and the mapping of the rig
file's channels to uldaq's documented enums (``uldaq/ul_enums.py`` of the installed package,
loaded by path: the package itself needs libuldaq to import)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from dimacq.backends import BACKENDS, lookup
from dimacq.backends.mcc_uldaq import import_uldaq
from dimacq.devices.daq import ChannelConfig
from dimacq.drivers.mcc.uldaq_task import range_volts, scan_plan
from dimacq.errors import DeviceNotFoundError, SetupError


def _ul_enums() -> ModuleType:
    spec = importlib.util.find_spec("uldaq")
    if spec is None or not spec.submodule_search_locations:
        pytest.skip("the uldaq package is not installed (pip install 'dimacq[mcc]')")
    path = Path(next(iter(spec.submodule_search_locations))) / "ul_enums.py"
    enums_spec = importlib.util.spec_from_file_location("_uldaq_enums", path)
    assert enums_spec is not None and enums_spec.loader is not None
    module = importlib.util.module_from_spec(enums_spec)
    enums_spec.loader.exec_module(module)
    return module


def _accel(k: int, range_v: float = 10.0, ua: int = 4000, coupling: str = "AC") -> ChannelConfig:
    return ChannelConfig(k, f"a{k}", "m/s^2", 0.01, range_v, ua, coupling)  # type: ignore[arg-type]


def test_the_table_has_uldaq() -> None:
    assert BACKENDS["daq"]["uldaq"] == "dimacq.backends.mcc_uldaq:open_daq"
    assert callable(lookup("daq", "uldaq"))


def test_missing_package_and_missing_library(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "uldaq", None)
    with pytest.raises(
        SetupError, match=r"package uldaq is not installed; pip install 'dimacq\[mcc\]'"
    ) as e:
        import_uldaq()
    assert "\n" not in str(e.value)
    monkeypatch.delitem(sys.modules, "uldaq")
    if importlib.util.find_spec("uldaq") is None:
        pytest.skip("the uldaq package is not installed (pip install 'dimacq[mcc]')")
    try:
        import_uldaq()
    except DeviceNotFoundError as err:  # the package is here, libuldaq.so is not
        msg = str(err)
        assert "\n" not in msg
        assert "libuldaq is not installed" in msg and "github.com/mccdaq/uldaq" in msg
    else:
        pytest.skip("libuldaq is installed here: its absence cannot be shown")


def test_range_names() -> None:
    ul = _ul_enums()
    volts = {m.name: range_volts(m.name) for m in ul.Range}
    assert volts["BIP10VOLTS"] == 10.0 and volts["BIP1VOLTS"] == 1.0
    assert volts["BIP2PT5VOLTS"] == 2.5 and volts["BIPPT625VOLTS"] == 0.625
    assert volts["BIPPT078VOLTS"] == 0.078 and volts["UNI10VOLTS"] is None
    assert all(v is None or v > 0 for v in volts.values())


def test_dt9837_plan_against_uldaq_enums() -> None:
    """DT9837A (uldaq AiUsb9837x.cpp:29-61, :472-473): 4 single-ended inputs, ±10 V and ±1 V,
    IEPE. Accelerometers on inputs 1 and 3 (IEPE, AC), the hammer on 0 (IEPE, AC)."""
    ul = _ul_enums()
    ranges = [ul.Range.BIP10VOLTS, ul.Range.BIP1VOLTS]
    chans = (_accel(0), _accel(1), _accel(3, coupling="DC", ua=0))
    plan = scan_plan(ul, chans, ranges, n_inputs=4, supports_iepe=True)
    assert (plan.low, plan.high, plan.columns) == (0, 3, [0, 1, 3])
    assert plan.range is ul.Range.BIP10VOLTS
    assert plan.iepe == {0: ul.IepeMode.ENABLED, 1: ul.IepeMode.ENABLED, 3: ul.IepeMode.DISABLED}
    assert plan.coupling == {0: ul.CouplingMode.AC, 1: ul.CouplingMode.AC, 3: ul.CouplingMode.DC}
    assert plan.options == ul.ScanOption.CONTINUOUS  # uldaq.h: SO_CONTINUOUS = 1 << 3
    assert int(plan.options) == 8
    trig = scan_plan(ul, chans, ranges, n_inputs=4, supports_iepe=True, external_trigger=True)
    assert int(trig.options) == (1 << 3) | (1 << 5)  # CONTINUOUS | EXTTRIGGER
    one = scan_plan(ul, (_accel(2, range_v=1.0),), ranges, n_inputs=4, supports_iepe=True)
    assert one.range is ul.Range.BIP1VOLTS and (one.low, one.high) == (2, 2)
    # values of the enums as uldaq documents them (uldaq.h / ul_enums.py)
    assert (int(ul.IepeMode.ENABLED), int(ul.CouplingMode.AC), int(ul.Range.BIP10VOLTS)) == (
        2,
        2,
        5,
    )


def test_plan_refusals_name_the_fix() -> None:
    ul = _ul_enums()
    ranges = [ul.Range.BIP10VOLTS, ul.Range.BIP1VOLTS]
    with pytest.raises(SetupError, match=r"range_v = 5 V; the device offers ±10 V, ±1 V"):
        scan_plan(ul, (_accel(0, range_v=5.0),), ranges, n_inputs=4, supports_iepe=True)
    with pytest.raises(SetupError, match=r"one range; give every channel .* the same range_v"):
        scan_plan(ul, (_accel(0), _accel(1, range_v=1.0)), ranges, n_inputs=4, supports_iepe=True)
    with pytest.raises(SetupError, match=r"physical_channel 4; the device has inputs 0..3"):
        scan_plan(ul, (_accel(4),), ranges, n_inputs=4, supports_iepe=True)
    with pytest.raises(SetupError, match=r"without IEPE excitation; put an IEPE conditioner"):
        scan_plan(ul, (_accel(0),), ranges, n_inputs=8, supports_iepe=False)
    # the USB-1808X through uldaq: voltage inputs, no IEPE settings sent
    plan = scan_plan(ul, (_accel(0, ua=0),), ranges, n_inputs=8, supports_iepe=False)
    assert plan.iepe == {} and plan.coupling == {}
