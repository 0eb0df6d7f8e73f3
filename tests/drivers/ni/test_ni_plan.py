"""The NI cDAQ plan against NI's published figures: data rates ``fs = (fM/256)/n`` coerced up,
input delays, the IEPE current and bridge excitation a module offers, and the task's rate on a
shared timebase. Sources: NI KB kA00Z0000004A0YSAU ("Calculate the Input Delay on NI-9237":
fs = (fM/256)/n, n = 1..31, fM = 12.8 MHz, coerced up; n = 25 -> 2 kS/s, input delay
0.0200094 s); NI 9144 User Guide, "NI 9237 Example Data Rates" (Table 52); NI-9234
Specifications (fM 13.1072 MHz, 1.652 .. 51.2 kS/s); NI USB-9234 User Guide ("51.2 kS/s,
25.6 kS/s, 17.067 kS/s, ... down to 1.652 kS/s"); NI CompactRIO manual, "NI 9234 maximum sample
rate when synchronizing multiple modules" (50 kS/s on a 9237's timebase); NI 9234 Operating
Instructions, Figure 4 ("2 mA IEPE on/off")."""

from __future__ import annotations

import pytest

from dimacq.drivers.ni.modules import CATALOGUE, coerce_rate, input_delay_s, module_spec
from dimacq.drivers.ni.plan import (
    ChannelRequest,
    ModuleSlot,
    catalogue_slots,
    make_plan,
    place,
    propose_modules,
    task_rate,
)
from dimacq.drivers.ni.task import NiDsaTask
from dimacq.errors import SetupError

N9234 = CATALOGUE["NI 9234"]
N9237 = CATALOGUE["NI 9237"]


def test_9237_rates_are_the_manuals_table() -> None:
    """NI 9144 User Guide, Table 52 (12.8 MHz clock): data rate and clock divisor."""
    table = {
        50000.0: 1,
        25000.0: 2,
        16666.667: 3,
        12500.0: 4,
        10000.0: 5,
        6250.0: 8,
        5000.0: 10,
        3333.333: 15,
        2500.0: 20,
        2000.0: 25,
    }
    for rate, n in table.items():
        # the table's figures are rounded to 1 S/s: ask a hair below, get the exact rate
        got, n_got = coerce_rate(N9237, rate - 1e-3)
        assert n_got == n and got == pytest.approx(rate, abs=1e-3)


def test_9237_input_delay_is_the_kb_example() -> None:
    """KB kA00Z0000004A0YSAU: fM 12.8 MHz, n = 25 -> 2 kS/s, input delay 0.0200094 s."""
    rate, n = coerce_rate(N9237, 2000.0)
    assert (rate, n) == (2000.0, 25)
    assert input_delay_s(N9237, rate) == pytest.approx(0.0200094, abs=5e-8)


def test_9234_rates_coerce_up_within_its_published_range() -> None:
    # 51.2 kS/s, 25.6 kS/s, 17.067 kS/s, ... down to 1.652 kS/s (NI USB-9234 User Guide)
    assert coerce_rate(N9234, 51200.0) == (51200.0, 1)
    assert coerce_rate(N9234, 25600.0) == (25600.0, 2)
    assert coerce_rate(N9234, 17000.0)[0] == pytest.approx(17066.667, abs=1e-3)
    assert coerce_rate(N9234, 2048.0) == (2048.0, 25)
    # between two rates: up to the next one (2000 Hz asked -> 2048 Hz)
    assert coerce_rate(N9234, 2000.0) == (2048.0, 25)
    # below the lowest: the lowest, 1.652 kS/s (n = 31)
    low, n = coerce_rate(N9234, 1000.0)
    assert n == 31 and low == pytest.approx(1652.0, abs=0.5)
    with pytest.raises(SetupError, match=r"sample_rate_hz = 60000 Hz: the NI 9234 runs at most"):
        coerce_rate(N9234, 60000.0)


def test_9234_on_a_9237_timebase_tops_at_50_kS_s() -> None:
    """CompactRIO manual: a 9234 slaved to a 9237's master timebase runs at most 50 kS/s."""
    assert coerce_rate(N9234, 50000.0, N9237.timebase_hz) == (50000.0, 1)
    with pytest.raises(SetupError, match="runs at most 50000 Hz"):
        coerce_rate(N9234, 51200.0, N9237.timebase_hz)


def test_9234_delay_figure() -> None:
    assert input_delay_s(N9234, 2048.0) == pytest.approx(38.4 / 2048.0 + 3e-6, rel=1e-12)


def test_catalogue_names() -> None:
    assert module_spec("NI-9234") is N9234 and module_spec("ni9237") is N9237
    assert module_spec("NI 9250") is None  # no published figures were found for it


def _slot(model: str, inputs: tuple[int, ...], device: str = "cDAQ1Mod1") -> ModuleSlot:
    s = CATALOGUE[model]
    return ModuleSlot(device, model, inputs, s.n_channels, s.iepe_currents_a, s.excitation_v)


