"""The USB-1808(X)'s FPGA being configured: a Xilinx Spartan-6 XC6SLX16 taking a bitstream.

What the part does with the bytes the microcontroller passes on (Xilinx UG380, *Spartan-6 FPGA
Configuration User Guide*, chapter 5 "Configuration Details": bitstream, packets, registers):

- until the 32-bit sync word ``AA 99 55 66`` it ignores the data (the 0xFF padding; a text file
  never has it, so the part never leaves this state);
- then 16-bit big-endian words: a type-1 header ``001 op reg[10:5] count[4:0]`` (op 00 NOP,
  10 write) followed by ``count`` words; a type-2 header ``010 op reg[10:5] ...`` followed by a
  32-bit word count and that many words (the frame data, register FDRI = 3), after which the part
  reads two words of automatic CRC;
- a write to IDCODE (register 14, two words) that is not the part's own stops configuration
  (ID error); FDRI frame data of another length than the part's frame memory leave the part
  unconfigured;
- CMD (register 5) START (5) runs the start-up sequence, DESYNC (13) ends the packet stream; the
  part is configured (DONE high: the USB-1808's STATUS FPGA_CONFIGURED) when it has seen both, in
  that order, with no error.

Part facts: IDCODE ``0x04002093`` (XC6SLX16) and the frame-data length (231953 words) are those of
the image uldaq ships for the USB-1808 (``src/usb/fw/Usb1808Fpga.c``) and of Warren Jasper's
earlier one, which agree. The configuration CRC is not computed.
"""

from __future__ import annotations

import struct

__all__ = ["FDRI_WORDS", "IDCODE", "Spartan6", "synthetic_image"]

IDCODE = 0x04002093
FDRI_WORDS = 231953
SYNC = bytes.fromhex("aa995566")
_REG_FDRI, _REG_CMD, _REG_IDCODE = 3, 5, 14
_CMD_START, _CMD_DESYNC = 5, 13


class Spartan6:
    """The configuration logic of one part; :meth:`feed` the bytes, read :attr:`done`."""

    def __init__(self, idcode: int = IDCODE, fdri_words: int = FDRI_WORDS) -> None:
        self.idcode = idcode
        self.fdri_words = fdri_words
        self.reset()

    def reset(self) -> None:
        """PROGRAM_B pulsed: the part forgets its configuration and waits for the sync word."""
        self.synced = False
        self.done = False
        self.error = ""
        self.started = False
        self._pending = bytearray()
        self._tail = b""
        self._reg = 0
        self._words_left = 0  # data words of the current packet still to come
        self._data: list[int] = []
        self._fdri = False
        self._count = 0
        self._count_words = 0

    def feed(self, data: bytes) -> None:
        if self.done or self.error:
            return  # desynchronised (or stopped): the part ignores what follows
        if not self.synced:
            buf = self._tail + data
            at = buf.find(SYNC)
            if at < 0:
                self._tail = buf[-(len(SYNC) - 1) :]
                return
            self.synced = True
            data = buf[at + len(SYNC) :]
        self._pending += data
        n = len(self._pending) // 2 * 2
        words = struct.unpack(f">{n // 2}H", self._pending[:n])
        del self._pending[:n]
        for w in words:
            self._word(w)
            if self.done or self.error:
                return

    def _word(self, w: int) -> None:
        if self._count_words:  # the 32-bit count of a type-2 packet, high word first
            self._count = self._count << 16 | w
            self._count_words -= 1
            if not self._count_words:
                self._type2_count(self._count)
            return
        if self._words_left:
            self._words_left -= 1
            if not self._fdri:
                self._data.append(w)
            if not self._words_left:
                self._packet_done()
            return
        kind, op, reg = w >> 13, (w >> 11) & 3, (w >> 5) & 0x3F
        if kind == 1:
            self._reg, self._fdri, self._data = reg, False, []
            self._words_left = w & 0x1F if op == 2 else 0
            if op == 2 and not self._words_left:
                self._packet_done()
        elif kind == 2 and op == 2:
            self._reg, self._fdri, self._data = reg, reg == _REG_FDRI, []
            self._count, self._count_words = 0, 2
        else:
            self.error = f"word {w:#06x} is no packet header"

    def _type2_count(self, count: int) -> None:
        """Frame data: the part's length or an error; then its data and two automatic-CRC words."""
        if self._fdri and count != self.fdri_words:
            self.error = f"frame data of {count} words; the part's memory takes {self.fdri_words}"
            return
        self._words_left = count + (2 if self._fdri else 0)
        if not self._words_left:
            self._packet_done()

    def _packet_done(self) -> None:
        if self._reg == _REG_IDCODE and not self._fdri:
            got = (self._data[0] << 16 | self._data[1]) if len(self._data) == 2 else -1
            if got != self.idcode:
                self.error = f"IDCODE {got:#010x} is not the part's {self.idcode:#010x}"
        elif self._reg == _REG_CMD and self._data:
            if self._data[-1] == _CMD_START:
                self.started = True
            elif self._data[-1] == _CMD_DESYNC:
                self.done = self.started
                if not self.started:
                    self.error = "DESYNC without START"
        self._data = []


def synthetic_image(
    idcode: int = IDCODE, fdri_words: int = FDRI_WORDS, length: int = 464196
) -> bytes:
    """A bitstream of the USB-1808 image's form and length for the simulated lab (the vendor's
    image is not shipped): padding, sync, IDCODE, frame data of the part's length (a fixed
    pattern), NOPs to ``length`` bytes, START, DESYNC and 14 NOPs (as the vendor's ends)."""

    def t1(reg: int, *words: int) -> bytes:
        return struct.pack(f">H{len(words)}H", 0x3000 | reg << 5 | len(words), *words)

    nop = struct.pack(">H", 0x2000)
    head = b"\xff" * 16 + SYNC + t1(_REG_CMD, 7) + t1(_REG_IDCODE, idcode >> 16, idcode & 0xFFFF)
    head += t1(_REG_CMD, 1) + struct.pack(">HI", 0x5000 | _REG_FDRI << 5, fdri_words)
    frames = bytes((k * 37 + 11) & 0xFF for k in range(2 * fdri_words)) + bytes(4)
    tail = t1(_REG_CMD, _CMD_START) + t1(_REG_CMD, _CMD_DESYNC) + nop * 14  # as the vendor's
    pad = length - len(head) - len(frames) - len(tail)
    if pad < 0 or pad % 2:
        raise ValueError(f"length {length} bytes cannot hold a {fdri_words}-word image")
    return head + frames + nop * (pad // 2) + tail
