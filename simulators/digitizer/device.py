"""The simulated sonic digitizer: a byte-in, byte-out model of the device.

:class:`SimulatedDigitizer` interprets the commands of
:mod:`dimacq.drivers.digitizer.protocol` (the only driver module a simulator may import: the
codec) and answers with the same bytes a real unit would, the physics coming from
:mod:`dimacq.simulators.lab.sonic`. Two transports carry it: the pyserial URL handler
(:mod:`dimacq.simulators.digitizer.protocol_simdigitizer`, ``simdigitizer://name``) and a real
pseudo-terminal (:mod:`dimacq.simulators.digitizer.pty`).

Simulator-only commands (a real unit answers ``$ERR,1``)::

    SIM:PROBE x,y,z,ux,uy,uz   hold the probe tip at (x, y, z) m (DACS), axis u (emitter 2 → tip)
    SIM:TEMP t                 air temperature, °C
    SIM:ECHO p                 probability that a shot carries an echo (0..1)
    SIM:ECHOES?                $SIM,ECHOES,<n>,<seq>,...: sequence numbers of echo-corrupted shots
                               since reset
    SIM:TRUTH?                 $SIM,TRUTH,<x>,<y>,<z>,<c>: tip position (m) and speed of sound (m/s)

The test hooks :meth:`SimulatedDigitizer.unplug` / :meth:`plug` make the port vanish and come back,
and :meth:`corrupt_next` damages the next reply line (garbage, checksum, truncation).
"""

from __future__ import annotations

import logging
import os
import threading
import time
import tomllib
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.devices.digitizer import DeviceIdentity, DigitizerSettings, ShotRecord
from dimacq.drivers.digitizer import protocol as wire
from dimacq.errors import ProtocolError, SetupError
from dimacq.simulators.imperfections import fault_log
from dimacq.simulators.lab.sonic import (
    SonicArray,
    SonicEnvironment,
    SonicLab,
    SonicProbe,
    speed_of_sound_m_s,
)

__all__ = ["SimulatedDigitizer", "default_config_path", "lab_from_config"]

log = logging.getLogger(__name__)


def default_config_path() -> Path:
    """``$DIMACQ_CONFIG_DIR/digitizer/array.toml`` or the repository's ``config/digitizer/array.toml``."""
    base = os.environ.get("DIMACQ_CONFIG_DIR")
    root = Path(base) if base else Path(__file__).resolve().parents[2] / "config"
    return root / "digitizer" / "array.toml"


def lab_from_config(path: Path | None = None) -> SonicLab:
    """Build the virtual lab's digitizer corner from the array configuration file."""
    path = path or default_config_path()
    try:
        cfg: dict[str, Any] = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise SetupError(
            f"digitizer array config {path}: cannot read ({err}); fix the file"
        ) from err
    try:
        array = SonicArray(
            microphones_m=np.asarray(cfg["array"]["microphones_m"], dtype=float),
            bar_length_m=float(cfg["bar"]["length_m"]),
            delay_s=float(cfg["counter"]["delay_counts"]) / float(cfg["counter"]["clock_hz"]),
            clock_hz=float(cfg["counter"]["clock_hz"]),
            counter_bits=int(cfg["counter"]["bits"]),
        )
        probe = SonicProbe(
            emitter_spacing_m=float(cfg["probe"]["emitter_spacing_m"]),
            tip_length_m=float(cfg["probe"]["tip_length_m"]),
        )
    except KeyError as err:
        raise SetupError(
            f"digitizer array config {path}: missing key {err}; see config/digitizer/array.toml"
        ) from err
    return SonicLab(array=array, probe=probe)


