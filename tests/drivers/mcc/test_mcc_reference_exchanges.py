"""Reference exchanges of the USB-1808(X), transcribed from MCC's published code, checked against
our driver (scripted exchanges) and against the twin (the same literal bytes sent to it).

Sources (line numbers at the commits fetched):

- U = ``github:mccdaq/uldaq`` at 1d8404159c0fb6d2665461b80acca5bbef5c610a, under ``src/usb/``;
- J = ``github:wjasper/Linux_Drivers`` at 94ff7013610abb0be7530b88b4db1d7fbf2064af, under
  ``USB/mcc-libusb/``.

bmRequestType: J pmd.h:41-49 (HOST_TO_DEVICE 0 << 7, DEVICE_TO_HOST 1 << 7, VENDOR_TYPE 2 << 5,
DEVICE_RECIPIENT 0): OUT 0x40, IN 0xC0; U UsbDaqDevice.cpp:418 and :473 the same from libusb.
Every byte below is written out from those lines, not from our codec.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import usb.core
from _exchange import BulkIn, Ctrl, expected_exchange

from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import Usb1808
from dimacq.simulators.daq.backend import DaqInput
from dimacq.simulators.mcc.backend import Mcc1808Backend, lab_fpga_image

OUT, IN = 0x40, 0xC0
# calibration table: slope 1.0 (f32 LE 0000803f), offset -2.5 (f32 LE 000020c0) × 32 pairs
TABLE = (bytes.fromhex("0000803f") + bytes.fromhex("000020c0")) * 32


@dataclass(frozen=True)
class Ref:
    """One message: the pairs on the wire, where they are written, and the driver call."""

    message: str
    pairs: list[tuple[Any, Any]]
    source: str
    call: Callable[[Usb1808], Any]
    result: Any = None


REFERENCES = [
    Ref(
        "STATUS (FPGA configured)",
        [(Ctrl(IN, 0x40, 0, 0, 2), bytes.fromhex("0001"))],
        "J usb-1808.c:72 STATUS 0x40, :1144 u16; usb-1808.h:100 FPGA_CONFIGURED 1 << 8; "
        "U Usb1808.cpp:20, UsbFpgaDevice.cpp:111-113 (status & 0x100)",
        lambda u: int(u.status()),
        0x0100,
    ),
    Ref(
        "STATUS (running, overrun, config mode)",
        [(Ctrl(IN, 0x40, 0, 0, 2), bytes.fromhex("0602"))],
        "J usb-1808.h:94-101 (AIN_SCAN_RUNNING 1 << 1, AIN_SCAN_OVERRUN 1 << 2, "
        "FPGA_CONFIG_MODE 1 << 9); U Usb1808.cpp:35-37 (overrun 0x0004, running 0x0002)",
        lambda u: u.status(),
        p.Status.AIN_SCAN_RUNNING | p.Status.AIN_SCAN_OVERRUN | p.Status.FPGA_CONFIG_MODE,
    ),
    Ref(
        "SERIAL",
        [(Ctrl(IN, 0x48, 0, 0, 8), b"01F2A7C3")],
        "J usb-1808.c:77 SERIAL 0x48, :1257 8 bytes",
        lambda u: u.serial_number(),
        "01F2A7C3",
    ),
    Ref(
        "FPGA_VERSION",
        [(Ctrl(IN, 0x52, 0, 0, 2), bytes.fromhex("0301"))],
        "J usb-1808.c:82 FPGA_VERSION 0x52, :1387 u16; U UsbFpgaDevice.h:35, UsbFpgaDevice.cpp:376",
        lambda u: u.fpga_version(),
        0x0103,
    ),
    Ref(
        "MEM_ADDRESS + MEMORY (calibration table, 64-byte reads)",
        [
            (Ctrl(OUT, 0x31, 0, 0, bytes.fromhex("0070")), 2),
            *[(Ctrl(IN, 0x30, 0, 0, 64), TABLE[k : k + 64]) for k in range(0, 256, 64)],
        ],
        "U UsbDaqDevice.cpp:61-62 (MEM 0x30, MEM_ADDR 0x31), :67 (EEPROM reads ≤ 64), :610-614 "
        "(address u16 LE), :633-649 (address once, then reads of ≤ 64); AiUsb1808.cpp:50-52 "
        "(0x7000, 32 coefficients); AiUsbBase.cpp:119-147 (slope f32, offset f32 LE); "
        "J usb-1808.c:98-108, :1281, :1319",
        lambda u: tuple(float(a[3, 2]) for a in u.read_calibration()),
        (1.0, -2.5),
    ),
    Ref(
        "ADC_SETUP (AI1 ±10 V, AI6 ±5 V, single-ended)",
        [(Ctrl(OUT, 0x11, 0, 0, bytes.fromhex("0404040404040504")), 8)],
        "J usb-1808.c:41 ADC_SETUP 0x11, :320-338 (range bits 1-0, mode << 2, SINGLE_ENDED 1 "
        "usb-1808.h:69, BP_5V 1 :89); U AiUsb1808.h:52-66, AiUsb1808.cpp:177",
        lambda u: u.adc_setup(
            [p.Range.BP_10V] * 6 + [p.Range.BP_5V, p.Range.BP_10V],
            [p.InputMode.SINGLE_ENDED] * 8,
        ),
    ),
    Ref(
        "AIN_CONFIG (scan queue AI1, AI6)",
        [(Ctrl(OUT, 0x14, 0, 1, bytes([1, 6]) + bytes(11)), 13)],
        "J usb-1808.c:44 AIN_CONFIG 0x14, :534 (wIndex lastChan - 1, 13 bytes); "
        "U DaqIUsb1808.cpp:193 scanQueue[13], :230 (wIndex idx - 1)",
        lambda u: u.scan_config([1, 6]),
    ),
    Ref(
        "AIN_CLR_FIFO",
        [(Ctrl(OUT, 0x15, 0, 0, b""), 0)],
        "J usb-1808.c:45, :573; U DaqIUsb1808.h:36 CMD_SCAN_CLEARFIFO 0x15",
        lambda u: u.clear_fifo(),
    ),
    Ref(
        "AIN_SCAN_START (continuous, 1 kHz pacer, block I/O)",
        [(Ctrl(OUT, 0x12, 0, 0, bytes.fromhex("00000000 00000000 9f860100 ff 00")), 14)],
        "J usb-1808.c:42, :423-439 (count, retrig_count, pacer_period u32, packet_size, options "
        "u8), :449 pacer = rint(100e6 / f - 1) = 99999 = 0x0001869f, :456 0xff, :460 14 bytes; "
        "U DaqIUsb1808.h:39-50, DaqIUsb1808.cpp:96, :115-123 (block I/O: 512 / 2 - 1 = 0xff)",
        lambda u: u.scan_start(p.AInScanStart(0, 0, p.pacer_period(1000.0))),
    ),
    Ref(
        "AIN_SCAN_START (slave: external clock, 4096 scans)",
        [(Ctrl(OUT, 0x12, 0, 0, bytes.fromhex("00100000 00000000 00000000 ff 00")), 14)],
        "J usb-1808.c:378-379, :446-447 (pacer_period 0: the ICLKO pin paces)",
        lambda u: u.scan_start(p.AInScanStart(4096, 0, 0)),
    ),
    Ref(
        "AIN_SCAN_START (2^31 scans, retrigger every 2^31: unsigned counts)",
        [(Ctrl(OUT, 0x12, 0, 0, bytes.fromhex("00000080 00000080 00000000 ff 04")), 14)],
        "J usb-1808.c:424-425 (count, retrig_count uint32_t), :430 (bit 2 retrigger); "
        "U DaqIUsb1808.h:43-44 (unsigned int)",
        lambda u: u.scan_start(p.AInScanStart(2**31, 2**31, 0, options=0x04)),
    ),
    Ref(
        "AIN_SCAN_START (slowest pacer: period 2^32 - 2)",
        [(Ctrl(OUT, 0x12, 0, 0, bytes.fromhex("00000000 00000000 feffffff ff 00")), 14)],
        "J usb-1808.c:426 (pacer_period uint32_t); U ai/AiUsb1808.cpp:15 (min rate = "
        "clock / UINT_MAX), DaqIUsb1808.h:45",
        lambda u: u.scan_start(p.AInScanStart(0, 0, 0xFFFFFFFE)),
    ),
    Ref(
        "bulk IN 0x86 (two scans of AI1, AI6)",
        [(BulkIn(0x86, 16), bytes.fromhex("00000200 ff3f0300 33330200 00000000"))],
        "J usb-1808.c:475 (LIBUSB_ENDPOINT_IN | 6), :389-396 (scan-major, 32-bit samples, "
        "18-bit codes zero-padded); U DaqIUsb1808.cpp:44 (0x86), :72 (4 bytes a sample)",
        lambda u: p.decode_scans(u.read_scans(16), 2).tolist(),
        [[0x20000, 0x33FFF], [0x23333, 0]],
    ),
    Ref(
        "AIN_SCAN_STOP",
        [(Ctrl(OUT, 0x13, 0, 0, b""), 0)],
        "J usb-1808.c:43, :565; U DaqIUsb1808.h:36 CMD_IN_SCAN_STOP 0x13",
        lambda u: u.scan_stop(),
    ),
]


def _fpga_pairs(image: bytes) -> list[tuple[Any, Any]]:
    """U UsbFpgaDevice.cpp:218-247: FPGA_CFG 0x50 with 0xAD, the image in 64-byte FPGA_DATA
    0x51 transfers, then two zero bytes (Spartan-6: :242-246, :359-365); J usb-1808.c:148-160
    (STATUS must show FPGA_CONFIG_MODE 1 << 9, then FPGA_CONFIGURED 1 << 8)."""
    pairs: list[tuple[Any, Any]] = [
        (Ctrl(OUT, 0x50, 0, 0, b"\xad"), 1),
        (Ctrl(IN, 0x40, 0, 0, 2), bytes.fromhex("0002")),
    ]
    for k in range(0, len(image), 64):
        pairs.append((Ctrl(OUT, 0x51, 0, 0, image[k : k + 64]), len(image[k : k + 64])))
    pairs += [(Ctrl(OUT, 0x51, 0, 0, b"\x00\x00"), 2), (Ctrl(IN, 0x40, 0, 0, 2), b"\x00\x03")]
    return pairs


@pytest.mark.parametrize("ref", REFERENCES, ids=[r.message for r in REFERENCES])
def test_driver_sends_and_reads_the_reference_bytes(ref: Ref) -> None:
    with expected_exchange("usb", ref.pairs, connect=lambda d: Usb1808(d)) as unit:
        got = ref.call(unit)
    assert got == ref.result


def test_driver_loads_the_fpga_as_uldaq_does() -> None:
    image = lab_fpga_image()
    assert len(image) == 464196  # U fw/Usb1808Fpga.c:38694 USB_1808_bin_len
    assert image[16:20] == bytes.fromhex("aa995566")  # U fw/Usb1808Fpga.c:11 (sync word)
    with expected_exchange("usb", _fpga_pairs(image), connect=lambda d: Usb1808(d)) as unit:
        unit.configure_fpga(image)


def test_the_driver_message_table_is_the_vendors() -> None:
    """Every request code, status bit, range and mode the driver's table holds, against J
    usb-1808.c:40-82, usb-1808.h:28-29, :68-70, :88-101, pmd.h:31."""
    assert {r.name: int(r) for r in p.Request} == {
        "AIN_ADC_SETUP": 0x11,
        "AIN_SCAN_START": 0x12,
        "AIN_SCAN_STOP": 0x13,
        "AIN_SCAN_CONFIG": 0x14,
        "AIN_CLR_FIFO": 0x15,
        "MEMORY": 0x30,
        "MEM_ADDRESS": 0x31,
        "STATUS": 0x40,
        "TRIGGER_CONFIG": 0x43,
        "SERIAL": 0x48,
        "FPGA_CONFIG": 0x50,
        "FPGA_DATA": 0x51,
        "FPGA_VERSION": 0x52,
    }
    assert {s.name: int(s) for s in p.Status if s} == {
        "AIN_SCAN_RUNNING": 0x0002,
        "AIN_SCAN_OVERRUN": 0x0004,
        "AIN_SCAN_DONE": 0x0020,
        "FPGA_CONFIGURED": 0x0100,
        "FPGA_CONFIG_MODE": 0x0200,
    }
    assert [(r.name, int(r)) for r in p.Range] == [
        ("BP_10V", 0),
        ("BP_5V", 1),
        ("UP_10V", 2),
        ("UP_5V", 3),
    ]
    assert {r: p.RANGES_V[r] for r in p.Range} == {0: 10.0, 1: 5.0, 2: 10.0, 3: 5.0}
    assert [(m.name, int(m)) for m in p.InputMode] == [
        ("DIFFERENTIAL", 0),
        ("SINGLE_ENDED", 1),
        ("GROUNDED", 3),
    ]
    assert (p.VENDOR_ID, sorted(p.PRODUCT_IDS)) == (0x09DB, [0x013D, 0x013E])
    # U DaqIUsb1808.h:35 FIFO 8 * 4 * 1024; J usb-1808.h:103-104, :109; U AiUsb1808.cpp:29
    assert (p.FIFO_BYTES, p.N_AI, p.N_RANGES, p.BASE_CLOCK_HZ) == (32768, 8, 4, 100e6)
    assert (p.CODE_MASK, p.MID_SCALE) == (0x3FFFF, 131072)  # J usb-1808.c:1406-1415
    assert p.SCAN_QUEUE_LEN == 13 and p.PACKET_BYTES == 512  # J usb-1808.c:512, usb-1808.h:107


# -- the same bytes against the twin -------------------------------------------------------


class _Dc:
    """1.25 V on every wired input."""

    sample_rate_hz = 1000.0
    channel_names = ("dc",)
    channel_units = ("V",)

    def read(self, channels: np.ndarray, start: int, n: int) -> np.ndarray:
        return np.full((len(channels), n), 1.25)

    def excite(self, input_index: int, at_sample: int) -> None:
        return None


def _twin(**kw: Any) -> Any:
    backend = Mcc1808Backend(
        _Dc(), {1: DaqInput(0, 1.0)}, n_units=1, free_running=False, seed=5, **kw
    )
    (dev,) = usb.core.find(find_all=True, idVendor=0x09DB, idProduct=0x013E, backend=backend)
    return dev


def _status(dev: Any) -> int:
    return int(struct.unpack("<H", bytes(dev.ctrl_transfer(IN, 0x40, 0, 0, 2)))[0])


def _stalls(call: Callable[[], Any]) -> bool:
    try:
        call()
    except usb.core.USBError as err:
        return err.errno == 32
    return False


def _load(dev: Any, image: bytes) -> None:
    """The uldaq sequence, bytes as in :func:`_fpga_pairs`."""
    dev.ctrl_transfer(OUT, 0x50, 0, 0, b"\xad")
    for k in range(0, len(image), 64):
        dev.ctrl_transfer(OUT, 0x51, 0, 0, image[k : k + 64])
    dev.ctrl_transfer(OUT, 0x51, 0, 0, b"\x00\x00")


def test_twin_takes_the_reference_sequence() -> None:
    dev = _twin()
    assert _status(dev) == 0x0000  # J usbInit_1808: not configured after power-up
    assert _stalls(lambda: dev.ctrl_transfer(OUT, 0x13, 0, 0, b""))  # DAQ requests: FPGA first
    assert _stalls(lambda: dev.ctrl_transfer(OUT, 0x51, 0, 0, b"\xff" * 64))  # not config mode
    assert _stalls(lambda: dev.ctrl_transfer(OUT, 0x50, 0, 0, b"\xae"))  # wrong unlock code
    dev.ctrl_transfer(OUT, 0x50, 0, 0, b"\xad")
    assert _status(dev) == 0x0200  # FPGA_CONFIG_MODE
    assert _stalls(lambda: dev.ctrl_transfer(OUT, 0x51, 0, 0, b"\xff" * 65))  # J :1372 ≤ 64
    image = lab_fpga_image()
    for k in range(0, len(image), 64):
        dev.ctrl_transfer(OUT, 0x51, 0, 0, image[k : k + 64])
    assert _status(dev) & 0x0100  # configured (Jasper checks here, without the trailer)
    dev.ctrl_transfer(OUT, 0x51, 0, 0, b"\x00\x00")  # uldaq's trailer is accepted
    assert bytes(dev.ctrl_transfer(IN, 0x48, 0, 0, 8)) == b"01F2A000"
    # EEPROM: 64-byte reads from one address; a longer read stalls
    dev.ctrl_transfer(OUT, 0x31, 0, 0, bytes.fromhex("0070"))
    assert _stalls(lambda: dev.ctrl_transfer(IN, 0x30, 0, 0, 256))
    dev.ctrl_transfer(OUT, 0x31, 0, 0, bytes.fromhex("0070"))
    table = b"".join(bytes(dev.ctrl_transfer(IN, 0x30, 0, 0, 64)) for _ in range(4))
    pairs = np.frombuffer(table, "<f4").reshape(8, 4, 2)
    assert np.all(np.abs(pairs[..., 0] - 1) < 0.02) and np.all(np.abs(pairs[..., 1]) < 300)
    # a scan of AI1 (±10 V), one bulk transfer, then stop
    dev.ctrl_transfer(OUT, 0x11, 0, 0, bytes.fromhex("0404040404040404"))
    dev.ctrl_transfer(OUT, 0x14, 0, 0, bytes([1]) + bytes(12))
    dev.ctrl_transfer(OUT, 0x15, 0, 0, b"")
    dev.ctrl_transfer(OUT, 0x12, 0, 0, bytes.fromhex("00000000 00000000 9f860100 ff 00"))
    assert _status(dev) & 0x0002  # AIN_SCAN_RUNNING
    assert _stalls(lambda: dev.ctrl_transfer(OUT, 0x12, 0, 0, bytes(14)))  # J :369 while running
    words = np.frombuffer(bytes(dev.read(0x86, 512, 1000)), "<u4")
    assert words.size == 128 and not np.any(words >> 18)  # 18-bit codes, zero-padded
    slope, offset = pairs[1, 0]
    volts = (np.rint(words * slope + offset) - 131072) * 10 / 131072  # J :297, :1406
    assert np.all(np.abs(volts - 1.25) < 2 * 10 / 131072)
    dev.ctrl_transfer(OUT, 0x13, 0, 0, b"")
    assert not _status(dev) & 0x0002


def _c_array_text(image: bytes) -> bytes:
    """The image as Jasper's ``usb-1808.rbf`` holds it: C source of an array."""
    rows = ",\n  ".join(
        ", ".join(f"0x{b:02x}" for b in image[k : k + 8]) for k in range(0, len(image), 8)
    )
    return f"static unsigned char FPGA_data[] = {{\n  {rows}\n}};\n".encode("ascii")


