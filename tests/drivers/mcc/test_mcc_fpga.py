"""The USB-1808 FPGA image where a lab gets it: the C arrays MCC publishes it as (uldaq's
``xxd -i`` file, Warren Jasper's ``usb-1808.rbf``), an installed libuldaq, a file; its form
checked, text refused with the fix named."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from dimacq.cli.main import main
from dimacq.drivers.mcc import fpga
from dimacq.errors import SetupError
from dimacq.simulators.mcc.backend import lab_fpga_image


def _xxd(image: bytes) -> str:
    """As uldaq's src/usb/fw/Usb1808Fpga.c (lines 1-11 and 38693-38694): ``xxd -i``."""
    rows = ",\n  ".join(
        ", ".join(f"0x{b:02x}" for b in image[k : k + 12]) for k in range(0, len(image), 12)
    )
    return (
        "// Usb1808Fpga.c\n// - xxd -i USB_1808.bin > Usb1808Fpga.c 0x12 in a comment\n"
        f"const unsigned char USB_1808_bin[] = {{\n  {rows}\n}};\n"
        f"const unsigned int USB_1808_bin_len = {len(image)};\n"
    )


def _jasper(image: bytes) -> str:
    """As Jasper's USB/mcc-libusb/usb-1808.rbf (line 1): ``static unsigned char FPGA_data[]``."""
    rows = ",\n  ".join(
        ",  ".join(f"0x{b:02x}" for b in image[k : k + 8]) for k in range(0, len(image), 8)
    )
    return f"static unsigned char FPGA_data[] = {{\n  {rows}\n}};\n"


@pytest.mark.slow
@pytest.mark.parametrize("form", [_xxd, _jasper])
def test_c_arrays_give_the_image(form) -> None:  # type: ignore[no-untyped-def]
    image = lab_fpga_image()
    assert fpga.c_array_bytes(form(image)) == image


def test_read_image_refuses_text_with_the_fix(tmp_path: Path) -> None:
    image = lab_fpga_image()
    rbf = tmp_path / "usb-1808.rbf"
    rbf.write_text(_jasper(image[:4096]))
    with pytest.raises(SetupError, match=r"is text .*dimacq devices mcc-fpga .*usb-1808.rbf") as e:
        fpga.read_image(rbf)
    assert "\n" not in str(e.value)
    short = tmp_path / "short.bin"
    short.write_bytes(image[:100_000])
    with pytest.raises(SetupError, match=r"100000 bytes, the USB-1808 FPGA image has 464196"):
        fpga.read_image(short)
    with pytest.raises(SetupError, match=r"cannot read it"):
        fpga.read_image(tmp_path / "absent.bin")
    good = tmp_path / "USB_1808.bin"
    good.write_bytes(image)
    assert fpga.read_image(good) == image


def test_image_found_inside_a_library(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two Spartan-6 images of the same length in one library (as libuldaq holds the USB-1808's
    and the USB-DIO32HS's): the one whose SHA-256 is known is taken."""
    image = lab_fpga_image()
    other = image.replace(b"\x20\x00" * 8, b"\x20\x00" * 7 + b"\x30\x00", 1)
    lib = tmp_path / "libuldaq.so.1.2.1"
    lib.write_bytes(b"\x7fELF" + bytes(1000) + other + b"\xff" * 40 + image + bytes(77))
    monkeypatch.setattr(fpga, "KNOWN_IMAGES", {hashlib.sha256(image).hexdigest(): "the lab's"})
    found = fpga.image_from_library([lib])
    assert found is not None and found[0] == image and "the lab's" in found[1]
    assert fpga.image_from_library([tmp_path / "none.so"]) is None
    monkeypatch.setenv("LD_LIBRARY_PATH", str(tmp_path))
    assert lib in fpga.library_paths()


@pytest.mark.slow
def test_cli_converts_the_c_source(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    image = lab_fpga_image()
    src = tmp_path / "Usb1808Fpga.c"
    src.write_text(_xxd(image))
    out = tmp_path / "fw" / "USB_1808.bin"
    assert main(["devices", "mcc-fpga", str(src), "-o", str(out)]) == 0
    assert out.read_bytes() == image
    assert "set daq_fpga_file" in capsys.readouterr().out
    bad = tmp_path / "half.c"
    bad.write_text(_xxd(image[:1000]))
    assert main(["devices", "mcc-fpga", str(bad), "-o", str(tmp_path / "x.bin")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "1000 bytes, the USB-1808 FPGA image has 464196" in err
