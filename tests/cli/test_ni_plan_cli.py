"""``dimacq devices plan --daq nidaqmx``: the NI cDAQ plan of a rig file printed without
hardware, with nidaqmx installed but no NI-DAQmx (the CI case) and without the package."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from dimacq.cli.main import main

SHIPPED = Path(__file__).resolve().parents[2] / "config" / "rig.toml"


@pytest.mark.parametrize("package", [True, False], ids=["nidaqmx-installed", "no-nidaqmx"])
def test_the_shipped_rig_is_planned_and_its_refusals_named(
    package: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    if not package:
        monkeypatch.setitem(sys.modules, "nidaqmx", None)
    out = tmp_path / "plan.json"
    rc = main(
        ["devices", "plan", "--daq", "nidaqmx", "--rig-file", str(SHIPPED), "--json", str(out)]
    )
    printed = capsys.readouterr().out
    assert rc == 1  # the shipped rig asks 4 mA, ±10 V and 10 V: refused, each with its fix
    assert "rate: asked 2048 Hz -> 2048 Hz (fM 13.1072 MHz of cDAQ1Mod1 / 256 / 25)" in printed
    assert "hammers.0 .. responses.23 (25): iepe_current_ma = 4 mA: NI 9234 offers 2 mA" in printed
    assert "excitation_v = 10 V: NI 9237 offers internal excitation of 2, 2.5, 3.3, 5 V" in printed
    assert "responses.0 .. responses.23 (24): range_v = 10 V: NI 9234 measures ±5 V" in printed
    plan = json.loads(out.read_text())
    assert [m["model"] for m in plan["modules"]] == ["NI 9234"] * 7 + ["NI 9237"] * 3
    assert len(plan["channels"]) == 37
    gauge = next(c for c in plan["channels"] if c["input"] == 25)
    assert gauge["physical"] == "cDAQ1Mod8/ai0"
    assert gauge["delay_s"] == pytest.approx((40 + 5 / 512) / 2048 + 4.5e-6)


def test_a_rig_the_modules_accept_plans_ok(tmp_path: Path, capsys) -> None:
    text = SHIPPED.read_text(encoding="utf-8")
    text = text.replace("iepe_current_ma = 4.0", "iepe_current_ma = 2.0")
    text = text.replace("excitation_v = 10 ", "excitation_v = 5.0 ")
    text = text.replace("range_v = 10.0", "range_v = 5.0")
    modules = "".join(
        f'[[daq.modules]]\nname = "cDAQ1Mod{i + 1}"\nmodel = "NI 9234"\n'
        f"inputs = {list(range(4 * i, min(4 * i + 4, 25)))}\n"
        for i in range(7)
    ) + "".join(
        f'[[daq.modules]]\nname = "cDAQ1Mod{8 + j}"\nmodel = "NI 9237"\n'
        f"inputs = {list(range(25 + 4 * j, 29 + 4 * j))}\n"
        for j in range(3)
    )
    text = text.replace("[[hammers]]", modules + "\n[[hammers]]", 1)
    rig = tmp_path / "rig.toml"
    rig.write_text(text, encoding="utf-8")
    (tmp_path / "calibrations").mkdir()
    assert main(["devices", "plan", "--daq", "nidaqmx", "--rig-file", str(rig)]) == 0
    printed = capsys.readouterr().out
    assert "modules:\n  cDAQ1Mod1: NI 9234, inputs 0..3 on ai0..ai3 (of 4 AI)" in printed
    assert "  cDAQ1Mod7: NI 9234, input 24 on ai0 (of 4 AI)" in printed
    assert (
        " 25 LC501 g01      cDAQ1Mod8/ai0   bridge  full bridge, mV/V, internal excitation 5 V"
        in printed
    )
    assert "ok: nothing in the plan is refused" in printed


def test_modules_and_units_together_are_refused() -> None:
    from dimacq.errors import SetupError
    from dimacq.io.rig_file import parse_rig_text

    text = (
        '[daq]\nsample_rate_hz = 2048.0\nunits = ["cDAQ1Mod1"]\n'
        '[[daq.modules]]\nname = "cDAQ1Mod1"\nmodel = "NI 9234"\n'
    )
    with pytest.raises(SetupError, match=r"either as units .* or as \[\[daq\.modules\]\]"):
        parse_rig_text(text, "rig.toml")
    bad = (
        '[daq]\nsample_rate_hz = 2048.0\n[[daq.modules]]\nname = "M"\nmodel = "NI 9234"\n'
        "inputs = [1, 1]\n"
    )
    with pytest.raises(SetupError, match=r"daq\.modules\.0\.inputs"):
        parse_rig_text(bad, "rig.toml")