@pytest.mark.slow
@pytest.mark.parametrize(
    "what",
    ["C source text", "image without its last 64 bytes", "image with another IDCODE"],
)
def test_twin_stays_unconfigured_on_what_is_not_its_image(what: str) -> None:
    image = lab_fpga_image()
    bad = {
        "C source text": _c_array_text(image)[: 2 * len(image)],
        "image without its last 64 bytes": image[:-64],
        "image with another IDCODE": image.replace(
            bytes.fromhex("31c2 0400 2093"), bytes.fromhex("31c2 0400 1093"), 1
        ),
    }[what]
    assert bad != image
    dev = _twin()
    _load(dev, bad)
    assert not _status(dev) & 0x0100
    assert _stalls(lambda: dev.ctrl_transfer(OUT, 0x12, 0, 0, bytes(14)))  # scans refused
    _load(dev, image)  # the image itself, after a new FPGA_CONFIG: configured
    assert _status(dev) & 0x0100


def test_twin_fifo_is_the_devices() -> None:
    """U DaqIUsb1808.h:35: 32 KiB; a host 8193 samples late overruns (J usb-1808.h:95)."""
    dev = _twin()
    _load(dev, lab_fpga_image())
    dev.ctrl_transfer(OUT, 0x14, 0, 0, bytes([1]) + bytes(12))
    dev.ctrl_transfer(OUT, 0x12, 0, 0, bytes.fromhex("00000000 00000000 9f860100 ff 00"))
    data = bytes(dev.read(0x86, 8192 * 4, 1000))  # exactly the FIFO: no overrun
    assert len(data) == 32768 and not _status(dev) & 0x0004
    dev.ctrl_transfer(OUT, 0x13, 0, 0, b"")


