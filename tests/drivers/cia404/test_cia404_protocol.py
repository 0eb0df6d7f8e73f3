"""Generic CiA 404 amplifier: CiA 301 frames written out byte for byte from the specification's
layouts (not from our codec), and the driver's mapping procedure as a scripted exchange."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _exchange import Can, ScriptedBus

from dimacq.drivers.cia404 import protocol as p
from dimacq.drivers.cia404.driver import CanChannel, Cia404Amplifier
from dimacq.errors import SetupError

EDS = Path(__file__).resolve().parents[3] / "config" / "canopen" / "cia404-generic.eds"
NODE = 5


def test_object_indices_of_cia301_and_cia404() -> None:
    """The objects the driver reads and writes, as CiA 301 (communication) and CiA 404
    (analogue inputs) number them."""
    assert (p.SYNC_COB_ID, p.DEVICE_TYPE, p.HEARTBEAT_TIME, p.IDENTITY) == (
        0x080,
        0x1000,
        0x1017,
        0x1018,
    )
    assert (p.TPDO_COMM, p.TPDO_MAP, p.COB_ID_INVALID) == (0x1800, 0x1A00, 1 << 31)
    assert (p.REAL32_PV.index, p.INT16_PV.index, p.AI_DECIMAL_DIGITS) == (0x6130, 0x7130, 0x6132)
    assert (p.AI_SENSOR_TYPE, p.AI_ADC_SAMPLE_RATE, p.AI_PHYSICAL_UNIT) == (0x6110, 0x6114, 0x6131)
    assert (p.AI_SCALING_FACTOR, p.AI_SCALING_OFFSET) == (0x6126, 0x6127)
    assert (p.AI_FILTER_TYPE, p.AI_FILTER_CONSTANT, p.FILTER_MOVING_AVERAGE) == (0x61A0, 0x61A1, 1)
    assert p.TRANSMISSION_SYNCHRONOUS == 1  # CiA 301: synchronous, every SYNC


def test_cia301_reference_frames() -> None:
    # SDO expedited download, 4 bytes (ccs 1, e = s = 1, n = 0: 0x23), index LE, sub, data LE:
    # TPDO1's first mapping entry = 0x6130 sub 1, 32 bits, to node 5
    assert p.sdo_expedited_download(NODE, 0x1A00, 1, (0x61300120).to_bytes(4, "little")) == (
        0x605,
        bytes.fromhex("23001a0120013061"),
    )
    # 2 bytes: n = 2 → 0x2B (producer heartbeat 0x1017 = 200 ms); 1 byte: n = 3 → 0x2F
    assert p.sdo_expedited_download(NODE, 0x1017, 0, b"\xc8\x00")[1] == bytes.fromhex(
        "2b171000c8000000"
    )
    assert p.sdo_expedited_download(NODE, 0x1800, 2, b"\x01")[1] == bytes.fromhex(
        "2f00180201000000"
    )
    # the server's confirmation (scs 3: 0x60)
    assert p.sdo_download_answer(NODE, 0x1A00, 1) == (0x585, bytes.fromhex("60001a0100000000"))
    # NMT: start node 5 = 000#01 05; every node pre-operational = 000#80 00
    assert p.nmt_frame(p.NmtCommand.START, NODE) == (0x000, bytes.fromhex("0105"))
    assert p.nmt_frame(p.NmtCommand.PRE_OPERATIONAL, 0) == (0x000, bytes.fromhex("8000"))
    # SYNC: 080# without data (with a counter 080#01); EMCY of node 5 on 0x085
    assert p.sync_frame() == (0x080, b"")
    assert p.sync_frame(1) == (0x080, b"\x01")
    assert p.emcy_cob_id(NODE) == 0x085


def test_mapping_entries_and_cob_ids() -> None:
    assert p.mapping_entry(0x6130, 1, 32) == 0x61300120
    assert p.mapping_entry(0x7130, 3, 16) == 0x71300310
    # predefined connection set: TPDO1..4 = 0x180/0x280/0x380/0x480 + node
    assert [p.tpdo_cob_id(NODE, k) for k in range(4)] == [0x185, 0x285, 0x385, 0x485]
    with pytest.raises(SetupError, match=r"node id of 1\.\.63"):
        p.tpdo_cob_id(100, 4)


def test_frame_bits_worst_case() -> None:
    # 8 data bytes, 11-bit id: 111 bits + 24 stuff bits = 135 (Davis et al. 2007, table 1);
    # a SYNC (no data): 47 + 8 = 55
    assert p.frame_bits(8) == 135
    assert p.frame_bits(0) == 55
    # 12 REAL32 channels in 6 TPDOs + SYNC at 2048 S/s on 1 Mbit/s: 865 bits per sample
    assert p.bus_load([8] * 6, 2048, 1_000_000) == pytest.approx(865 * 2048 / 1e6)


def test_plan_packs_channels_in_order() -> None:
    plans = p.plan_tpdos(12, p.REAL32_PV, NODE, 6, where="t")
    assert [t.channels for t in plans] == [(2 * k, 2 * k + 1) for k in range(6)]
    assert plans[4].cob_id == 0x1C5 and plans[0].entries == (0x61300120, 0x61300220)
    plans16 = p.plan_tpdos(6, p.INT16_PV, NODE, 6, where="t")
    assert [t.length for t in plans16] == [8, 4]
    with pytest.raises(SetupError, match="need 7 TPDOs, the EDS has 6"):
        p.plan_tpdos(13, p.REAL32_PV, NODE, 6, where="t")


def test_decode_is_the_inverse_of_the_node_side() -> None:
    plan = p.plan_tpdos(2, p.REAL32_PV, NODE, 6, where="t")[0]
    v = np.array([[1.5, -2.25], [3.0e-4, 7.0]])
    # REAL32 little endian: 1.5 = 0x3FC00000
    assert p.encode_tpdo(plan, v)[0][:4] == bytes.fromhex("0000c03f")
    np.testing.assert_array_equal(p.decode_tpdo(plan, p.encode_tpdo(plan, v)), v.astype("<f4"))


def _sdo(index: int, sub: int, data: str) -> tuple[Can, Can]:
    """An expedited download written out by hand, and its confirmation."""
    n = len(bytes.fromhex(data))
    cmd = {4: 0x23, 2: 0x2B, 1: 0x2F}[n]
    req = bytes([cmd, index & 0xFF, index >> 8, sub]) + bytes.fromhex(data).ljust(4, b"\0")
    return Can(0x605, req), Can(0x585, bytes([0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))


def test_the_mapping_procedure_on_the_wire() -> None:
    """Two channels of 0x6130 into TPDO1 (CiA 301 order: disable, count 0, entries, count,
    transmission type 1, enable), TPDO2..6 disabled; NMT pre-operational first."""
    script = [
        (Can(0x000, bytes.fromhex("8005")), None),
        _sdo(0x1800, 1, "85010080"),  # COB-ID 0x185 with bit 31: not valid
        _sdo(0x1A00, 0, "00"),
        _sdo(0x1A00, 1, "20013061"),  # 0x61300120
        _sdo(0x1A00, 2, "20023061"),  # 0x61300220
        _sdo(0x1A00, 0, "02"),
        _sdo(0x1800, 2, "01"),  # synchronous, every SYNC
        _sdo(0x1800, 1, "85010000"),  # valid
        _sdo(0x1801, 1, "85020080"),
        _sdo(0x1802, 1, "85030080"),
        _sdo(0x1803, 1, "85040080"),
        _sdo(0x1804, 1, "c5010080"),  # TPDO5/6: 0x1C0/0x2C0 + node
        _sdo(0x1805, 1, "c5020080"),
    ]
    bus = ScriptedBus(script)
    ch = CanChannel(bus, bitrate=1_000_000, max_load=0.7, where="test")
    try:
        amp = Cia404Amplifier(ch, node_id=NODE, eds=EDS, n_channels=2, timeout_s=1.0)
        amp.configure()
        amp.close()
        bus.assert_done()
    finally:
        ch.close()


def test_nmt_command_specifiers_of_cia301() -> None:
    """CiA 301 NMT: 01 start, 02 stop, 80 enter pre-operational, 81 reset node, 82 reset
    communication, each [command, node] on identifier 0."""
    want = {
        p.NmtCommand.START: "0105",
        p.NmtCommand.STOP: "0205",
        p.NmtCommand.PRE_OPERATIONAL: "8005",
        p.NmtCommand.RESET_NODE: "8105",
        p.NmtCommand.RESET_COMMUNICATION: "8205",
    }
    for cmd, data in want.items():
        assert p.nmt_frame(cmd, NODE) == (0x000, bytes.fromhex(data)), cmd.name
    # by name: two members of one value would be one member (an alias) and pass the loop
    assert {c.name: int(c) for c in p.NmtCommand} == {
        "START": 0x01,
        "STOP": 0x02,
        "PRE_OPERATIONAL": 0x80,
        "RESET_NODE": 0x81,
        "RESET_COMMUNICATION": 0x82,
    }


def test_sdo_of_a_high_index_and_subindex() -> None:
    """Index and sub-index are unsigned: 0xA000 (a profile area index) sub 0x81."""
    assert p.sdo_expedited_download(NODE, 0xA000, 0x81, b"\x01\x02\x03\x04")[1] == bytes.fromhex(
        "2300a08101020304"
    )
    assert p.sdo_download_answer(NODE, 0xA000, 0x81)[1] == bytes.fromhex("6000a08100000000")


def test_a_mapping_holds_at_most_eight_entries() -> None:
    eight = p.TpdoPlan(1, 0x185, p.INT16_PV, tuple(range(8)))
    assert len([w for w in p.mapping_writes([eight], 1, NODE) if w[0] == p.TPDO_MAP]) == 10
    nine = p.TpdoPlan(1, 0x185, p.INT16_PV, tuple(range(9)))
    with pytest.raises(SetupError, match="9 entries; at most 8"):
        p.mapping_writes([nine], 1, NODE)


def test_int16_process_values_are_signed_little_endian() -> None:
    plan = p.plan_tpdos(2, p.INT16_PV, NODE, 6, where="t")[0]
    got = p.decode_tpdo(plan, [bytes.fromhex("feff0200")], np.array([0.5, 0.5]))
    np.testing.assert_array_equal(got, [[-1.0, 1.0]])
    assert p.encode_tpdo(plan, np.array([[-2.0, 2.0]]))[0] == bytes.fromhex("feff0200")


def test_the_process_value_the_eds_offers() -> None:
    """``auto`` takes 0x6130 REAL32 where the EDS has it PDO-mappable, else 0x7130 INTEGER16
    (CiA 404's two AI process values); a value the EDS does not map is refused by name."""
    import canopen

    od = canopen.import_od(str(EDS))
    assert p.process_value(od, where="t") is p.REAL32_PV
    assert p.process_value(od, "0x7130", where="t") is p.INT16_PV
    od[0x6130][1].pdo_mappable = False
    assert p.process_value(od, where="t") is p.INT16_PV
    od[0x7130][1].pdo_mappable = False
    with pytest.raises(SetupError, match="0x6130 or 0x7130"):
        p.process_value(od, where="t")


def test_unit_codes_follow_the_cia303_2_coding() -> None:
    """CiA 303-2 physical unit (0x6131): the prefix's power of ten as a signed byte in byte 3,
    the SI unit's code in byte 2 (volt 0x26; a ratio has none, 0x00). Built here from that rule,
    not copied from the codec: V = 10⁰ V, mV = 10⁻³ V, mV/V = 10⁻³ (dimensionless)."""

    def code(power_of_ten: int, si_unit: int) -> int:
        return (power_of_ten & 0xFF) << 24 | si_unit << 16

    volt, ratio = 0x26, 0x00
    assert p.UNIT_CODES == {"V": code(0, volt), "mV": code(-3, volt), "mV/V": code(-3, ratio)}


def test_heartbeat_states_of_cia301() -> None:
    """CiA 301 heartbeat / boot-up byte: 0x00 boot-up, 0x04 stopped, 0x05 operational,
    0x7F pre-operational, as python-canopen's own table has them (its 0x00 is named
    INITIALISING: the boot-up message)."""
    from canopen.nmt import NMT_STATES as theirs

    ours = {"INITIALISING" if v == "BOOT-UP" else v: k for k, v in p.NMT_STATES.items()}
    assert ours == {v: k for k, v in theirs.items() if v in ours}
    assert sorted(ours) == ["INITIALISING", "OPERATIONAL", "PRE-OPERATIONAL", "STOPPED"]
