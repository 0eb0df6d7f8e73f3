"""The NI task on a twin of NI-DAQmx (``tests/_daqmx_twin.py``: nidaqmx's own ``Task``,
channels, timing and reader on an interpreter that behaves as NI documents the modules): the
thesis's set-up (hammer and accelerometers on NI 9234s, a load cell's bridges on an NI 9237,
one task), the rate read back, each module's input delay removed up to NI's published figure,
the sample clock exported; a rate NI-DAQmx chose differently from the plan, and a delay it
cannot remove, refuse the start."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("nidaqmx")

from _daqmx_twin import (
    FILTER_DELAY_ADJUSTMENT,
    REMOVE_FILTER_DELAY,
    SAMP_CLK_OUTPUT_TERM,
    DaqmxTwin,
)

from dimacq.devices.daq import ChannelConfig
from dimacq.drivers.daq_loadcell.driver import ChannelDaq
from dimacq.drivers.ni.modules import CATALOGUE
from dimacq.drivers.ni.plan import ModuleSlot
from dimacq.drivers.ni.task import NiDsaTask
from dimacq.errors import SetupError

DEVICES = {"cDAQ1Mod1": "NI 9234", "cDAQ1Mod2": "NI 9234", "cDAQ1Mod3": "NI 9237"}


def _slots() -> list[ModuleSlot]:
    out = []
    for i, (dev, model) in enumerate(DEVICES.items()):
        s = CATALOGUE[model]
        inputs = tuple(range(4 * i, 4 * i + 4))
        out.append(ModuleSlot(dev, model, inputs, 4, s.iepe_currents_a, s.excitation_v))
    return out


def _thesis_task(twin: DaqmxTwin, **kw: str) -> NiDsaTask:
    task = NiDsaTask(twin.module(), _slots(), **kw)
    task.add_force_channel(0, "hammer", 2.25, iepe_current_ma=2.0)
    for k in range(1, 7):
        task.add_accel_channel(k, f"a{k}", 100.0, iepe_current_ma=2.0)
    for k in range(8, 12):  # the bridges at 5 V: V per mV/V = 5e-3
        task.add_channel(ChannelConfig(k, f"LC501 g{k - 7:02d}", "mV/V", 5e-3, 0.1, 0, "DC"))
    task.configure_timing(2000.0, 256)
    return task


def test_the_thesis_set_up_runs_at_the_read_back_rate_with_delays_removed() -> None:
    twin = DaqmxTwin(DEVICES)
    task = _thesis_task(twin, sample_clock_out="/cDAQ1/PFI1", start_trigger="/cDAQ1/PFI0")
    assert isinstance(task, ChannelDaq)  # the load cell's gauges as DAQ inputs ("daq-channels")
    assert task.sample_rate_hz == 2048.0  # read back from the committed task, before start
    task.start()
    try:
        (t,) = twin.tasks.values()
        assert t.export[SAMP_CLK_OUTPUT_TERM] == "/cDAQ1/PFI1" and t.trigger == "/cDAQ1/PFI0"
        assert [c.kind for c in t.chans] == ["force"] + ["accel"] * 6 + ["bridge"] * 4
        assert all(c.attrs[REMOVE_FILTER_DELAY] for c in t.chans)
        adj = {c.name: c.attrs[FILTER_DELAY_ADJUSTMENT] for c in t.chans}
        # the twin's filter delay is the digital part: the rest of NI's figure is the analogue one
        assert adj["hammer"] == pytest.approx(3e-6, abs=1e-12)
        assert adj["LC501 g01"] == pytest.approx(4.5e-6, abs=1e-12)
        daqmx, published = task.filter_delays_s["LC501 g01"]
        assert daqmx == pytest.approx((40 + 5 / 512) / 2048)
        assert published == pytest.approx((40 + 5 / 512) / 2048 + 4.5e-6)
        block = task.read(512, timeout_s=1.0)
        assert block.sample_rate_hz == 2048.0 and block.data.shape == (11, 512)
        assert block.units[0] == "N" and block.units[-1] == "mV/V"
        assert block.data[0, 0] == 1.0 and block.data[-1, -1] == 512.0
    finally:
        task.stop()
    assert task.samples_clocked == 512


def test_the_rate_ni_daqmx_chose_is_the_one_used(caplog: pytest.LogCaptureFixture) -> None:
    """NI-DAQmx puts the 9237's 12.8 MHz timebase in charge: 50000/24 = 2083.33 Hz for 2048 Hz
    asked, not the plan's 2048 Hz; the read-back labels everything."""
    twin = DaqmxTwin(DEVICES, master="cDAQ1Mod3")
    task = _thesis_task(twin)
    task.configure_timing(2048.0)
    assert task.sample_rate_hz == pytest.approx(50000 / 24)
    assert "where the plan (cDAQ1Mod1's timebase) said 2048 Hz" in caplog.text
    task.start()
    try:
        assert task.read(16, timeout_s=1.0).sample_rate_hz == pytest.approx(50000 / 24)
    finally:
        task.close()


def test_a_rate_that_changed_after_it_was_reported_refuses_the_start() -> None:
    twin = DaqmxTwin(DEVICES)  # NI's default: a 9234's timebase when the task has one
    task = NiDsaTask(twin.module(), _slots())
    task.add_channel(ChannelConfig(8, "LC501 g01", "mV/V", 5e-3, 0.1, 0, "DC"))
    task.configure_timing(2048.0)
    assert task.sample_rate_hz == pytest.approx(50000 / 24)  # a 9237 alone: its 12.8 MHz
    task.add_force_channel(0, "hammer", 2.25, iepe_current_ma=2.0)  # now a 9234 leads
    with pytest.raises(SetupError, match=r"runs the modules at 2048 Hz, but 2083.33 Hz was rep"):
        task.start()
    assert not task.running
    assert all(t.state == "cleared" for t in twin.tasks.values())  # nothing left reserved


