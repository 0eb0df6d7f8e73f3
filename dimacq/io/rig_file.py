"""The acquisition rig's channel map: ``config/rig.toml`` (schema_version 1).

What is cabled where, for :func:`dimacq.services.acquisition.rig.build_rig`, real or simulated alike (the
simulated lab is cabled as the rig file says, and its drivers read the same calibrated
sensitivities and calibration files as on a real rig):

.. code-block:: toml

    schema_version = 1

    [daq]
    sample_rate_hz = 2048.0
    samples_per_frame = 256
    serial_number = ""          # "" = the first DAQ found
    timeout_s = 2.0             # USB transfer timeout
    strike_timeout_s = 60.0     # how long the trigger waits for the operator's strike
    # daq = "nidaqmx": the cDAQ modules and the rig inputs on their ai0, ai1, ...
    # [[daq.modules]]
    # name = "cDAQ1Mod1"
    # model = "NI 9234"
    # inputs = [0, 1, 2, 3]

    [[hammers]]                 # one impact hammer per entry (usually one roving hammer)
    physical_channel = 0
    sensitivity_mv_per_n = 2.25
    range_v = 5.0
    iepe_current_ma = 4.0       # 0 = IEPE off
    inputs = []                 # setup inputs struck with it, e.g. ["101+X"]; [] = every input

    [[responses]]               # one entry per accelerometer axis of the setup
    node = 1101
    direction = "+X"            # or the UFF number 1
    physical_channel = 1
    sensitivity_mv_per_g = 100.0
    range_v = 10.0

    [[load_cells]]              # one entry per load cell of the setup
    node = 501
    node_id = 1                 # the amplifier's CAN node id
    calibration_file = "calibrations/lc-501.json"   # relative to this file
    channel = ""                # CAN channel if not the service's loadcell_channel
    # or / and its gauges on DAQ inputs (loadcell = "daq-channels"):
    # daq_channels = [25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36]
    # daq_signals = "gauges"    # or "outputs": six conditioned F/T voltages (6x6 matrix)
    # excitation_v = 10.0       # bridge excitation when the calibration is in mV/V
    # daq_range_v = 0.1

    [acquisition]               # optional defaults of an impact test (a request overrides them)
    record_samples = 4096

Files are refused item by item: the message names the item (``responses.3.physical_channel``) and
what to give instead.
"""

from __future__ import annotations

import logging
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from dimacq.errors import SetupError
from dimacq.io.documents import loads_toml
from dimacq.io.validation import refuse
from dimacq.model.channels import axis_name
from dimacq.model.impact import ImpactOverrides
from dimacq.model.setup import direction_label
from dimacq.model.types import OneLine

__all__ = [
    "ChainCalibrationEntry",
    "NiModuleEntry",
    "RigFile",
    "load_rig_file",
    "parse_direction",
    "parse_rig_text",
    "write_chain_calibration",
]

log = logging.getLogger(__name__)

#: The highest DAQ sample rate a rig file may give, Hz.
MAX_SAMPLE_RATE_HZ = 1e7
#: The names a load cell's calibration file may have.
CALIBRATION_SUFFIXES = (".json", ".xml")
#: The range of a transducer's sensitivity (mV/N, mV/g).
MIN_SENSITIVITY, MAX_SENSITIVITY = 1e-3, 1e5

_LABELS = {direction_label(d): d for d in (1, 2, 3, -1, -2, -3)}


def parse_direction(value: Any) -> int:
    """UFF direction ``±1..±3`` from an int or a label ``"+X"``, ``"-Z"``."""
    if isinstance(value, bool):
        raise ValueError("give a direction ±1..±3 or a label like '+X'")
    if isinstance(value, int):
        if value in (1, 2, 3, -1, -2, -3):
            return value
        raise ValueError(f"direction {value} is not ±1, ±2 or ±3")
    if isinstance(value, str):
        key = value.strip().upper()
        key = key if key[:1] in "+-" else "+" + key
        if key in _LABELS:
            return _LABELS[key]
    raise ValueError(f"direction {value!r}: give ±1..±3 or one of {', '.join(_LABELS)}")


