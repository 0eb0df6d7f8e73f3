"""``loadcell = "cia404"`` / ``"cia404-simulated"``, and the CAN configuration items of the real
backends: python-can's own configuration, interface options and bit timing passed through,
``virtual`` refused with a real backend, one-line errors for a misconfigured interface, a missing
adapter library and a node that is not the EDS's device."""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from dimacq.backends import BACKENDS, is_simulated, lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import load_settings
from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.services.acquisition import rig as rig_builder
from dimacq.simulators.cia404.node import Cia404NodeSim
from dimacq.simulators.lab.scenarios import build_scenario


def test_cia404_entries_are_in_the_table() -> None:
    assert {"cia404", "cia404-simulated"} <= set(BACKENDS["loadcell"])
    assert is_simulated("loadcell", "cia404-simulated") and not is_simulated("loadcell", "cia404")


def test_devices_check_through_the_generic_eds(tmp_path: Path) -> None:
    settings = load_settings(data_dir=tmp_path, token="t", loadcell="cia404-simulated")
    got = rig_builder.check_devices(settings, "loadcell")
    cell = got["load_cells"]["501"]
    assert got["backend"] == "cia404-simulated"
    assert (cell["node_id"], cell["serial_number"], cell["n_gauges"]) == (1, 501, 12)
    assert "(0x6130) in 6 TPDOs" in cell["firmware"]


@pytest.mark.slow
def test_an_impact_test_through_cia404_simulated(tmp_path: Path) -> None:
    """Two inputs, two averages: every average accepted, the load cell's six reactions present
    and finite (the same world and strikes as the native amplifier are checked against the
    source itself in tests/simulators/cia404)."""
    settings = load_settings(data_dir=tmp_path, token="t", loadcell="cia404-simulated")
    setup = build_scenario(settings.scenario).model.setup
    setup = setup.model_copy(update={"excitations": setup.excitations[:2]})
    cfg = {"averages_per_input": 2, "record_samples": 2048, "seed": 4}
    rig = rig_builder.build_rig(settings, setup, cfg)
    rejected: list[Any] = []
    try:
        res = rig_builder.run_impact_test(
            rig,
            setup,
            cfg,
            on_average=lambda i, k, ok, reasons, *a: rejected.append(reasons) if not ok else None,
            on_progress=lambda f, m: None,
        )
    finally:
        rig.close()
    assert not rejected
    assert res.H.shape[1] == 24 + 6 and np.isfinite(res.H).all()


def _real(tmp_path: Path, **kw: Any) -> Any:
    return load_settings(data_dir=tmp_path, token="t", **kw)


@pytest.mark.parametrize("backend", ["canopen", "cia404", "dimacq-can", "netft-can"])
def test_virtual_is_refused_with_a_real_backend(tmp_path: Path, backend: str) -> None:
    settings = _real(tmp_path, loadcell=backend, loadcell_interface="virtual")
    with pytest.raises(SetupError) as err:
        rig_builder.check_devices(settings, "loadcell")
    msg = str(err.value)
    assert "\n" not in msg and "'virtual'" in msg and f"'{backend}-simulated'" in msg


