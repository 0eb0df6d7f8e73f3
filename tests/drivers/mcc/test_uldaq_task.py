"""``daq = "uldaq"``: the one-line refusal without MCC's library, and the mapping of the rig
file's channels to uldaq's documented enums (``uldaq/ul_enums.py`` of the installed package,
loaded by path: the package itself needs libuldaq to import)."""

from __future__ import annotations

import ctypes
import importlib.util
import sys
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import pytest

from dimacq.backends import BACKENDS, lookup
from dimacq.backends.mcc_uldaq import import_uldaq
from dimacq.devices.daq import ChannelConfig
from dimacq.drivers.mcc.uldaq_task import UldaqTask, range_volts, scan_plan
from dimacq.errors import DeviceNotFoundError, DeviceStateError, SetupError


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


class _FakeAi:
    """uldaq's AiDevice as its docs describe it (ai_device.py): a_in_scan fills the circular
    buffer scan-major and returns the actual rate; get_scan_status gives current_total_count."""

    def __init__(self, ul: ModuleType, actual_rate: float | None = None) -> None:
        self.ul, self.actual_rate, self.calls = ul, actual_rate, []
        self.total = 0
        self.buffer: Any = None
        self.n_scan = 0

    def get_info(self) -> Any:
        ul = self.ul

        class Info:
            def get_num_chans(self) -> int:
                return 4

            def supports_iepe(self) -> bool:
                return True

            def get_ranges(self, mode: Any) -> list[Any]:
                assert mode == ul.AiInputMode.SINGLE_ENDED
                return [ul.Range.BIP10VOLTS, ul.Range.BIP1VOLTS]

        return Info()

    def get_config(self) -> Any:
        calls = self.calls

        class Config:
            def __getattr__(self, name: str) -> Any:
                return lambda *a: calls.append((name, *a))

        return Config()

    def a_in_scan(self, low, high, mode, rng, n, rate, options, flags, buf):  # type: ignore[no-untyped-def]
        self.calls.append(("a_in_scan", low, high, mode, rng, n, rate, options, flags))
        self.buffer, self.n_scan = buf, high - low + 1
        return rate if self.actual_rate is None else self.actual_rate

    def clock(self, scans: int) -> None:
        """The device puts ``scans`` more scans in the buffer: input k holds 0.1·k + scan/1e4 V."""
        assert self.buffer is not None
        cap = len(self.buffer) // self.n_scan
        for s in range(self.total // self.n_scan, self.total // self.n_scan + scans):
            for k in range(self.n_scan):
                self.buffer[(s % cap) * self.n_scan + k] = 0.1 * k + s / 1e4
        self.total += scans * self.n_scan

    def get_scan_status(self) -> Any:
        class Xfer:
            current_total_count = self.total

        return self.ul.ScanStatus.RUNNING, Xfer()

    def scan_stop(self) -> None:
        self.calls.append(("scan_stop",))

    def set_trigger(self, *a: Any) -> None:
        self.calls.append(("set_trigger", *a))


def _fake_ul(ai: _FakeAi) -> Any:
    ul = ai.ul

    class Desc:
        product_name, unique_id = "DT9837A", "1F2E3D"

    class Device:
        def get_ai_device(self) -> _FakeAi:
            return ai

        def get_descriptor(self) -> Desc:
            return Desc()

    ns = SimpleNamespace(**{k: getattr(ul, k) for k in dir(ul) if not k.startswith("_")})
    ns.create_float_buffer = lambda n_ch, n: (ctypes.c_double * (n_ch * n))()  # as uldaq's
    return ns, Device()


def test_task_reads_the_circular_buffer_in_volts_and_units() -> None:
    ul = _ul_enums()
    ai = _FakeAi(ul)
    fake, device = _fake_ul(ai)
    task = UldaqTask(fake, device, external_trigger=True)
    task.add_accel_channel(1, "a1", 100.0)  # 100 mV/g
    task.add_force_channel(3, "hammer", 2.25)  # 2.25 mV/N
    task.configure_timing(1000.0, 64)
    task.start()
    assert ("set_trigger", ul.TriggerType.POS_EDGE, 0, 0.0, 0.0, 0) in ai.calls
    scan = next(c for c in ai.calls if c[0] == "a_in_scan")
    assert scan[1:5] == (1, 3, ul.AiInputMode.SINGLE_ENDED, ul.Range.BIP10VOLTS)
    assert int(scan[7]) == (1 << 3) | (1 << 5) and scan[6] == 1000.0
    assert ("set_chan_iepe_mode", 1, ul.IepeMode.ENABLED) in ai.calls
    assert ("set_chan_coupling_mode", 3, ul.CouplingMode.AC) in ai.calls
    cap = len(ai.buffer) // 3  # type: ignore[arg-type]
    ai.clock(cap - 10)
    first = task.read(cap - 10)
    ai.clock(30)  # wraps around the circular buffer
    block = task.read(30)
    s = np.arange(cap - 10, cap + 20)
    assert block.first_sample == cap - 10
    assert block.data[0] == pytest.approx((0.0 + s / 1e4) / (0.1 / 9.80665))
    assert block.data[1] == pytest.approx((0.2 + s / 1e4) / 2.25e-3)
    assert first.data.shape == (2, cap - 10)
    ai.clock(cap + 1)  # the host is later than the buffer holds
    with pytest.raises(DeviceStateError, match="fell 1 scans behind"):
        task.read(1)
    assert task.identify().model == "DT9837A"


def test_task_refuses_a_coerced_rate() -> None:
    ul = _ul_enums()
    ai = _FakeAi(ul, actual_rate=1002.5)
    fake, device = _fake_ul(ai)
    task = UldaqTask(fake, device)
    task.add_accel_channel(0, "a0", 100.0)
    task.configure_timing(1000.0)
    with pytest.raises(SetupError, match=r"scans at 1002.5 Hz instead; set sample_rate_hz"):
        task.start()
    assert ai.calls[-1] == ("scan_stop",)