class _Model(BaseModel):
    """Strict (no ``"1"`` or ``true`` as a number) and finite (no ``"inf"`` or ``1e999``)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class NiModuleEntry(_Model):
    """A C Series module of an NI cDAQ chassis (``daq = "nidaqmx"``): ``inputs[k]`` is the rig
    input (``physical_channel``) wired to its ``ai<k>``; the model is checked against the device
    and is what a dry run plans with."""

    name: str = Field(min_length=1, description="its NI-DAQmx device name, e.g. 'cDAQ1Mod1'")
    model: str = Field(min_length=1, description="its product type, e.g. 'NI 9234' or 'NI 9237'")
    inputs: list[int] = Field(
        default_factory=list,
        description="the rig inputs on its ai0, ai1, ... (each 0..255); [] = all its AIs, "
        "numbered on from the previous module's last",
    )

    @field_validator("inputs")
    @classmethod
    def _inputs(cls, v: list[int]) -> list[int]:
        if any(not 0 <= k <= 255 for k in v) or len(set(v)) != len(v):
            raise ValueError("give distinct rig inputs 0..255, one per AI from ai0 on")
        return v


class DaqSection(_Model):
    sample_rate_hz: float = Field(
        ge=1.0, le=MAX_SAMPLE_RATE_HZ, description="the sample rate in Hz (1..10 MHz), e.g. 2048.0"
    )
    samples_per_frame: int = Field(
        default=256, ge=1, le=65535, description="USB frame size in samples (1..65535)"
    )
    serial_number: OneLine = Field(
        default="", max_length=200, description="the DAQ's serial number, or ''"
    )
    units: list[Annotated[OneLine, Field(max_length=200)]] = Field(
        max_length=64,
        default_factory=list,
        description="daq = 'mcc-usb': the USB-1808X units' serial numbers in channel order "
        "(inputs 0..7 on the first, the clock master; 8..15 on the second; ...); daq = 'nidaqmx': "
        "the NI device names in channel order; [] = the one found",
    )
    modules: list[NiModuleEntry] = Field(
        default_factory=list,
        description="daq = 'nidaqmx': the cDAQ's C Series modules ([[daq.modules]]: name, model, "
        "inputs); [] = [daq] units (or the first device found)",
    )
    timeout_s: float = Field(
        default=2.0, ge=0.001, le=3600.0, description="a USB timeout in seconds, 0.001..3600"
    )
    strike_timeout_s: float = Field(
        default=60.0,
        ge=0.1,
        le=86400.0,
        description="seconds the trigger waits for a strike (0.1..86400)",
    )

    @model_validator(mode="after")
    def _one_module_list(self) -> DaqSection:
        if self.units and self.modules:
            raise ValueError(
                "give the NI modules either as units (device names) or as [[daq.modules]], not both"
            )
        return self


class _Analog(_Model):
    """An analogue input. Which ranges and IEPE currents exist is the DAQ's business: its
    backend refuses a value it does not have when the rig is built, naming this item."""

    physical_channel: int = Field(ge=0, le=255, description="the DAQ input number (0-based)")
    range_v: float = Field(
        default=10.0, ge=0.001, le=100.0, description="the input range ±V (0.001..100)"
    )
    iepe_current_ma: float = Field(
        default=4.0, ge=0, le=20.0, description="IEPE current in mA (0 = off, at most 20)"
    )
    coupling: Literal["AC", "DC"] = Field(default="AC", description="'AC' or 'DC'")


class ChainCalibrationEntry(_Model):
    """The chain calibration of a hammer (:mod:`dimacq.pipeline.chain_calibration`): measured on
    a weighed reference body with this hammer and the rig's accelerometers. The acquisition uses
    ``sensitivity_mv_per_n × factor``: every FRF (∝ the hammer's sensitivity) × γ."""

    factor: float = Field(
        ge=0.9, le=1.1, description="γ = measured / weighed mass of the reference body (0.9..1.1)"
    )
    u_rel: float = Field(ge=0, lt=0.5, description="relative standard uncertainty of γ")
    source: OneLine = Field(
        default="", max_length=500, description="where it was measured (reference body, data)"
    )
    date: OneLine = Field(default="", max_length=40, description="when (ISO date)")


class HammerEntry(_Analog):
    sensitivity_mv_per_n: float = Field(
        ge=MIN_SENSITIVITY,
        le=MAX_SENSITIVITY,
        description="the hammer's sensitivity in mV/N (0.001..100000)",
    )
    inputs: list[Annotated[OneLine, Field(max_length=200)]] = Field(
        default_factory=list,
        max_length=10_000,
        description="setup inputs struck with this hammer as 'node+dir' (e.g. '101+X'), [] = all",
    )
    chain_calibration: ChainCalibrationEntry | None = Field(
        default=None,
        description="chain calibration on a reference mass (dimacq solve --reference-mass "
        "--write-rig): the acquisition uses sensitivity_mv_per_n × factor",
    )

    @property
    def effective_sensitivity_mv_per_n(self) -> float:
        """The certificate's sensitivity times the chain factor (when calibrated), mV/N."""
        f = 1.0 if self.chain_calibration is None else self.chain_calibration.factor
        return self.sensitivity_mv_per_n * f


class ResponseEntry(_Analog):
    node: int = Field(ge=1, le=2**31 - 1, description="the setup response's node number")
    direction: int = Field(description="the response's direction, ±1..±3 or '+X'..'-Z'")
    sensitivity_mv_per_g: float = Field(
        ge=MIN_SENSITIVITY,
        le=MAX_SENSITIVITY,
        description="the accelerometer's mV/g (0.001..100000)",
    )

    @field_validator("direction", mode="before")
    @classmethod
    def _dir(cls, v: Any) -> int:
        return parse_direction(v)

    @property
    def key(self) -> str:
        return axis_name(self.node, self.direction)


class LoadCellEntry(_Model):
    """One load cell: its amplifier on CAN (``node_id``, ``channel``, bit timing) and/or its
    gauges or six conditioned F/T outputs on DAQ inputs (``daq_channels``: the
    ``loadcell = "daq-channels"`` backend, sampled with the accelerometers on one clock)."""

    node: int = Field(ge=1, le=2**31 - 1, description="the setup load cell's node number")
    node_id: int | None = Field(
        default=None,
        ge=1,
        le=127,
        description="the amplifier's CAN node id (1..127); the CAN backends need it",
    )
    calibration_file: OneLine = Field(
        min_length=1,
        max_length=1000,
        description="the cell's calibration file (.json or .xml, relative paths from rig.toml)",
    )
    channel: OneLine = Field(
        default="", max_length=200, description="a CAN channel, or '' for loadcell_channel"
    )
    # the cell's signals read as DAQ inputs (loadcell = "daq-channels")
    daq_channels: list[Annotated[int, Field(ge=0, le=255)]] = Field(
        default_factory=list,
        max_length=64,
        description="DAQ inputs (0-based) of the cell's gauges, or of its six conditioned "
        "outputs, in the calibration matrix's column order",
    )
    daq_signals: Literal["gauges", "outputs"] = Field(
        default="gauges",
        description="'gauges' (bridge outputs, the calibration's 6xN matrix) or 'outputs' (six "
        "conditioned F/T voltages, a 6x6 matrix)",
    )
    excitation_v: float | None = Field(
        default=None,
        gt=0,
        le=20,
        description="the bridges' excitation in V when the calibration's gauge_unit is mV/V",
    )
    daq_range_v: float = Field(
        default=10.0, ge=0.001, le=100.0, description="the inputs' range ±V (0.001..100)"
    )
    daq_coupling: Literal["AC", "DC"] = Field(
        default="DC", description="the inputs' coupling: 'DC' (bridges, static loads) or 'AC'"
    )
    # an ATI Net F/T (loadcell = "netft-can" / "netft-udp"): where it is and its counts per unit
    netft_base: int | None = Field(
        default=None,
        ge=0,
        le=0x7F9,
        description="the Net F/T's CAN base address as its DIP switches set it (0..0x7F9)",
    )
    netft_host: OneLine = Field(
        max_length=253,
        default="",
        description="the Net F/T's IP address for RDT over UDP ('netft-udp')",
    )
    netft_port: int = Field(default=49152, ge=1, le=65535, description="its RDT UDP port")
    netft_rdt_rate_hz: float = Field(
        default=7000.0,
        gt=0,
        le=7000.0,
        description="its RDT output rate in Hz as its settings page shows it (up to 7000)",
    )
    netft_ft_rate_hz: float = Field(
        default=7000.0,
        gt=0,
        le=1e6,
        description="its internal sample rate in Hz: what ft_sequence counts (7000 on a Net F/T)",
    )
    netft_band_hz: float | None = Field(
        default=None,
        gt=0,
        le=MAX_SAMPLE_RATE_HZ,
        description="the top of the band analysed, Hz: where the RDT alignment's phase is "
        "checked (default: 0.32 x the DAQ's rate, the automatic band's top)",
    )
    netft_max_phase_deg: float = Field(
        default=2.0,
        gt=0,
        le=180.0,
        description="the FRF phase error in degrees the RDT alignment may cost at netft_band_hz",
    )
    netft_latency_floor_s: float = Field(
        default=20e-6,
        ge=0,
        le=10.0,
        description="the network's least latency in s (in the RDT alignment's budget)",
    )
    netft_time_base: Literal["data", "host"] = Field(
        default="data",
        description="RDT alignment: 'data' (the host's clock coarse, the residual delay fitted "
        "from the hammer and cell FRFs per input, its uncertainty checked against "
        "netft_max_phase_deg) or 'host' (the host's clock alone)",
    )
    netft_fit_lo_hz: float = Field(
        default=50.0,
        gt=0,
        le=MAX_SAMPLE_RATE_HZ,
        description="the lowest line of the RDT delay fit, Hz (its highest: netft_band_hz)",
    )
    netft_counts_per_force: int | None = Field(
        default=None,
        gt=0,
        le=2**31 - 1,
        description="its counts per force unit (its calibration info)",
    )
    netft_counts_per_torque: int | None = Field(
        default=None,
        gt=0,
        le=2**31 - 1,
        description="its counts per torque unit (its calibration info)",
    )
    netft_force_unit: int = Field(
        default=2, ge=1, le=6, description="its force unit code (1 lbf, 2 N, 3 klbf, 4 kN, ...)"
    )
    netft_torque_unit: int = Field(
        default=3, ge=1, le=6, description="its torque unit code (1 lbf-in, ..., 3 N-m, ...)"
    )
    # CAN FD bit timing of this cell's bus (None: the loadcell_* setting of the same name)
    f_clock: int | None = Field(
        default=None, gt=0, le=10**9, description="the adapter's CAN clock in Hz, or leave it out"
    )
    bitrate: int | None = Field(
        default=None, gt=0, le=10**7, description="the nominal bit rate in bit/s, or leave it out"
    )
    sample_point: float | None = Field(
        default=None, gt=50.0, lt=100.0, description="the nominal sample point in % (50..100)"
    )
    data_bitrate: int | None = Field(
        default=None,
        gt=0,
        le=10**7,
        description="the data-phase bit rate in bit/s, or leave it out",
    )
    data_sample_point: float | None = Field(
        default=None, gt=50.0, lt=100.0, description="the data-phase sample point in % (50..100)"
    )

    @field_validator("calibration_file")
    @classmethod
    def _inside_the_rig_folder(cls, v: str) -> str:
        """The service reads *and replaces* this file (a calibration run installs the next
        version there): it must lie in the rig file's folder or below it."""
        p = PurePosixPath(v.replace("\\", "/"))
        if p.is_absolute() or PureWindowsPath(v).is_absolute() or v.startswith("~"):
            raise ValueError(
                f"{v!r} is an absolute path; give a path relative to the rig file, inside its "
                "folder (e.g. 'calibrations/lc-501.json')"
            )
        if ".." in p.parts:
            raise ValueError(
                f"{v!r} leaves the rig file's folder ('..'); keep the calibration files in the "
                "rig file's folder or below it (e.g. 'calibrations/lc-501.json')"
            )
        if p.suffix.lower() not in CALIBRATION_SUFFIXES:
            raise ValueError(
                f"{v!r} is not a calibration file name; give a .json or .xml file in the rig "
                "file's folder or below it (e.g. 'calibrations/lc-501.json')"
            )
        return v

    @model_validator(mode="after")
    def _signals(self) -> LoadCellEntry:
        if len(set(self.daq_channels)) != len(self.daq_channels):
            raise ValueError("daq_channels lists a DAQ input twice; give each signal its own")
        if any(not 0 <= c <= 255 for c in self.daq_channels):
            raise ValueError("daq_channels: give DAQ input numbers 0..255")
        if self.daq_signals == "outputs" and self.daq_channels and len(self.daq_channels) != 6:
            raise ValueError(
                f"daq_signals = 'outputs' with {len(self.daq_channels)} daq_channels; give the "
                "six conditioned outputs Fx Fy Fz Mx My Mz in that order"
            )
        return self

    def require_node_id(self, where: str) -> int:
        """The CAN node id, which a CAN backend (``where``) needs; :class:`SetupError` naming
        the cell."""
        if self.node_id is None:
            raise SetupError(
                f"load cell {self.node}: {where} needs its amplifier's CAN node id; give "
                "node_id in its [[load_cells]] entry of the rig file"
            )
        return self.node_id


class RigFile(_Model):
    """The channel map of a real rig (see the module docstring)."""

    schema_version: Literal[1] = Field(description="schema_version = 1")
    daq: DaqSection = Field(description="a [daq] table with sample_rate_hz")
    hammers: list[HammerEntry] = Field(min_length=1, description="at least one [[hammers]] entry")
    responses: list[ResponseEntry] = Field(
        default_factory=list, description="[[responses]] entries"
    )
    load_cells: list[LoadCellEntry] = Field(
        default_factory=list, description="[[load_cells]] entries"
    )
    acquisition: ImpactOverrides = Field(default_factory=ImpactOverrides)
    path: Path | None = Field(default=None, exclude=True, description="(set when read)")

    @model_validator(mode="after")
    def _unique(self) -> RigFile:
        seen: dict[int, str] = {}
        for i, h in enumerate(self.hammers):
            _claim(seen, h.physical_channel, f"hammers.{i}")
        keys: set[str] = set()
        for i, r in enumerate(self.responses):
            _claim(seen, r.physical_channel, f"responses.{i}")
            if r.key in keys:
                raise ValueError(f"responses.{i}: {r.key} is listed twice; keep one entry")
            keys.add(r.key)
        nodes: set[int] = set()
        ids: set[tuple[str, int]] = set()
        for i, lc in enumerate(self.load_cells):
            for ch in lc.daq_channels:
                _claim(seen, ch, f"load_cells.{i}.daq_channels")
            if lc.node in nodes:
                raise ValueError(f"load_cells.{i}: node {lc.node} is listed twice; keep one entry")
            nodes.add(lc.node)
            if lc.node_id is None:
                continue
            if (lc.channel, lc.node_id) in ids:
                raise ValueError(
                    f"load_cells.{i}: node_id {lc.node_id} is used twice on one CAN channel; "
                    "give each amplifier its own node id"
                )
            ids.add((lc.channel, lc.node_id))
        return self

    @property
    def name(self) -> str:
        """The rig file's name (never its folder: messages leave server paths out)."""
        return self.path.name if self.path is not None else "rig.toml"

    def calibration_path(self, entry: LoadCellEntry) -> Path:
        """The calibration file, relative to the rig file's folder (never outside it:
        :meth:`LoadCellEntry._inside_the_rig_folder`)."""
        p = Path(entry.calibration_file)
        if self.path is not None:
            p = self.path.parent / p
        return p


def _claim(seen: dict[int, str], channel: int, item: str) -> None:
    if channel in seen:
        raise ValueError(
            f"{item}: physical_channel {channel} is already used by {seen[channel]}; "
            "give every transducer its own DAQ input"
        )
    seen[channel] = item


def _refuse(source: str, err: ValidationError) -> SetupError:
    return refuse("rig file", source, err, RigFile, "see dimacq.io.rig_file")


def load_rig_file(path: str | Path) -> RigFile:
    """Read and check a rig file.

    Raises
    ------
    SetupError
        Missing or unreadable file, TOML syntax, or an item that fails its check (the message
        names the item and the fix).
    """
    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise SetupError(
            f"rig file {p.name}: cannot read it ({err.strerror}); set rig_file (DIMACQ_RIG_FILE) to the channel "
            "map of the real rig (see config/rig.toml)"
        ) from err
    return parse_rig_text(text, p)


def parse_rig_text(text: str, path: str | Path) -> RigFile:
    """Check a rig file's text as :func:`load_rig_file` reads it; ``path`` is where it lives
    (relative calibration paths are taken from its folder; nothing is read or written there).

    Raises
    ------
    SetupError
        TOML syntax, or an item that fails its check (the message names the item and the fix).
    """
    p = Path(path).expanduser()
    data = loads_toml(text, f"rig file {p}")  # within the documents' limits, named if not
    if isinstance(data, dict):
        data.pop("path", None)
    try:
        rig = RigFile.model_validate(data)
    except ValidationError as err:
        raise _refuse(p.name, err) from err
    rig = rig.model_copy(update={"path": p.resolve()})
    _check_calibration_files(rig)
    return rig


def _check_calibration_files(rig: RigFile) -> None:
    """Every calibration file that exists is a regular file inside the rig file's folder (a
    symbolic link out of it, a folder or a device would fail the acquisition later)."""
    assert rig.path is not None
    folder = rig.path.parent
    for i, lc in enumerate(rig.load_cells):
        target = rig.calibration_path(lc)
        item = f"load_cells.{i}.calibration_file"
        try:
            real = target.resolve()
            inside = real.is_relative_to(folder) and real != rig.path
            exists = target.exists()
            regular = target.is_file()
        except (OSError, ValueError) as err:
            raise SetupError(
                f"rig file {rig.path.name} refused: item '{item}' = {lc.calibration_file!r}: "
                f"cannot be read ({type(err).__name__}); fix: give a calibration file in the "
                "rig file's folder"
            ) from err
        if not inside or (exists and not regular):
            what = "leaves the rig file's folder" if not inside else "is not a regular file"
            raise SetupError(
                f"rig file {rig.path.name} refused: item '{item}' = {lc.calibration_file!r} "
                f"{what}; fix: give a .json or .xml calibration file in the rig file's folder "
                "or below it (e.g. 'calibrations/lc-501.json')"
            )


def write_chain_calibration(
    path: str | Path, factor: float, u_rel: float, *, source: str, date: str
) -> RigFile:
    """Record a chain calibration measured on the rig in its rig file (its one hammer).

    The factor was measured on FRFs the rig already scaled by its recorded factor ``γ₀`` (if
    any), so the hammer's new factor is ``γ₀ · factor``; ``u_rel`` is the new measurement's. The
    file is edited in place, line by line (its comments stay); the result is read back and
    checked before it replaces the old file.

    Raises
    ------
    SetupError
        A rig file with no or several hammers (which one was calibrated is ambiguous), or a
        combined factor outside 0.9..1.1.
    """
    import math
    import os

    p = Path(path)
    rf = load_rig_file(p)
    if len(rf.hammers) != 1:
        raise SetupError(
            f"rig file {p.name}: {len(rf.hammers)} [[hammers]]; a chain calibration is written "
            "for a rig with one hammer (calibrate each hammer on its own rig file)"
        )
    (h,) = rf.hammers
    old = 1.0 if h.chain_calibration is None else h.chain_calibration.factor
    total = old * factor
    if not (math.isfinite(total) and 0.9 <= total <= 1.1):
        raise SetupError(
            f"rig file {p.name}: chain factor {old:.6g} × {factor:.6g} = {total:.6g} is outside "
            "0.9..1.1; check the hammer's sensitivity in the rig file"
        )
    src = source.replace('"', "'")
    line = (
        f'chain_calibration = {{ factor = {total:.7f}, u_rel = {u_rel:.3g}, source = "{src}", '
        f'date = "{date}" }}'
    )
    lines = p.read_text(encoding="utf-8").splitlines()
    out: list[str] = []
    in_hammer = False
    written = False
    for ln in lines:
        stripped = ln.strip()
        if stripped.startswith("["):
            in_hammer = stripped == "[[hammers]]"
        if in_hammer and stripped.startswith("chain_calibration"):
            continue  # replaced below
        out.append(ln)
        if in_hammer and stripped.startswith("sensitivity_mv_per_n") and not written:
            out.append(line)
            written = True
    if not written:
        raise SetupError(f"rig file {p.name}: no sensitivity_mv_per_n line in [[hammers]]")
    import tempfile

    fd, name = tempfile.mkstemp(prefix=".rig-chain-", suffix=".toml", dir=p.parent)
    tmp = Path(name)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:  # a new file: never through a link
        fh.write("\n".join(out) + "\n")
    try:
        checked = parse_rig_text(tmp.read_text(encoding="utf-8"), p)
    except SetupError:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, p)
    return checked