def test_python_cans_own_configuration_is_honoured(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``loadcell_interface = ""``: CAN_INTERFACE / CAN_CHANNEL as ``can.Bus()`` reads them."""
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    settings = _real(tmp_path, loadcell="canopen")
    with pytest.raises(SetupError, match="python-can's configuration gives interface 'virtual'"):
        rig_builder.check_devices(settings, "loadcell")
    monkeypatch.setenv("CAN_INTERFACE", "nosuchbus")
    with pytest.raises(DeviceNotFoundError, match="unknown python-can interface") as err:
        rig_builder.check_devices(settings, "loadcell")
    assert "nosuchbus" in str(err.value) and "\n" not in str(err.value)


def test_options_and_bit_timing_reach_the_bus(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from dimacq.backends.can_bus import open_can_bus

    opened: list[dict[str, Any]] = []
    real_bus = can.Bus

    def recording_bus(**kw: Any) -> Any:
        opened.append(kw)
        return real_bus(interface="virtual", channel=kw["channel"])

    monkeypatch.setattr(can, "Bus", recording_bus)
    monkeypatch.setattr("can.interfaces.VALID_INTERFACES", {"pcan", "virtual"})
    timing = {"f_clock": 8_000_000, "brp": 1, "tseg1": 5, "tseg2": 2, "sjw": 1}
    settings = _real(
        tmp_path,
        loadcell="cia404",
        loadcell_interface="pcan",
        loadcell_can_options={"device_id": 3, "auto_reset": True},
        loadcell_can_bit_timing=timing,
    )
    open_can_bus(settings, backend="cia404", channel="PCAN_USBBUS1", bitrate=1_000_000).shutdown()
    (kw,) = opened
    assert (kw["interface"], kw["channel"], kw["device_id"], kw["auto_reset"]) == (
        "pcan",
        "PCAN_USBBUS1",
        3,
        True,
    )
    assert "bitrate" not in kw and kw["timing"].bitrate == 1_000_000
    assert (kw["timing"].tseg1, kw["timing"].tseg2) == (5, 2)
    bad = _real(tmp_path, loadcell_interface="pcan", loadcell_can_bit_timing={"brp": 1})
    with pytest.raises(SetupError, match=r"loadcell_can_bit_timing = .* missing"):
        open_can_bus(bad, backend="cia404", channel="x", bitrate=1_000_000)


@pytest.mark.parametrize(
    ("interface", "match"),
    [
        ("nosuchbus", "unknown python-can interface 'nosuchbus'"),
        ("kvaser", "the vendor library of interface 'kvaser' is missing"),
        ("socketcan", "cannot open the CAN bus"),
    ],
)
def test_canopen_bus_errors_are_one_line_naming_the_fix(
    tmp_path: Path, interface: str, match: str
) -> None:
    """A misconfigured interface, a missing adapter library, a channel that does not open."""
    channel = "0" if interface == "kvaser" else "dimacq-no-such-can9"
    settings = _real(
        tmp_path, loadcell="canopen", loadcell_interface=interface, loadcell_channel=channel
    )
    with pytest.raises(DeviceNotFoundError, match=match) as err:
        rig_builder.check_devices(settings, "loadcell")
    assert "\n" not in str(err.value) and "loadcell_interface" in str(err.value)


def test_canopen_node_answering_with_another_eds_is_named(tmp_path: Path) -> None:
    """``loadcell = "canopen"`` (the project's EDS) on a node that is a generic CiA 404 amplifier:
    one line naming both identities and the fix."""
    from dimacq.simulators.lab.source import SampleSource  # noqa: F401 (type only)

    channel = f"dimacq-otheds-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    settings = _real(
        tmp_path,
        loadcell="canopen",
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,
        loadcell_channel=channel,
    )

    class Zero:
        sample_rate_hz = 1000.0

        def read(self, channels: Any, start: int, n: int) -> Any:
            return np.zeros((len(channels), n))

    with (
        Cia404NodeSim(
            channel, settings.loadcell_cia404_eds_path, Zero(), range(12), node_id=1
        ) as _node,
        DeviceContext(settings) as ctx,
        pytest.raises(SetupError) as err,
    ):
        lookup("loadcell", "canopen")(ctx, ctx.rig_file.load_cells[0])
    msg = str(err.value)
    assert "\n" not in msg and "product 0x0000000C but its EDS describes" in msg
    assert "loadcell = 'cia404'" in msg


def test_a_real_bus_refuses_the_load_the_simulated_one_only_reports(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """12 REAL32 inputs at the lab's 2048 S/s: 177 % of 1 Mbit/s. ``cia404`` refuses it (a
    real bus) at set_rate; ``cia404-simulated`` logs what a real bus would refuse."""
    from dimacq.backends.cia404 import shared_channel

    name = f"dimacq-load-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    settings = _real(tmp_path)
    with DeviceContext(settings) as ctx:
        ch = shared_channel(
            ctx, name, lambda: can.Bus(interface="virtual", channel=name), where="real bus"
        )
        ch.register(1, (8,) * 6)
        with pytest.raises(SetupError, match=r"177 % of 1000000 bit/s, above 70 %.*<= 809 S/s"):
            ch.check_load(2048)
        assert shared_channel(ctx, name, lambda: None, where="again") is ch  # one per channel
    sim = load_settings(data_dir=tmp_path / "s", token="t", loadcell="cia404-simulated")
    with caplog.at_level("WARNING"):
        rig_builder.check_devices(sim, "loadcell")
        with DeviceContext(sim) as ctx:
            amp = lookup("loadcell", "cia404-simulated")(ctx, ctx.rig_file.load_cells[0])
            amp.set_rate(2048)
    assert any("a real bus would be" in r.getMessage() for r in caplog.records)


def test_real_backend_path_on_a_node_of_the_generic_eds(tmp_path: Path) -> None:
    """``loadcell = "cia404"`` (the real backend's code) on ``virtual`` with a node simulator:
    the devices check identifies it, serial number against cell 501's calibration file."""
    channel = f"dimacq-cia404real-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    settings = _real(
        tmp_path,
        loadcell="cia404",
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,
        loadcell_channel=channel,
    )

    class Zero:
        sample_rate_hz = 1000.0

        def read(self, channels: Any, start: int, n: int) -> Any:
            return np.zeros((len(channels), n))

    eds = settings.loadcell_cia404_eds_path
    with Cia404NodeSim(channel, eds, Zero(), range(12), node_id=1, serial_number=501):
        got = rig_builder.check_devices(settings, "loadcell")
    assert got["load_cells"]["501"]["serial_number"] == 501


def test_the_x38s_three_cells_share_one_bus(tmp_path: Path) -> None:
    """Three nodes on one channel: one ``can.Bus``, one ``canopen.Network``, and the summed
    load of 3 × (6 TPDOs) + SYNC at the X-38's 256 S/s: 3 × 810 + 55 bits, 63.6 %."""
    from dimacq.config import scenario_rig_file

    settings = load_settings(
        data_dir=tmp_path,
        token="t",
        loadcell="cia404-simulated",
        scenario="x38",
        rig_file=scenario_rig_file("x38"),
    )
    with DeviceContext(settings) as ctx:
        cells = [lookup("loadcell", "cia404-simulated")(ctx, e) for e in ctx.rig_file.load_cells]
        assert len(cells) == 3 and len({id(c.channel) for c in cells}) == 1
        assert len({id(c.channel.bus) for c in cells}) == 1
        assert sorted(cells[0].channel.nodes) == [1, 2, 3]
        load = cells[0].channel.check_load(256)
        assert load == pytest.approx((3 * 6 * 135 + 55) * 256 / 1e6)
