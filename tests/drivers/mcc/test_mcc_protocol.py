"""The USB-1808X wire format against MCC's Linux driver (github:wjasper/Linux_Drivers,
USB/mcc-libusb/usb-1808.c), with bytes written out by hand from that source, not from our codec.

- bmRequestType: HOST_TO_DEVICE | VENDOR_TYPE | DEVICE_RECIPIENT = 0x00 | 0x40 | 0x00 = 0x40,
  DEVICE_TO_HOST … = 0xC0;
- AIN_SCAN_START 0x12 sends ``struct AInScan_t`` packed in 14 bytes: count u32, retrig_count
  u32, pacer_period = rint(100e6 / f − 1) u32, packet_size u8 (0xFF: BLOCK_IO), options u8
  (``wLength`` 14: the struct's 2 pad bytes are not sent);
- AIN_CONFIG 0x14: wIndex = lastChan − 1, 13 queue bytes; ADC_SETUP 0x11: ``range | mode << 2``;
- bulk IN endpoint 0x86 (LIBUSB_ENDPOINT_IN | 6), 32-bit little-endian words, 18-bit codes;
- ``volts_USB1808``: (value − 131072) · 10 / 131072 on BP_10V.
"""

from __future__ import annotations

import errno

import numpy as np
import pytest
import usb.core
from _exchange import BulkIn, Ctrl, expected_exchange

from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import MccTask, Usb1808
from dimacq.errors import DeviceStateError, SetupError
from dimacq.simulators.mcc.backend import lab_fpga_image

OUT, IN = 0x40, 0xC0
# EEPROM table: slope 1.0, offset 0.0 for all 8 × 4 → f32 LE 0x3F800000, 0x00000000
UNIT_TABLE = (bytes.fromhex("0000803f") + bytes(4)) * 32


def test_ain_scan_start_bytes_of_the_c_driver() -> None:
    # usbAInScanStart_USB1808(udev, 0, 0, 1000.0, 0): pacer_period = rint(1e8/1000 - 1) = 99999
    start = p.AInScanStart(count=0, retrig_count=0, pacer_period=p.pacer_period(1000.0))
    assert start.encode() == bytes.fromhex("00000000000000009f860100ff00")
    # a slave: external clock (pacer_period 0), 4096 scans
    slave = p.AInScanStart(4096, 0, 0)
    assert slave.encode() == bytes.fromhex("001000000000000000000000ff00")
    assert p.AIN_SCAN_START_STRUCT.size == 14


def test_codes_and_volts_follow_the_c_driver() -> None:
    # two scans of two channels; the upper 14 bits of each word are not the ADC's
    raw = bytes.fromhex("00000200ffff0300333302000000fcff")
    codes = p.decode_scans(raw, 2)
    assert codes.tolist() == [[0x20000, 0x3FFFF], [0x23333, 0]]
    volts, clip = p.codes_to_volts(
        codes, np.array([p.Range.BP_10V, p.Range.BP_5V]), np.ones(2), np.zeros(2)
    )
    ref = [
        [(0x20000 - 131072.0) * 10 / 131072, (0x3FFFF - 131072.0) * 5 / 131072],
        [(0x23333 - 131072.0) * 10 / 131072, (0 - 131072.0) * 5 / 131072],
    ]
    assert volts == pytest.approx(np.array(ref), abs=1e-12)
    assert clip.tolist() == [[False, True], [False, True]]
    # calibration: corrected = rint(raw * slope + offset)
    v, _ = p.codes_to_volts(
        np.array([[131072]]), np.array([0]), np.array([1.001]), np.array([-3.0])
    )
    assert v[0, 0] == pytest.approx((round(131072 * 1.001 - 3) - 131072) * 10 / 131072)


def test_status_bits() -> None:
    s = p.Status(0x0100 | 0x0004 | 0x0002)
    assert s & p.Status.FPGA_CONFIGURED and s & p.Status.AIN_SCAN_OVERRUN
    assert s & p.Status.AIN_SCAN_RUNNING and not s & p.Status.FPGA_CONFIG_MODE


def _unit_open() -> list[tuple[Ctrl | BulkIn, object]]:
    """What MccTask([unit]) sends first: the EEPROM table (MEM_ADDRESS 0x7000, four MEMORY
    reads of 64 bytes), then SERIAL."""
    return [
        (Ctrl(OUT, 0x31, 0, 0, bytes.fromhex("0070")), 2),
        *[(Ctrl(IN, 0x30, 0, 0, 64), UNIT_TABLE[k : k + 64]) for k in range(0, 256, 64)],
        (Ctrl(IN, 0x48, 0, 0, 8), b"01F2A7C3"),
    ]