def test_the_plan_refuses_4_mA_on_a_2_mA_device() -> None:
    slot = _slot("NI 9234", (0, 1, 2, 3))
    req = ChannelRequest(1, "1+X", "accel", "responses.0", iepe_current_ma=4.0)
    with pytest.raises(SetupError) as e:
        place(req, [slot])
    msg = str(e.value)
    assert "iepe_current_ma = 4 mA: NI 9234 offers 2 mA (or off)" in msg
    assert "set iepe_current_ma = 2 (or 0 = off)" in msg
    # what it offers is taken (2.1 mA asked: the 2 mA within 10 %), 0 turns IEPE off
    assert place(ChannelRequest(1, "a", "accel", iepe_current_ma=2.1), [slot]).iepe_current_a == (
        2e-3
    )
    assert place(ChannelRequest(1, "a", "accel", iepe_current_ma=0.0), [slot]).iepe_current_a == 0
    with pytest.raises(SetupError, match="AC coupling only; set coupling = 'AC'"):
        place(ChannelRequest(1, "a", "accel", iepe_current_ma=2.0, coupling="DC"), [slot])
    # the 9234 measures ±5 V (NI 9144 User Guide, "NI 9234 Calibration Data"): every field
    # refused is named
    with pytest.raises(SetupError) as e:
        place(ChannelRequest(1, "a", "accel", iepe_current_ma=4.0, range_v=10.0), [slot])
    assert "range_v = 10 V: NI 9234 measures ±5 V; set range_v = 5" in str(e.value)
    assert "; and iepe_current_ma = 4 mA" in str(e.value)


def test_the_plan_refuses_an_excitation_the_9237_does_not_offer() -> None:
    slot = _slot("NI 9237", (25, 26, 27, 28), "cDAQ1Mod8")
    with pytest.raises(SetupError, match=r"excitation_v = 10 V: NI 9237 offers internal excit"):
        place(ChannelRequest(25, "g01", "bridge", excitation_v=10.0), [slot])
    got = place(ChannelRequest(26, "g02", "bridge", excitation_v=5.0), [slot])
    assert (got.physical, got.excitation_v) == ("cDAQ1Mod8/ai1", 5.0)
    with pytest.raises(SetupError, match="needs an IEPE module"):
        place(ChannelRequest(27, "x", "accel", iepe_current_ma=2.0), [slot])
    with pytest.raises(SetupError, match="needs a bridge module"):
        place(ChannelRequest(0, "x", "bridge", excitation_v=5.0), [_slot("NI 9234", (0,))])


def test_the_plan_reports_the_coerced_rate_and_the_delays() -> None:
    """9234 masters the timebase: 2000 Hz asked -> 2048 Hz for every module, whatever the order
    of the modules (NI KB "Valid Sampling Rates for the NI 9233, NI 9234, and NI 9237": "If you
    have a 9233 or 9237 in a task with a 9234 it will run at the 9234 rates by default"); the
    9237 alone: 2048 Hz asked -> 50000/24 = 2083.33 Hz."""
    reqs = [
        ChannelRequest(0, "hammer", "force", "hammers.0", 2.0),
        ChannelRequest(1, "1+X", "accel", "responses.0", 2.0),
        ChannelRequest(4, "g01", "bridge", "load_cells.0", excitation_v=2.5),
    ]
    slots = [_slot("NI 9234", (0, 1, 2, 3)), _slot("NI 9237", (4, 5, 6, 7), "cDAQ1Mod2")]
    plan = make_plan(reqs, slots, 2000.0)
    assert plan.ok and plan.rate_hz == 2048.0 and plan.timebase_device == "cDAQ1Mod1"
    d = {c.request.name: c.delay_s for c in plan.channels}
    assert d["hammer"] == pytest.approx(38.4 / 2048 + 3e-6)
    assert d["g01"] == pytest.approx((40 + 5 / 512) / 2048 + 4.5e-6)
    assert plan.delay_spread_s() == pytest.approx((40 + 5 / 512 - 38.4) / 2048 + 1.5e-6)
    rate, fm, master = task_rate(list(reversed(slots)), 2048.0)
    assert (rate, fm, master.device) == (2048.0, 13.1072e6, "cDAQ1Mod1")
    bridges_first = make_plan(list(reversed(reqs)), list(reversed(slots)), 2000.0)
    assert (bridges_first.rate_hz, bridges_first.timebase_device) == (2048.0, "cDAQ1Mod1")
    rate, fm, master = task_rate(slots[1:], 2048.0)
    assert (round(rate, 6), fm, master.device) == (round(50000 / 24, 6), 12.8e6, "cDAQ1Mod2")