def test_a_delay_ni_daqmx_cannot_remove_refuses_the_start() -> None:
    twin = DaqmxTwin(DEVICES, no_delay_removal=("cDAQ1Mod3",))
    task = _thesis_task(twin)
    with pytest.raises(
        SetupError, match=r"does not remove the filter delay of cDAQ1Mod3/ai\d \(NI 9237"
    ):
        task.start()
    # modules of one family, none removed: their delays are equal and cancel in the FRFs
    twin2 = DaqmxTwin(DEVICES, no_delay_removal=("cDAQ1Mod1", "cDAQ1Mod2"))
    task2 = NiDsaTask(twin2.module(), _slots())
    task2.add_force_channel(0, "hammer", 2.25, iepe_current_ma=2.0)
    task2.add_accel_channel(4, "a4", 100.0, iepe_current_ma=2.0)
    task2.configure_timing(2048.0)
    task2.start()
    task2.stop()


def _rig_for_the_cdaq(tmp_path: Path) -> Path:
    """The shipped rig with what the modules offer (2 mA, 5 V) and its [[daq.modules]]."""
    import shutil

    shipped = Path(__file__).resolve().parents[3] / "config"
    shutil.copytree(shipped / "calibrations", tmp_path / "calibrations")
    text = (shipped / "rig.toml").read_text(encoding="utf-8")
    text = text.replace("iepe_current_ma = 4.0", "iepe_current_ma = 2.0")
    text = text.replace("excitation_v = 10 ", "excitation_v = 5.0 ")
    text = text.replace("range_v = 10.0", "range_v = 5.0")
    modules = [("NI 9234", list(range(4 * i, min(4 * i + 4, 25)))) for i in range(7)]
    modules += [("NI 9237", list(range(25 + 4 * j, 29 + 4 * j))) for j in range(3)]
    table = "".join(
        f'[[daq.modules]]\nname = "cDAQ1Mod{i + 1}"\nmodel = "{m}"\ninputs = {inputs}\n'
        for i, (m, inputs) in enumerate(modules)
    )
    rig = tmp_path / "rig.toml"
    rig.write_text(text.replace("[[hammers]]", table + "\n[[hammers]]", 1), encoding="utf-8")
    return rig


def test_daq_channels_on_nidaqmx_build_the_thesis_rig(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``loadcell = "daq-channels"`` on ``daq = "nidaqmx"``: the load cell's 12 bridges on the
    NI 9237s in the task of the hammer and the 24 accelerometers (one task, one timebase)."""
    from dimacq.backends import ni_daqmx
    from dimacq.config import load_settings
    from dimacq.drivers.daq_loadcell.driver import DaqSplitter
    from dimacq.services.acquisition import rig as rig_builder
    from dimacq.simulators.lab.scenarios import build_scenario

    devices = {f"cDAQ1Mod{i + 1}": "NI 9234" for i in range(7)}
    devices.update({f"cDAQ1Mod{8 + j}": "NI 9237" for j in range(3)})
    twin = DaqmxTwin(devices)
    monkeypatch.setattr(ni_daqmx, "import_nidaqmx", twin.module)
    settings = load_settings(
        data_dir=tmp_path / "data",
        token="t",
        daq="nidaqmx",
        loadcell="daq-channels",
        rig_file=str(_rig_for_the_cdaq(tmp_path)),
        daq_ni_sample_clock_out="/cDAQ1/PFI1",
    )
    setup = build_scenario(settings.scenario).model.setup
    rig = rig_builder.build_rig(settings, setup, {})
    try:
        assert isinstance(rig.daq, DaqSplitter) and isinstance(rig.daq.inner, NiDsaTask)
        task = rig.daq.inner
        physical = {c.request.name: c.physical for c in task.planned}
        assert physical["hammer ch0"] == "cDAQ1Mod1/ai0"
        assert physical["8+Z"] == "cDAQ1Mod7/ai0"
        assert (
            physical["LC501 g01"] == "cDAQ1Mod8/ai0" and physical["LC501 g12"] == "cDAQ1Mod10/ai3"
        )
        assert rig.daq.sample_rate_hz == 2048.0
        assert [s.model for s in task.slots] == ["NI 9234"] * 7 + ["NI 9237"] * 3
        assert task.sample_clock_out == "/cDAQ1/PFI1"
    finally:
        rig.close()


def test_a_module_that_is_not_the_rig_files_model_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from dimacq.backends import ni_daqmx
    from dimacq.config import load_settings
    from dimacq.services.acquisition import rig as rig_builder

    devices = {f"cDAQ1Mod{i + 1}": "NI 9234" for i in range(10)}  # no 9237 in slot 8
    monkeypatch.setattr(ni_daqmx, "import_nidaqmx", DaqmxTwin(devices).module)
    settings = load_settings(
        data_dir=tmp_path / "data",
        token="t",
        daq="nidaqmx",
        rig_file=str(_rig_for_the_cdaq(tmp_path)),
    )
    with pytest.raises(
        SetupError, match=r"daq.modules.7: cDAQ1Mod8 is an NI 9234, not the NI 9237"
    ):
        rig_builder.check_devices(settings, "daq")
