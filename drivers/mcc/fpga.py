"""Where a lab gets the USB-1808(X) FPGA image, and its form checked before it is sent.

The image is the binary Xilinx Spartan-6 bitstream (:func:`dimacq.drivers.mcc.protocol.
check_fpga_image`). MCC publishes it only inside source code and its library:

- uldaq's ``src/usb/fw/Usb1808Fpga.c``: ``xxd -i`` of ``USB_1808.bin``, a C array;
- Warren Jasper's ``USB/mcc-libusb/usb-1808.rbf``: an earlier image as a C array
  (``static unsigned char FPGA_data[] = {...}``), despite its name not a binary ``.rbf``;
- an installed ``libuldaq.so``, which carries the uldaq array in its read-only data.

:func:`c_array_bytes` turns such an array into the binary image (``dimacq devices mcc-fpga``);
:func:`image_from_library` finds the image inside an installed libuldaq by the SHA-256 of the
images we know (:data:`KNOWN_IMAGES`); :func:`read_image` reads a file and refuses one that is not
the binary image with a one-line error naming the fix.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
from collections.abc import Iterable
from pathlib import Path

from dimacq.drivers.mcc import protocol as p
from dimacq.errors import SetupError

__all__ = ["KNOWN_IMAGES", "c_array_bytes", "image_from_library", "library_paths", "read_image"]

log = logging.getLogger(__name__)

#: SHA-256 of the USB-1808(X) images published → where (both 464196 bytes)
KNOWN_IMAGES = {
    "6c6f3336b2c390b3de96cdab94a9102b94364074a73f977a781378119129d0d2": (
        "uldaq 1.2.1 src/usb/fw/Usb1808Fpga.c (USB_1808.bin)"
    ),
    "4adbac6a6da9f656837bd0416d098df77e0819f2562f808f4b2262374de1d483": (
        "wjasper/Linux_Drivers USB/mcc-libusb/usb-1808.rbf (FPGA_data[])"
    ),
}

_ARRAY_START = re.compile(r"\[\s*\w*\s*\]\s*=\s*\{|=\s*\(")
_HEX_BYTE = re.compile(r"0[xX]([0-9a-fA-F]{1,2})\b")


def c_array_bytes(text: str) -> bytes:
    """The bytes of the first array in C (``name[] = { 0xff, ... };``) or Python
    (``name = ( 0xff, ... )``) source, as ``xxd -i`` and Jasper's files write them.

    Raises
    ------
    ValueError
        No array of hexadecimal bytes in ``text``.
    """
    m = _ARRAY_START.search(text)
    if m is None:
        raise ValueError("no array '[] = {' or '= (' in the text; give the .c file of the image")
    end = text.find("}" if text[m.end() - 1] == "{" else ")", m.end())
    body = text[m.end() : end if end >= 0 else len(text)]
    data = bytes(int(h, 16) for h in _HEX_BYTE.findall(body))
    if not data:
        raise ValueError("the array holds no 0x.. bytes; give the .c file of the image")
    return data


def read_image(path: str | Path) -> bytes:
    """The binary image in ``path``, its form checked.

    Raises
    ------
    SetupError
        The file cannot be read, is text (a C array: the error names the converter), has no
        Xilinx sync word, or another length than the USB-1808's image.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise SetupError(
            f"daq_fpga_file = {str(path)!r}: cannot read it ({err.strerror}); give the path of "
            "the binary USB_1808.bin (dimacq devices mcc-fpga makes it from uldaq's source)"
        ) from err
    try:
        p.check_fpga_image(data, str(path))
    except ValueError as err:
        raise SetupError(f"daq_fpga_file: {err}") from err
    known = KNOWN_IMAGES.get(hashlib.sha256(data).hexdigest())
    log.info("USB-1808 FPGA image %s: %s", path, known or "form checked, not one we know")
    return data


def library_paths(extra: Iterable[str] = ()) -> list[Path]:
    """Installed libuldaq files: ``LD_LIBRARY_PATH``, then the usual library folders."""
    folders = [*extra, *os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep)]
    folders += [
        "/usr/local/lib",
        "/usr/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib/aarch64-linux-gnu",
        "/usr/lib/arm-linux-gnueabihf",
        "/opt/homebrew/lib",
    ]
    out: list[Path] = []
    for folder in folders:
        if folder and Path(folder).is_dir():
            for f in sorted(Path(folder).glob("libuldaq*")):
                if f.is_file() and f.resolve() not in [o.resolve() for o in out]:
                    out.append(f)
    return out


def image_from_library(paths: Iterable[Path] | None = None) -> tuple[bytes, str] | None:
    """The USB-1808 image inside an installed libuldaq, and where it was found; None if none.

    Each place where 0xFF padding and the sync word start is cut to :data:`~dimacq.drivers.mcc.
    protocol.FPGA_IMAGE_BYTES` bytes and kept if its SHA-256 is one of :data:`KNOWN_IMAGES`
    (the library holds other Spartan-6 images of the same length, e.g. the USB-DIO32HS's).
    """
    head = b"\xff" * 16 + p.FPGA_SYNC_WORD
    for lib in library_paths() if paths is None else paths:
        try:
            blob = Path(lib).read_bytes()
        except OSError:
            continue
        at = blob.find(head)
        while at >= 0:
            image = blob[at : at + p.FPGA_IMAGE_BYTES]
            known = KNOWN_IMAGES.get(hashlib.sha256(image).hexdigest())
            if known is not None:
                return image, f"{lib} ({known})"
            at = blob.find(head, at + 1)
    return None