def test_the_task_refuses_4_mA_and_reports_the_coerced_rate_without_the_driver() -> None:
    """The task places its channels with the plan: no nidaqmx needed until it is built."""
    slots = [_slot("NI 9234", (0, 1, 2, 3)), _slot("NI 9237", (4, 5, 6, 7), "cDAQ1Mod2")]
    task = NiDsaTask(None, slots)
    with pytest.raises(SetupError, match=r"iepe_current_ma = 4 mA: NI 9234 offers 2 mA"):
        task.add_accel_channel(1, "1+X", 100.0, iepe_current_ma=4.0)
    task.add_force_channel(0, "hammer", 2.25, iepe_current_ma=2.0)
    task.add_accel_channel(1, "1+X", 100.0, iepe_current_ma=2.0)
    from dimacq.devices.daq import ChannelConfig

    task.add_channel(ChannelConfig(4, "LC501 g01", "mV/V", 5e-3, 0.1, 0, "DC"))  # 5 V bridges
    with pytest.raises(SetupError, match=r"excitation_v = 10 V"):
        task.add_channel(ChannelConfig(5, "LC501 g02", "mV/V", 10e-3, 0.1, 0, "DC"))
    task.configure_timing(2000.0)
    assert task.sample_rate_hz == 2048.0  # what every block and FRF line is labelled with
    assert [c.physical for c in task.planned] == ["cDAQ1Mod1/ai0", "cDAQ1Mod1/ai1", "cDAQ1Mod2/ai0"]


def test_proposed_modules_of_the_shipped_numbering() -> None:
    """Hammer 0, accelerometers 1..24, gauges 25..36: seven 9234s (the last with input 24
    alone) and three 9237s."""
    reqs = [ChannelRequest(k, f"a{k}", "accel", iepe_current_ma=2.0) for k in range(25)]
    reqs += [ChannelRequest(k, f"g{k}", "bridge", excitation_v=5.0) for k in range(25, 37)]
    slots = propose_modules(reqs)
    assert [s.model for s in slots] == ["NI 9234"] * 7 + ["NI 9237"] * 3
    assert slots[6].inputs == (24,) and slots[7].inputs == (25, 26, 27, 28)
    plan = make_plan(reqs, slots, 2048.0)
    assert plan.ok and plan.rate_hz == 2048.0


def test_catalogue_slots_number_on_and_refuse_overlaps() -> None:
    slots = catalogue_slots([("M1", "NI 9234", []), ("M2", "NI 9237", [])])
    assert slots[1].inputs == (4, 5, 6, 7)
    with pytest.raises(SetupError, match="both carry input"):
        catalogue_slots([("M1", "NI 9234", []), ("M2", "NI 9237", [3, 4])])
    with pytest.raises(SetupError, match="not in the catalogue"):
        catalogue_slots([("M1", "NI 9250", [])])


def test_every_catalogue_figure_and_its_source() -> None:
    """Each figure of the catalogue against the NI document it comes from:

    - NI 9234: NI-9234 Specifications, Table 2 (internal master timebase 13.1072 MHz) and
      Table 3 (data rate 1.652 .. 51.2 kS/s internal, 0.391 .. 52.734 kS/s external timebase);
      NI USB-9234 User Guide, "Understanding NI USB-9234 Data Rates" (``n`` 1 .. 31); NI 9234
      Operating Instructions, Figure 4 (2 mA IEPE on/off); NI 9144 User Guide, "NI 9234
      Calibration Data" (±5 V); NI KB "Valid Sampling Rates for the NI 9233, NI 9234, and
      NI 9237" (a 9237 in a task with a 9234 runs at the 9234's rates). Its input delay
      ``38.4/fs + 3 µs`` is the one figure not found in NI's pages (see the manual).
    - NI 9237: NI KB kA00Z0000004A0YSAU (12.8 MHz, ``n`` 1 .. 31, input delay
      ``(40 + 5/512)/fs + 4.5 µs``); NI 9144 User Guide, "NI 9237 Example Data Rates" (data
      rate between 391 S/s and 52.734 kS/s).
    """
    n34, n37 = CATALOGUE["NI 9234"], CATALOGUE["NI 9237"]
    assert (n34.timebase_hz, n34.max_rate_hz, n34.n_max) == (13.1072e6, 51200.0, 31)
    assert n34.ext_rate_range_hz == (391.0, 52734.0)
    assert n34.timebase_hz / 256 / n34.n_max == pytest.approx(1652.0, abs=0.5)
    assert (n34.iepe_currents_a, n34.range_v, n34.kind, n34.n_channels) == ((2e-3,), 5.0, "iepe", 4)
    assert (n34.delay_samples, n34.analog_delay_s) == (38.4, 3e-6)
    assert n34.leads_mixed_task and not n37.leads_mixed_task
    assert (n37.timebase_hz, n37.max_rate_hz, n37.n_max) == (12.8e6, 50000.0, 31)
    assert n37.ext_rate_range_hz == (391.0, 52734.0)
    assert (n37.delay_samples, n37.analog_delay_s) == (40 + 5 / 512, 4.5e-6)
    assert (n37.kind, n37.n_channels, n37.iepe_currents_a) == ("bridge", 4, ())
    # a 9237 on the 9234's 13.1072 MHz (NI's default in a mixed task) stays in its range
    assert coerce_rate(n37, 51200.0, n34.timebase_hz) == (51200.0, 1)
    assert coerce_rate(n37, 2000.0, n34.timebase_hz) == (2048.0, 25)