def test_one_unit_task_exchange() -> None:
    """A 2-channel task at 1000 Hz: configuration, start, one bulk read (the task's reader
    thread), stop, drain (the thread, until a timeout), status."""
    # 64 scans (one 512-byte packet): 0 V on AI1, +0.625 V on AI6 (±5 V)
    scans = bytes.fromhex("0000020000400200") * 64
    pairs = [
        *_unit_open(),
        (Ctrl(OUT, 0x13, 0, 0, b""), 0),  # AIN_SCAN_STOP
        # ADC_SETUP: AI1 ±10 V, AI6 ±5 V, all single-ended (mode 1 << 2)
        (Ctrl(OUT, 0x11, 0, 0, bytes.fromhex("04 04 04 04 04 04 05 04")), 8),
        (Ctrl(OUT, 0x14, 0, 1, bytes([1, 6]) + bytes(11)), 13),  # queue AI1, AI6; wIndex 1
        (Ctrl(OUT, 0x15, 0, 0, b""), 0),  # AIN_CLR_FIFO
        (Ctrl(OUT, 0x12, 0, 0, bytes.fromhex("00000000 00000000 9f860100 ff00")), 14),
        (BulkIn(0x86, 512), scans),  # 4 scans asked: rounded up to a whole packet
        (Ctrl(OUT, 0x13, 0, 0, b""), 0),
        (BulkIn(0x86, 512), usb.core.USBTimeoutError("timeout", errno=110)),
        (Ctrl(IN, 0x40, 0, 0, 2), bytes.fromhex("0001")),  # STATUS: FPGA configured, no overrun
    ]
    with expected_exchange(
        "usb", pairs, connect=lambda d: Usb1808(d, timeout_s=0.5), reader_thread=True
    ) as unit:
        task = MccTask([unit])
        task.add_voltage_channel(1, "a1", range_v=10.0)
        task.add_voltage_channel(6, "a6", range_v=5.0)
        task.configure_timing(1000.0, samples_per_frame=4)
        task.start()
        block = task.read(4, timeout_s=0.5)
        task.stop()
    assert block.data[0] == pytest.approx(np.zeros(4))
    assert block.data[1] == pytest.approx(np.full(4, 0x4000 * 5 / 131072))
    assert task.samples_clocked == 64
    assert [p.scans_per_transfer(n, q) for n, q in [(256, 3), (200, 3), (100, 8), (1, 1)]] == [
        256,
        256,
        112,
        128,
    ]


def test_fpga_load_exchange_and_refusal(tmp_path) -> None:  # type: ignore[no-untyped-def]
    image = lab_fpga_image()
    pairs = [
        (Ctrl(OUT, 0x50, 0, 0, b"\xad"), 1),  # FPGA_CONFIG, unlock code 0xAD
        (Ctrl(IN, 0x40, 0, 0, 2), bytes.fromhex("0002")),  # FPGA_CONFIG_MODE
        *[(Ctrl(OUT, 0x51, 0, 0, image[k : k + 64]), 64) for k in range(0, len(image), 64)],
        (Ctrl(OUT, 0x51, 0, 0, b"\x00\x00"), 2),
        (Ctrl(IN, 0x40, 0, 0, 2), bytes.fromhex("0002")),  # not configured
    ]
    with expected_exchange("usb", pairs, connect=lambda d: Usb1808(d)) as unit:
        with pytest.raises(DeviceStateError, match="daq_fpga_file"):
            unit.configure_fpga(image)
    # a text file (Jasper's usb-1808.rbf is C source) or a short one: refused, nothing sent
    text = b"static unsigned char FPGA_data[] = {\n  0xff,  0xff,\n};\n"
    with expected_exchange("usb", [], connect=lambda d: Usb1808(d)) as unit:
        with pytest.raises(SetupError, match=r"is text .*dimacq devices mcc-fpga usb-1808.rbf"):
            unit.configure_fpga(text, "usb-1808.rbf")
        with pytest.raises(SetupError, match=r"464194 bytes, the USB-1808 FPGA image has 464196"):
            unit.configure_fpga(image[:-2])


def test_stall_reads_as_a_state_error() -> None:
    stall = usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)
    pairs = [(Ctrl(OUT, 0x13, 0, 0, b""), stall)]
    with expected_exchange("usb", pairs, connect=lambda d: Usb1808(d)) as unit:
        with pytest.raises(DeviceStateError, match="refused AIN_SCAN_STOP"):
            unit.scan_stop()


def test_setup_errors_name_the_field() -> None:
    with expected_exchange("usb", _unit_open(), connect=lambda d: Usb1808(d)) as unit:
        task = MccTask([unit])
    with pytest.raises(SetupError, match=r"range_v = 0.1 V.*set range_v to 10 or 5"):
        task.add_voltage_channel(0, "bridge", range_v=0.1)
    with pytest.raises(SetupError, match=r"physical_channel 8 .*\[daq\] units"):
        task.add_voltage_channel(8, "x")
    # 2048 Hz: pacer 48827 → 2048.0026 Hz (1.3 ppm, accepted); 150 kHz: 150.150 kHz, refused
    task.configure_timing(2048.0)
    with pytest.raises(SetupError, match=r"sample_rate_hz = 150000.*100 MHz/\(N\+1\)"):
        task.configure_timing(150_000.0)