class SimulatedDigitizer:
    """A sonic digitizer speaking the SD-3 protocol, fed by the virtual lab.

    Parameters
    ----------
    lab : SonicLab
        Physics (array, probe, air, where the probe is held).
    seed : int
        Seed of the noise and echo generator (the same seed gives the same bytes).
    serial : str
        Serial number reported by ``*IDN?``.
    shot_rate_hz : float
        Streaming rate; 0 sends a whole stream at once.
    """

    def __init__(
        self, lab: SonicLab, *, seed: int = 0, serial: str = "SIM0001", shot_rate_hz: float = 0.0
    ) -> None:
        self.lab = lab
        self.seed = seed
        self.serial = serial
        self.shot_rate_hz = shot_rate_hz
        self._plugged = True
        #: imperfections of a real serial link (random, seeded; see :meth:`set_imperfections`)
        self.noise_rate = 0.0
        self.port_loss_rate = 0.0
        self.port_loss_s = 0.3
        self._link_rng = np.random.default_rng([seed, 0x5E41])
        self._lost_until = 0.0
        #: bumped when the port drops off: a handle opened before is dead for good
        self.port_generation = 0
        #: faults injected so far, by kind
        self.injected: dict[str, int] = {}
        self._lock = threading.RLock()
        self._rx = bytearray()
        self._out = bytearray()
        self._corrupt: deque[str] = deque()
        self._reset()

    # ------------------------------------------------------------------ state
    def _reset(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        n_mics = len(self.lab.array.microphones_m)
        self.settings = DigitizerSettings(
            emitters=2,
            microphones=n_mics,
            averaging=1,
            bar_repeats=4,
            clock_hz=self.lab.array.clock_hz,
            delay_counts=round(self.lab.array.delay_s * self.lab.array.clock_hz),
        )
        self.seq = 0
        self.echo_seqs: list[int] = []
        self._stream_left = 0
        self._stream_total = 0
        self._next_due = 0.0

    @property
    def identity(self) -> DeviceIdentity:
        return DeviceIdentity(
            vendor="DIMACQ",
            model="SD-3-SIM",
            serial=self.serial,
            firmware="1.0",
            n_microphones=len(self.lab.array.microphones_m),
        )

    # ------------------------------------------------------------------ test hooks
    @property
    def plugged(self) -> bool:
        """The port is there (not unplugged, not in a random port loss)."""
        return self._plugged and time.monotonic() >= self._lost_until

    def unplug(self) -> None:
        """The cable is pulled: open ports fail, bytes in flight are lost."""
        with self._lock:
            self._plugged = False
            self._out.clear()
            self._rx.clear()

    def plug(self) -> None:
        """The cable is back; the device kept its settings and sequence number."""
        with self._lock:
            self._plugged = True

    def set_imperfections(
        self, *, noise_rate: float, port_loss_rate: float, port_loss_s: float
    ) -> None:
        """Random faults of a real link: per reply line, noise that damages it (garbage before
        it, a flipped bit, a cut line), probability ``noise_rate``; per command, the USB-serial
        adapter drops off for ``port_loss_s`` seconds (the command and bytes in flight are lost,
        open ports fail), probability ``port_loss_rate``. Each is logged on
        :data:`~dimacq.simulators.imperfections.fault_log`."""
        with self._lock:
            self.noise_rate = float(noise_rate)
            self.port_loss_rate = float(port_loss_rate)
            self.port_loss_s = float(port_loss_s)

    def _inject(self, kind: str, message: str, *args: object) -> None:
        self.injected[kind] = self.injected.get(kind, 0) + 1
        fault_log.warning("simulated fault %s: digitizer " + message, kind, *args)

    def corrupt_next(self, kind: str) -> None:
        """Damage the next reply line: ``"garbage"`` (noise before it), ``"checksum"`` (one byte
        flipped), ``"truncate"`` (the line is cut and the device sends it again)."""
        if kind not in {"garbage", "checksum", "truncate"}:
            raise ValueError(f"corrupt_next kind {kind!r}: use garbage, checksum or truncate")
        with self._lock:
            self._corrupt.append(kind)

    # ------------------------------------------------------------------ byte interface
    def receive(self, data: bytes) -> None:
        """Bytes from the host; complete commands (CR-terminated) are executed."""
        with self._lock:
            self._rx += data
            while True:
                cr = self._rx.find(b"\r")
                if cr < 0:
                    if len(self._rx) > 4 * wire.MAX_COMMAND:
                        self._rx.clear()
                        self._emit(
                            wire.frame("ERR", int(wire.ErrorCode.BAD_ARGUMENT), "line too long")
                        )
                    return
                line = bytes(self._rx[:cr]).replace(b"\n", b"")
                del self._rx[: cr + 1]
                if (
                    line.strip()
                    and self.port_loss_rate
                    and self._link_rng.random() < self.port_loss_rate
                ):
                    self._lost_until = time.monotonic() + self.port_loss_s
                    self.port_generation += 1  # open handles are dead: reopen the port
                    self._out.clear()
                    self._rx.clear()
                    self._inject("serial_port_loss", "port drops off for %g s", self.port_loss_s)
                    return
                if line.strip():
                    self._execute(line)

    def poll(self, now: float | None = None) -> bytes:
        """Bytes the device has sent by time ``now`` (monotonic seconds); clears them."""
        with self._lock:
            if self._stream_left:
                now = time.monotonic() if now is None else now
                while self._stream_left and now >= self._next_due:
                    self._stream_one()
                    self._next_due += 1.0 / self.shot_rate_hz
            out = bytes(self._out)
            self._out.clear()
            return out

    @property
    def streaming(self) -> bool:
        return self._stream_left > 0

    def _emit(self, line: bytes) -> None:
        kind = self._corrupt.popleft() if self._corrupt else None
        if kind is None and self.noise_rate and self._link_rng.random() < self.noise_rate:
            kind = str(self._link_rng.choice(["garbage", "checksum", "truncate"]))
            self._inject("serial_noise", "reply line damaged (%s)", kind)
        if kind == "garbage":
            self._out += b"\x00\xff#noise\r\n\x13" + line
        elif kind == "checksum":
            damaged = bytearray(line)
            damaged[len(damaged) // 2] ^= 0x01
            self._out += damaged
        elif kind == "truncate":
            self._out += line[: len(line) // 2] + line
        else:
            self._out += line

    # ------------------------------------------------------------------ commands
    def _error(self, code: wire.ErrorCode, text: str) -> None:
        self._emit(wire.frame("ERR", int(code), text.replace(",", ";")))

    def _execute(self, line: bytes) -> None:
        try:
            cmd = wire.parse_command(line)
        except ProtocolError as err:
            self._error(wire.ErrorCode.UNKNOWN_COMMAND, str(err)[:60])
            return
        log.debug("simulated digitizer command %r", cmd)
        if self._stream_left and cmd.name not in {"STOP", "*IDN?"}:
            self._error(wire.ErrorCode.BUSY, "streaming; send STOP")
            return
        try:
            handler = _HANDLERS.get(cmd.name)
            if handler is None:
                self._error(wire.ErrorCode.UNKNOWN_COMMAND, f"unknown command {cmd.name[:20]}")
                return
            handler(self, cmd.args)
        except (ValueError, ProtocolError) as err:
            self._error(wire.ErrorCode.BAD_ARGUMENT, str(err)[:80])

    def _cmd_idn(self, args: str) -> None:
        self._emit(wire.encode_identity(self.identity))

    def _cmd_rst(self, args: str) -> None:
        self._reset()
        self._emit(wire.frame("OK", "RST"))

    def _cmd_cfg_query(self, args: str) -> None:
        self._emit(wire.encode_settings(self.settings))

    def _cmd_cfg(self, args: str) -> None:
        values = wire.parse_cfg_args(args)
        s = self.settings
        e = values.get("E", s.emitters)
        m = values.get("M", s.microphones)
        a = values.get("A", s.averaging)
        b = values.get("B", s.bar_repeats)
        n_inst = len(self.lab.array.microphones_m)
        if not (1 <= e <= 2 and 3 <= m <= n_inst and 1 <= a <= 16 and 1 <= b <= 8):
            raise ValueError(f"E 1-2 M 3-{n_inst} A 1-16 B 1-8 (got E={e} M={m} A={a} B={b})")
        self.settings = DigitizerSettings(
            emitters=e,
            microphones=m,
            averaging=a,
            bar_repeats=b,
            clock_hz=s.clock_hz,
            delay_counts=s.delay_counts,
        )
        self._emit(wire.encode_settings(self.settings))

    def _make_shot(self) -> ShotRecord:
        s = self.settings
        shot = self.lab.shot(
            self.rng,
            n_emitters=s.emitters,
            n_microphones=s.microphones,
            averaging=s.averaging,
            n_bar=s.bar_repeats,
        )
        status = 0
        if shot.overflow[0]:
            status |= wire.Status.OVERFLOW_E1
        if len(shot.overflow) > 1 and shot.overflow[1]:
            status |= wire.Status.OVERFLOW_E2
        if shot.bar_overflow:
            status |= wire.Status.BAR_OVERFLOW
        record = ShotRecord(
            seq=self.seq,
            status=int(status),
            averaging=s.averaging,
            counts=shot.counts,
            bar_counts=shot.bar_counts,
        )
        if shot.echo:
            self.echo_seqs.append(self.seq)
        self.seq = (self.seq + 1) % 65536
        return record

    def _cmd_shot(self, args: str) -> None:
        self._emit(wire.encode_shot(self._make_shot()))

    def _cmd_strm(self, args: str) -> None:
        n = int(args)
        if not 1 <= n <= 100000:
            raise ValueError("STRM n: 1 <= n <= 100000")
        self._stream_left = n
        self._stream_total = n
        self._next_due = time.monotonic()
        if self.shot_rate_hz <= 0:
            while self._stream_left:
                self._stream_one()

    def _stream_one(self) -> None:
        self._emit(wire.encode_shot(self._make_shot()))
        self._stream_left -= 1
        if self._stream_left == 0:
            self._emit(wire.frame("OK", "STRM", self._stream_total))

    def _cmd_stop(self, args: str) -> None:
        self._stream_left = 0
        self._emit(wire.frame("OK", "STOP"))

    # ------------------------------------------------------------------ simulator-only commands
    def _cmd_sim_probe(self, args: str) -> None:
        values = [float(v) for v in args.split(",")]
        if len(values) != 6:
            raise ValueError("SIM:PROBE x,y,z,ux,uy,uz")
        self.lab.place_probe(np.array(values[:3]), np.array(values[3:]))
        self._emit(wire.frame("OK", "SIM:PROBE"))

    def _cmd_sim_temp(self, args: str) -> None:
        t = float(args)
        if not -40.0 <= t <= 60.0:
            raise ValueError("SIM:TEMP t: -40 <= t <= 60 degC")
        self.lab.environment.temperature_c = t
        self._emit(wire.frame("OK", "SIM:TEMP"))

    def _cmd_sim_echo(self, args: str) -> None:
        p = float(args)
        if not 0.0 <= p <= 1.0:
            raise ValueError("SIM:ECHO p: 0 <= p <= 1")
        self.lab.environment.echo_probability = p
        self._emit(wire.frame("OK", "SIM:ECHO"))

    def _cmd_sim_echoes(self, args: str) -> None:
        self._emit(wire.frame("SIM", "ECHOES", len(self.echo_seqs), *self.echo_seqs))

    def _cmd_sim_truth(self, args: str) -> None:
        c = float(speed_of_sound_m_s(self.lab.environment.temperature_c))
        x, y, z = (f"{v:.9f}" for v in self.lab.tip_m)
        self._emit(wire.frame("SIM", "TRUTH", x, y, z, f"{c:.6f}"))


_HANDLERS = {
    "*IDN?": SimulatedDigitizer._cmd_idn,
    "RST": SimulatedDigitizer._cmd_rst,
    "CFG?": SimulatedDigitizer._cmd_cfg_query,
    "CFG": SimulatedDigitizer._cmd_cfg,
    "SHOT": SimulatedDigitizer._cmd_shot,
    "STRM": SimulatedDigitizer._cmd_strm,
    "STOP": SimulatedDigitizer._cmd_stop,
    "SIM:PROBE": SimulatedDigitizer._cmd_sim_probe,
    "SIM:TEMP": SimulatedDigitizer._cmd_sim_temp,
    "SIM:ECHO": SimulatedDigitizer._cmd_sim_echo,
    "SIM:ECHOES?": SimulatedDigitizer._cmd_sim_echoes,
    "SIM:TRUTH?": SimulatedDigitizer._cmd_sim_truth,
}


def make_environment(
    temperature_c: float = 20.0, echo_probability: float = 0.0
) -> SonicEnvironment:
    """A :class:`SonicEnvironment` with the default timing noise (~0.1 mm)."""
    return SonicEnvironment(temperature_c=temperature_c, echo_probability=echo_probability)