def test_the_sixteen_bit_words_are_unsigned() -> None:
    """J usb-1808.c: ``usbMemAddressW_USB1808(udev, uint16_t address)`` sends the address as its
    two bytes, and the calibration area unlocks by a write at address 0x8000
    (``usbMemWriteEnable_USB1808``'s comment): ``00 80`` on the wire. ``usbStatus_USB1808``
    returns the ``uint16_t`` it read: ``ff ff`` is 65535, not −1."""
    assert p.ADDRESS_STRUCT.pack(0x8000) == bytes.fromhex("0080")
    assert p.STATUS_STRUCT.unpack(bytes.fromhex("ffff")) == (0xFFFF,)


def test_the_fpga_sync_word_may_start_up_to_byte_64() -> None:
    """The image check takes the sync word after at most 64 bytes of 0xFF padding (uldaq's and
    Jasper's images have 16): 64 is taken, 65 refused."""
    body = p.FPGA_SYNC_WORD + bytes(p.FPGA_IMAGE_BYTES)
    p.check_fpga_image((b"\xff" * 64 + body)[: p.FPGA_IMAGE_BYTES], "at 64")
    with pytest.raises(ValueError, match="no Xilinx sync word"):
        p.check_fpga_image((b"\xff" * 65 + body)[: p.FPGA_IMAGE_BYTES], "at 65")


def test_the_scan_start_bytes_are_unsigned() -> None:
    """J usb-1808.h ``usbAInScanStart_USB1808(udev, uint32_t count, uint32_t retrig_count,
    double frequency, uint8_t options)``; the pacer period is sent as a ``uint32_t`` and the
    packet size as one byte (0xFF block I/O): every field takes its whole unsigned range."""
    data = p.AInScanStart(2**32 - 1, 2**32 - 1, 2**32 - 1, 0xFF, 0xFF).encode()
    assert data == b"\xff" * 14
