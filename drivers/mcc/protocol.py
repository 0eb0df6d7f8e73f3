"""Wire protocol of the Measurement Computing USB-1808 / USB-1808X: the message table.

Facts from MCC's open-source Linux driver by W. J. Jasper (``github:wjasper/Linux_Drivers``,
``USB/mcc-libusb/usb-1808.c`` and ``usb-1808.h``; the same commands in ``USB/python/
usb_1808.py``); the code here is ours. Driver (:mod:`dimacq.drivers.mcc.driver`), simulator
(:mod:`dimacq.simulators.mcc.backend`) and tests import this module; nothing else slices bytes.

Device: USB 2.0 high speed, VID ``0x09DB`` (Measurement Computing), PID ``0x013D`` (USB-1808) or
``0x013E`` (USB-1808X); 8 analogue inputs, each with its own 18-bit ADC (simultaneous
sampling), ranges ±10 V, ±5 V, 0..10 V, 0..5 V; a 100 MHz base clock paces the scans.
Interface 0, bulk IN endpoint ``0x86`` (``LIBUSB_ENDPOINT_IN | 6``) carries the scan data.

Vendor control requests (endpoint 0; ``bmRequestType`` 0x40 = HOST_TO_DEVICE | VENDOR_TYPE |
DEVICE_RECIPIENT, 0xC0 = DEVICE_TO_HOST | VENDOR_TYPE | DEVICE_RECIPIENT)

=================  =====  ====  =======  ============  ======================================
request            bReq   dir   wValue   wIndex        data stage (little-endian)
=================  =====  ====  =======  ============  ======================================
AIN_ADC_SETUP      0x11   OUT   0        0             8 bytes: ``range | mode << 2`` per AI
AIN_SCAN_START     0x12   OUT   0        0             14 bytes :data:`AIN_SCAN_START_STRUCT`
AIN_SCAN_STOP      0x13   OUT   0        0             —
AIN_SCAN_CONFIG    0x14   OUT   0        last - 1      13 bytes: the scan queue (0..7 = AI)
AIN_CLR_FIFO       0x15   OUT   0        0             —
MEMORY             0x30   IN    0        0             ≤ 64 EEPROM bytes from the current address
MEM_ADDRESS        0x31   OUT   0        0             u16 address (auto-increments on reads)
STATUS             0x40   IN    0        0             u16 :class:`Status` bits
TRIGGER_CONFIG     0x43   OUT   0        0             u8: bit0 edge, bit1 rising
SERIAL             0x48   IN    0        0             8 ASCII bytes
FPGA_CONFIG        0x50   OUT   0        0             u8 unlock code 0xAD
FPGA_DATA          0x51   OUT   0        0             ≤ 64 bytes of the image; then ``00 00``
FPGA_VERSION       0x52   IN    0        0             u16
=================  =====  ====  =======  ============  ======================================

AInScanStart (``usbAInScanStart_USB1808``): ``count`` u32 (scans, 0 = continuous),
``retrig_count`` u32, ``pacer_period`` u32 = round(100 MHz / rate − 1) (**0: no internal
clock, the scan is paced by the external clock input** — how a slave unit follows a master's
ICLKO), ``packet_size`` u8 (0xFF block I/O, 0x01 single I/O), ``options`` u8 (bit0 external
trigger, bit1 pattern trigger, bit2 retrigger, bit3 keep counters): 14 bytes (wLength 14; the
C struct's 2 pad bytes are not sent).
A START while a scan runs stalls endpoint 0.

Bulk data (``usbAInScanRead_USB1808``): scans in queue order, each sample a 32-bit
little-endian word with the 18-bit ADC code in bits 0..17 (zero-padded)::

    ch0 scan0, ch1 scan0, ..., chN scan0, ch0 scan1, ...

Calibration (``usbBuildGainTableAI_USB1808``): EEPROM from 0x7000, for channel 0..7, range 0..3:
``slope`` f32, ``offset`` f32 (8 bytes per pair); corrected code = raw · slope + offset. Volts
(``volts_USB1808``): bipolar ``(code − 131072) · R / 131072``, unipolar ``code · R / 262143``.

Status (``usbStatus_USB1808``): bit1 AIN_SCAN_RUNNING, bit2 AIN_SCAN_OVERRUN (the FIFO filled:
the scan stopped, data after it are lost), bit5 AIN_SCAN_DONE, bit8 FPGA_CONFIGURED, bit9
FPGA_CONFIG_MODE (uldaq ``Usb1808.cpp`` sets the same overrun and running masks, 0x0004 and
0x0002).

FPGA (uldaq ``UsbFpgaDevice::loadFpga``, Jasper ``usbInit_1808``): after power-up the FPGA is not
configured; FPGA_CONFIG with the unlock code 0xAD, STATUS must show FPGA_CONFIG_MODE, then the
image in FPGA_DATA transfers of 64 bytes (the last one shorter) and, the FPGA being a Xilinx
Spartan-6, two zero bytes more (:data:`FPGA_TRAILER`: clocks for its start-up sequence). The image
is the binary Spartan-6 bitstream uldaq compiles in (``src/usb/fw/Usb1808Fpga.c``, ``xxd -i`` of
``USB_1808.bin``): :data:`FPGA_IMAGE_BYTES` bytes, 0xFF padding then the sync word ``AA 99 55 66``
(:func:`check_fpga_image`). Jasper's ``usb-1808.rbf`` is the same form written as a C array: C
source text, which the device cannot take as it is.

EEPROM reads (uldaq ``UsbDaqDevice::memRead_SingleCmd``): MEM_ADDRESS once, then MEMORY reads of at
most :data:`EEPROM_READ_MAX` = 64 bytes each (the address auto-increments); Jasper reads the table
4 bytes at a time with MEM_ADDRESS before each.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum, IntFlag

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "AIN_SCAN_START_STRUCT",
    "BASE_CLOCK_HZ",
    "BM_REQUEST_IN",
    "BM_REQUEST_OUT",
    "CAL_BASE_ADDRESS",
    "DATA_ENDPOINT",
    "EEPROM_READ_MAX",
    "FIFO_BYTES",
    "FPGA_IMAGE_BYTES",
    "FPGA_SYNC_WORD",
    "FPGA_TRAILER",
    "N_AI",
    "N_RANGES",
    "PRODUCT_IDS",
    "RANGES_V",
    "VENDOR_ID",
    "AInScanStart",
    "InputMode",
    "Range",
    "Request",
    "Status",
    "adc_setup",
    "calibration_table",
    "check_fpga_image",
    "codes_to_volts",
    "decode_scans",
    "eeprom_reads",
    "fpga_transfers",
    "pacer_period",
    "pacer_rate_hz",
    "scan_queue",
    "scans_per_transfer",
]

VENDOR_ID = 0x09DB
#: USB-1808 (0x013D) and USB-1808X (0x013E)
PRODUCT_IDS = {0x013D: "USB-1808", 0x013E: "USB-1808X"}
BM_REQUEST_OUT = 0x40
BM_REQUEST_IN = 0xC0
DATA_ENDPOINT = 0x86
N_AI = 8
N_RANGES = 4
SCAN_QUEUE_LEN = 13
BASE_CLOCK_HZ = 100e6
CAL_BASE_ADDRESS = 0x7000
FPGA_UNLOCK = 0xAD
FPGA_CHUNK = 64
#: sent after the image to a Spartan-6 part (uldaq UsbFpgaDevice.cpp ``dummyData[2]``)
FPGA_TRAILER = b"\x00\x00"
#: the USB-1808(X) image's length, bytes (uldaq ``USB_1808_bin_len``; Jasper's is as long)
FPGA_IMAGE_BYTES = 464196
#: the Xilinx configuration sync word, after the 0xFF padding
FPGA_SYNC_WORD = bytes.fromhex("aa995566")
#: where the sync word may start at most (uldaq's and Jasper's images: byte 16)
FPGA_SYNC_WITHIN = 64
#: the largest EEPROM read (uldaq ``setMemMaxReadSize(MT_EEPROM, 64)``)
EEPROM_READ_MAX = 64
#: the analogue input FIFO, bytes (uldaq DaqIUsb1808.h ``FIFO_SIZE = 8 * 4 * 1024``)
FIFO_BYTES = 8 * 4 * 1024
#: 18-bit codes
CODE_MASK = 0x3FFFF
MID_SCALE = 131072


class Request(IntEnum):
    AIN_ADC_SETUP = 0x11
    AIN_SCAN_START = 0x12
    AIN_SCAN_STOP = 0x13
    AIN_SCAN_CONFIG = 0x14
    AIN_CLR_FIFO = 0x15
    MEMORY = 0x30
    MEM_ADDRESS = 0x31
    STATUS = 0x40
    TRIGGER_CONFIG = 0x43
    SERIAL = 0x48
    FPGA_CONFIG = 0x50
    FPGA_DATA = 0x51
    FPGA_VERSION = 0x52


class Status(IntFlag):
    AIN_SCAN_RUNNING = 1 << 1
    AIN_SCAN_OVERRUN = 1 << 2
    AIN_SCAN_DONE = 1 << 5
    FPGA_CONFIGURED = 1 << 8
    FPGA_CONFIG_MODE = 1 << 9


class Range(IntEnum):
    BP_10V = 0
    BP_5V = 1
    UP_10V = 2
    UP_5V = 3


class InputMode(IntEnum):
    DIFFERENTIAL = 0
    SINGLE_ENDED = 1
    GROUNDED = 3


#: full scale of each range code, V (bipolar ranges: ±)
RANGES_V = {Range.BP_10V: 10.0, Range.BP_5V: 5.0, Range.UP_10V: 10.0, Range.UP_5V: 5.0}

#: count, retrig_count, pacer_period, packet_size, options: the 14 bytes the C driver sends
#: (its ``struct AInScan_t`` has 2 pad bytes more, which ``wLength = 14`` leaves out)
AIN_SCAN_START_STRUCT = struct.Struct("<IIIBB")
STATUS_STRUCT = struct.Struct("<H")
ADDRESS_STRUCT = struct.Struct("<H")
#: each calibration value: IEEE-754 f32 little-endian (slope, then offset, per input and range)
CAL_VALUE = np.dtype("<f4")
CAL_TABLE_BYTES = N_AI * N_RANGES * 2 * CAL_VALUE.itemsize


#: the bulk endpoint's packet size (high speed)
PACKET_BYTES = 512


def scans_per_transfer(scans: int, n_queue: int) -> int:
    """``scans`` rounded up so that a bulk transfer is whole scans and whole 512-byte packets:
    a multiple of ``128 / gcd(128, n_queue)`` scans (4 bytes per sample). A transfer that ends
    inside a packet would overflow (libusb's LIBUSB_ERROR_OVERFLOW) when the device sends it full.
    """
    step = (PACKET_BYTES // 4) // math.gcd(PACKET_BYTES // 4, n_queue)
    return -(-max(scans, 1) // step) * step


def pacer_period(rate_hz: float) -> int:
    """The pacer timer period of ``rate_hz``: ``round(100 MHz / rate − 1)``."""
    return round(BASE_CLOCK_HZ / rate_hz - 1)


def pacer_rate_hz(period: int) -> float:
    """The scan rate a pacer period gives: ``100 MHz / (period + 1)``."""
    return BASE_CLOCK_HZ / (period + 1)


@dataclass(frozen=True)
class AInScanStart:
    """The AIN_SCAN_START data stage (``struct AInScan_t`` without its pad: 14 bytes)."""

    count: int
    retrig_count: int
    pacer_period: int
    packet_size: int = 0xFF
    options: int = 0

    def encode(self) -> bytes:
        return AIN_SCAN_START_STRUCT.pack(
            self.count, self.retrig_count, self.pacer_period, self.packet_size, self.options
        )

    @classmethod
    def decode(cls, data: bytes) -> AInScanStart:
        return cls(*AIN_SCAN_START_STRUCT.unpack(data))


def fpga_transfers(image: bytes) -> list[bytes]:
    """The FPGA_DATA data stages for ``image``: 64-byte pieces (the last one shorter), then
    :data:`FPGA_TRAILER`."""
    return [image[k : k + FPGA_CHUNK] for k in range(0, len(image), FPGA_CHUNK)] + [FPGA_TRAILER]


def eeprom_reads(length: int) -> list[int]:
    """The MEMORY read lengths for ``length`` bytes from one MEM_ADDRESS: at most 64 each."""
    full, rest = divmod(length, EEPROM_READ_MAX)
    return [EEPROM_READ_MAX] * full + ([rest] if rest else [])


def check_fpga_image(image: bytes, source: str) -> None:
    """Refuse what is not the USB-1808(X)'s binary FPGA image.

    Its form: :data:`FPGA_IMAGE_BYTES` bytes, 0xFF padding, the Xilinx sync word
    ``AA 99 55 66`` within the first 64 bytes.

    Raises
    ------
    ValueError
        One line naming ``source`` and the fix: C source text (a ``.c`` or Jasper's ``.rbf``
        array: convert it with ``dimacq devices mcc-fpga``), no sync word, or another length.
    """
    head = image[:4096]
    if head and all(b in b"\t\n\r" or 32 <= b < 127 for b in head):
        raise ValueError(
            f"{source} is text (C source of an array?), not the binary FPGA image; convert it "
            f"with: dimacq devices mcc-fpga {source} -o usb-1808.bin"
        )
    at = image.find(FPGA_SYNC_WORD, 0, FPGA_SYNC_WITHIN + len(FPGA_SYNC_WORD))
    if at < 0 or image[:at] != b"\xff" * at:
        raise ValueError(
            f"{source}: no Xilinx sync word AA995566 after 0xFF padding in its first "
            f"{FPGA_SYNC_WITHIN} bytes: not a USB-1808 FPGA image; give uldaq's USB_1808.bin"
        )
    if len(image) != FPGA_IMAGE_BYTES:
        raise ValueError(
            f"{source}: {len(image)} bytes, the USB-1808 FPGA image has {FPGA_IMAGE_BYTES}; "
            "give the whole USB_1808.bin (uldaq src/usb/fw/Usb1808Fpga.c)"
        )


def adc_setup(ranges: list[Range], modes: list[InputMode]) -> bytes:
    """AIN_ADC_SETUP data: one byte per input, ``range | mode << 2``."""
    return bytes(int(r) | int(m) << 2 for r, m in zip(ranges, modes, strict=True))


def scan_queue(channels: list[int]) -> tuple[int, bytes]:
    """AIN_SCAN_CONFIG: ``(wIndex, data)``: wIndex = index of the queue's last element
    (``lastChan − 1`` for ``lastChan`` elements in the C driver), the 13 queue bytes (AI numbers,
    zero-padded)."""
    if not 0 < len(channels) <= SCAN_QUEUE_LEN:
        raise ValueError(f"scan queue of {len(channels)} elements; give 1..{SCAN_QUEUE_LEN}")
    return len(channels) - 1, bytes(channels) + bytes(SCAN_QUEUE_LEN - len(channels))


def calibration_table(data: bytes) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(slope, offset)``, each shape (8 inputs, 4 ranges), from the EEPROM bytes."""
    if len(data) != CAL_TABLE_BYTES:
        raise ValueError(f"calibration table of {len(data)} bytes; expected {CAL_TABLE_BYTES}")
    pairs = np.frombuffer(data, dtype=CAL_VALUE).reshape(N_AI, N_RANGES, 2).astype(float)
    return pairs[..., 0], pairs[..., 1]


def decode_scans(data: bytes, n_queue: int) -> NDArray[np.uint32]:
    """Bulk data → codes, shape (n_scans, n_queue) (the 18 low bits of each LE u32)."""
    words = np.frombuffer(data, dtype="<u4")
    if words.size % n_queue:
        raise ValueError(f"{len(data)} bytes are not whole scans of {n_queue} channels × 4 bytes")
    return np.bitwise_and(words, np.uint32(CODE_MASK)).reshape(-1, n_queue)


def codes_to_volts(
    codes: NDArray[np.integer],
    ranges: NDArray[np.integer],
    slope: NDArray[np.float64],
    offset: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Calibrated volts and clipping of raw codes.

    ``codes`` shape (n_scans, n_ch); ``ranges``, ``slope``, ``offset`` shape (n_ch,) (the
    channel's range code and its calibration pair). ``c = rint(raw · slope + offset)`` clipped
    to 0..2¹⁸−1 (``usbAIn_USB1808``), then bipolar ``V = (c − 131072) · R / 131072``, unipolar
    ``V = c · R / 262143``. Clipped: the ADC's raw code at 0 or 2¹⁸−1 (after the correction a
    saturated code need not reach the ends of the scale).
    """
    c = np.clip(np.rint(codes * slope + offset), 0, CODE_MASK)
    full = np.array([RANGES_V[Range(int(r))] for r in ranges])
    bipolar = np.asarray(ranges) <= Range.BP_5V
    volts = np.where(bipolar, (c - MID_SCALE) * full / MID_SCALE, c * full / CODE_MASK)
    return volts, (codes <= 0) | (codes >= CODE_MASK)
