"""Service configuration: pydantic-settings with a schema version.

Sources, highest priority first: arguments given to :func:`load_settings` (the command line),
``DIMACQ_*`` environment variables, ``config/dimacq.toml`` (or the file named by
``DIMACQ_CONFIG``), the defaults below.

Devices: ``daq``, ``loadcell`` and ``digitizer`` name an entry of the device backend tables
(:mod:`dimacq.backends`) — ``daq = "dimacq-usb" | "simulated" | "package.module:factory"``,
``loadcell = "dimacq-can" | "simulated" | ...``, ``digitizer = "serial" | "simulated" | ...`` —
with the channel map of the rig in ``rig_file`` (see :mod:`dimacq.io.rig_file`). The simulated
lab is the default; real hardware is configuration only. Older names still work:
``daq_backend = "simulated"`` means ``daq = "simulated"``; ``daq_backend = "libusb"`` or a
factory (the pyusb backend of ``"dimacq-usb"``) without ``daq`` means ``daq = "dimacq-usb"``;
``loadcell`` defaults to ``"simulated"`` with the simulated DAQ and to ``"dimacq-can"`` otherwise;
``digitizer`` to ``"simulated"`` for a ``simdigitizer://`` URL and to ``"serial"`` otherwise.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import socket
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from dimacq.errors import SetupError

__all__ = ["Settings", "default_config_file", "load_settings", "scenario_rig_file"]

SCHEMA_VERSION: Literal[1] = 1

_NAME = re.compile(r"[a-z][a-z0-9-]*")
_FACTORY = re.compile(r"[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*:[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*")


def default_config_file() -> Path:
    """``$DIMACQ_CONFIG`` or the repository's ``config/dimacq.toml``."""
    env = os.environ.get("DIMACQ_CONFIG")
    return Path(env) if env else Path(__file__).resolve().parents[1] / "config" / "dimacq.toml"


def scenario_rig_file(scenario: str) -> str:
    """The rig a virtual-lab scenario's article is cabled on: ``config/rigs/<scenario>.toml``,
    else ``config/rigs/<first word>.toml`` (e.g. ``cube`` for ``cube-2``), else "" (``rig.toml``,
    the calibration mass). What ``dimacq demo`` and ``dimacq acquire`` give as ``rig_file``."""
    rigs = default_config_file().parent / "rigs"
    for name in (scenario, scenario.split("-")[0]):
        if (rigs / f"{name}.toml").exists():
            return str(rigs / f"{name}.toml")
    return ""


#: The least free space on the data folder's disk the service starts with (an acquisition
#: writes its averages there).
MIN_FREE_BYTES = 64 * 2**20


def _default_data_dir() -> Path:
    base = os.environ.get("XDG_DATA_HOME")
    return (Path(base) if base else Path.home() / ".local" / "share") / "dimacq"


class Settings(BaseSettings):
    """Configuration of the dimacq service (``config/dimacq.toml``, schema_version 1)."""

    model_config = SettingsConfigDict(env_prefix="DIMACQ_", extra="forbid", frozen=True)

    schema_version: Literal[1] = SCHEMA_VERSION
    data_dir: Path = Field(default_factory=_default_data_dir)
    database_url: str = ""
    #: This test stand's name on a shared database (default: the host name); one service each.
    stand: str = Field(default="", max_length=100, pattern=r"^[A-Za-z0-9._-]*$")
    #: How long a write waits for an unreachable database (retry with backoff), in seconds.
    database_retry_s: float = Field(default=600.0, ge=0.0)
    host: str = "127.0.0.1"
    port: int = Field(default=8765, ge=0, le=65535)
    token: str = ""
    cors_origins: list[str] = Field(default_factory=list)
    daq: str = "simulated"
    loadcell: str = "simulated"
    digitizer: str = "simulated"
    #: further names (without port) the service may be called by, besides the loopback names and
    #: the bound host (the Host header is checked against them: DNS rebinding)
    allowed_hosts: list[str] = Field(default_factory=list)
    #: largest JSON request body, bytes (413 above it)
    max_body_bytes: int = Field(default=4 * 1024 * 1024, ge=1024, le=2**31 - 1)
    #: largest uploaded file (setup or UFF import), bytes (413 above it)
    max_upload_bytes: int = Field(default=256 * 1024 * 1024, ge=1024, le=2**40)
    digitizer_url: str = "simdigitizer://lab?seed=0"
    #: the digitizer's serial line (``digitizer = "serial"``): baud rate (the SD-3 runs at
    #: 115200 8N1; a USB-serial adapter takes what the device is set to), the longest wait for
    #: one reply line, s, and the port's read poll, s
    digitizer_baudrate: int = Field(default=115200, ge=300, le=4_000_000)
    digitizer_timeout_s: float = Field(default=2.0, gt=0.0, le=60.0)
    digitizer_poll_s: float = Field(default=0.02, gt=0.0, le=1.0)
    #: python-can interface of the real CAN load cell backends ("pcan", "socketcan", ...; ""
    #: = python-can's own configuration: ~/.canrc, CAN_INTERFACE / CAN_CHANNEL / CAN_BITRATE).
    #: "virtual" (python-can's in-process bus) is refused with a real backend unless
    #: ``loadcell_virtual_ok`` (tests that put a simulator on it).
    loadcell_interface: str = ""
    loadcell_channel: str = "dimacq-lab"
    loadcell_virtual_ok: bool = False
    #: further keyword arguments of ``can.Bus`` (interface-specific: PCAN ``device_id``, Kvaser
    #: ``accept_virtual``, socketcan ``receive_own_messages`` ...), passed through as given
    loadcell_can_options: dict[str, str | int | float | bool] = Field(default_factory=dict)
    #: explicit classic-CAN bit timing (``can.BitTiming``: ``f_clock``, ``brp``, ``tseg1``,
    #: ``tseg2``, ``sjw``, optional ``nof_samples``) instead of a bit rate; {} = the bit rate
    loadcell_can_bit_timing: dict[str, int] = Field(default_factory=dict)
    #: Rate mismatch of the DAQ's sample clock (SYNC) and a load cell amplifier's oscillator
    #: taken for crystal tolerance, ppm: estimated and corrected; beyond it a ``drift`` event.
    loadcell_clock_tolerance_ppm: float = Field(default=100.0, ge=0.0, lt=1e5)
    #: CAN FD bit timing of the load cell bus (python-can ``BitTimingFd.from_sample_point``):
    #: the adapter's CAN clock (Hz), nominal (arbitration) and data bit rates (bit/s) and
    #: sample points (%); every amplifier on the bus must use the same.
    loadcell_f_clock: int = Field(default=80_000_000, gt=0)
    loadcell_bitrate: int = Field(default=1_000_000, gt=0)
    loadcell_sample_point: float = Field(default=80.0, gt=50.0, lt=100.0)
    loadcell_data_bitrate: int = Field(default=5_000_000, gt=0)
    loadcell_data_sample_point: float = Field(default=80.0, gt=50.0, lt=100.0)
    daq_backend: str = "libusb"
    daq_vendor_id: int = Field(default=0x1209, ge=0, le=0xFFFF)
    daq_product_id: int = Field(default=0xDA64, ge=0, le=0xFFFF)
    #: daq = "mcc-usb": MCC's FPGA bitstream usb-1808.rbf, loaded into a USB-1808X after power-up
    daq_fpga_file: str = ""
    #: daq = "nidaqmx": the terminal whose digital edge starts the task ("/cDAQ1/PFI0"), "" = none
    daq_ni_start_trigger: str = ""
    #: daq = "nidaqmx": the terminal the task's sample clock is exported to ("/cDAQ1/PFI1") for
    #: devices that sample on it, "" = not exported
    daq_ni_sample_clock_out: str = ""
    rig_file: str = ""
    scenario: str = "calibration-mass-bungee"
    #: The simulated devices' imperfections over their defaults (dimacq.simulators.imperfections:
    #: free-running DAQ clock with a FIFO, stale frames, ±50 ppm crystals, CAN frame loss,
    #: serial noise and port loss, USB stalls; re-enumeration and bus-off at rate 0);
    #: ``{enabled = false}``: none.
    simulation_imperfections: dict[str, float | bool] = Field(default_factory=dict)
    # Registration of the digitizer array (see dimacq.pipeline.digitizing.registration):
    # 1σ per coordinate of the reference nodes' known GCS coordinates, and the largest accepted
    # residual of one reference node (None: 5·sqrt(σ_point² + σ_reference²) with σ_point the
    # array's [accuracy] point_m, 2.9 mm for the shipped array).
    reference_node_accuracy_m: float = Field(default=5.0e-4, ge=0, le=0.1)
    registration_limit_m: float | None = Field(default=None, gt=0, le=1.0)
    # Impact tests: fewest accepted averages per input (fewer: the input is struck again within
    # the attempt budget, then reported incomplete); coherence needs at least 2.
    min_averages: int = Field(default=3, ge=1, le=100)
    # CANopen load cell amplifiers (loadcell = "canopen" | "canopen-simulated",
    # dimacq.backends.canopen_loadcell): the EDS file of the amplifiers (relative paths from the
    # config file's folder), the classic CAN bit rate (bit/s), the node ids expected on the bus
    # (empty: whatever the rig file's node_id say; else each rig file node_id must be one of
    # them), and how many producer heartbeat periods may pass before a node counts as lost.
    loadcell_canopen_eds: str = "canopen/loadcell.eds"
    loadcell_canopen_bitrate: int = Field(default=1_000_000, gt=0, le=1_000_000)
    loadcell_canopen_node_ids: list[int] = Field(default_factory=list)
    loadcell_canopen_heartbeat_ms: int = Field(default=200, ge=10, le=10_000)
    loadcell_canopen_heartbeat_factor: float = Field(default=5.0, ge=1.5, le=100.0)
    # Generic CiA 404 amplifiers (loadcell = "cia404" | "cia404-simulated",
    # dimacq.backends.cia404): their EDS (relative paths from the config file's folder), who
    # sends the SYNC ("daq": a producer on the DAQ's sample clock; "host": this PC's timer,
    # bench readings only), which process value to map ("auto": 0x6130 REAL32 when the EDS has
    # it, else 0x7130 INTEGER16), the largest summed bus load accepted, and the number of inputs
    # of a cell without a calibration file (else its matrix's columns).
    loadcell_cia404_eds: str = "canopen/cia404-generic.eds"
    loadcell_cia404_sync: Literal["daq", "host"] = "daq"
    loadcell_cia404_process_value: Literal["auto", "0x6130", "0x7130"] = "auto"
    loadcell_cia404_max_bus_load: float = Field(default=0.70, gt=0.0, le=1.0)
    loadcell_cia404_channels: int = Field(default=12, ge=1, le=64)
    # FRF phase (deg) the CiA 404 node's held values may cost at 0.32 x the DAQ's rate
    loadcell_cia404_max_phase_deg: float = Field(default=2.0, gt=0.0)
    # ATI Net F/T on CAN (loadcell = "netft-can" | "netft-can-simulated",
    # dimacq.backends.netft_can): the classic CAN bit rate its DIP switches set, bit/s.
    loadcell_netft_bitrate: int = Field(default=500_000, gt=0, le=1_000_000)

    @model_validator(mode="before")
    @classmethod
    def _aliases(cls, data: Any) -> Any:
        """The older settings: ``daq_backend = "simulated"`` and the defaults that follow."""
        if not isinstance(data, dict):
            return data
        d = dict(data)
        backend = str(d.get("daq_backend", "")).strip()
        if backend == "simulated":
            d.pop("daq_backend")
            d.setdefault("daq", "simulated")
        elif backend and "daq" not in d:
            d["daq"] = "dimacq-usb"
        if "loadcell" not in d:
            # a simulated DAQ ("simulated", "mcc-usb-simulated") comes with the simulated lab
            daq = str(d.get("daq", "simulated")).strip()
            d["loadcell"] = (
                "simulated" if daq == "simulated" or daq.endswith("-simulated") else "dimacq-can"
            )
        if "digitizer" not in d:
            url = str(d.get("digitizer_url", "simdigitizer://"))
            d["digitizer"] = "simulated" if url.startswith("simdigitizer://") else "serial"
        return d

    @field_validator("daq", "loadcell", "digitizer")
    @classmethod
    def _kind(cls, v: str) -> str:
        v = v.strip()
        if _NAME.fullmatch(v) or _FACTORY.fullmatch(v):
            return v
        raise ValueError(
            "give a backend name of dimacq.backends.BACKENDS (e.g. 'simulated') or the import "
            "path 'package.module:factory' of a function opening the device"
        )

    @field_validator("daq_backend")
    @classmethod
    def _backend(cls, v: str) -> str:
        v = v.strip()
        if v == "libusb" or _FACTORY.fullmatch(v):
            return v
        raise ValueError(
            "give 'libusb' or the import path 'package.module:factory' of a function returning "
            "a pyusb backend (the simulated DAQ is daq = 'simulated')"
        )

    @field_validator("allowed_hosts")
    @classmethod
    def _hosts(cls, v: list[str]) -> list[str]:
        out = [h.strip().strip("[]").lower() for h in v]
        if any(not h or "/" in h or " " in h for h in out):
            raise ValueError("give host names or addresses without scheme, port or path")
        return out

    @field_validator("data_dir", mode="before")
    @classmethod
    def _empty_data_dir(cls, v: Any) -> Any:
        return _default_data_dir() if v in ("", None) else Path(str(v)).expanduser()

    @property
    def db_url(self) -> str:
        """The SQLAlchemy URL (default: SQLite in the data directory)."""
        return self.database_url or f"sqlite:///{self.data_dir / 'dimacq.sqlite'}"

    @property
    def stand_name(self) -> str:
        """``stand``, or the host name."""
        return self.stand or socket.gethostname()[:100]

    @property
    def rig_path(self) -> Path:
        """The rig's channel map: ``rig_file``, or ``rig.toml`` beside the config file
        (relative paths are taken from the config file's folder)."""
        base = default_config_file().parent
        if not self.rig_file:
            return base / "rig.toml"
        p = Path(self.rig_file).expanduser()
        return p if p.is_absolute() else base / p

    @property
    def loadcell_canopen_eds_path(self) -> Path:
        """The CANopen amplifiers' EDS file (``loadcell_canopen_eds``; relative paths from the
        config file's folder)."""
        p = Path(self.loadcell_canopen_eds).expanduser()
        return p if p.is_absolute() else default_config_file().parent / p

    @property
    def loadcell_cia404_eds_path(self) -> Path:
        """The CiA 404 amplifiers' EDS (``loadcell_cia404_eds``, relative to the config file)."""
        p = Path(self.loadcell_cia404_eds).expanduser()
        return p if p.is_absolute() else default_config_file().parent / p

    def check_data_dir(self) -> Path:
        """``data_dir``, created (mode 0700) when missing, checked to be a writable folder with
        room left (:data:`MIN_FREE_BYTES`); returns it.

        Raises
        ------
        SetupError
            One line naming the setting and the fix: ``data_dir`` is a file, cannot be created,
            is not writable, or its disk is full.
        """
        d = self.data_dir
        fix = "set data_dir (DIMACQ_DATA_DIR) to a writable folder"
        if d.exists() and not d.is_dir():
            raise SetupError(f"data_dir {d} is not a folder; {fix}")
        try:
            d.mkdir(mode=0o700, parents=True, exist_ok=True)
        except OSError as err:
            raise SetupError(f"data_dir {d} cannot be created ({err.strerror}); {fix}") from None
        if not os.access(d, os.R_OK | os.W_OK | os.X_OK):
            raise SetupError(f"data_dir {d} is not readable and writable by this user; {fix}")
        try:
            free = shutil.disk_usage(d).free
        except OSError as err:
            raise SetupError(f"data_dir {d} cannot be examined ({err.strerror}); {fix}") from None
        if free < MIN_FREE_BYTES:
            raise SetupError(
                f"data_dir {d}: {free // 2**20} MiB free, less than {MIN_FREE_BYTES // 2**20} MiB "
                f"(MIN_FREE_BYTES); free disk space or {fix} on another disk"
            )
        return d

    def resolved_token(self) -> str:
        """The access token: configured, or generated once and kept in ``<data_dir>/token``
        (mode 0600: readable by the service's user only)."""
        if self.token:
            return self.token
        self.check_data_dir()
        path = self.data_dir / "token"
        if path.exists():
            if path.stat().st_mode & 0o077:  # written by an older dimacq or by hand
                path.chmod(0o600)
            text = path.read_text(encoding="utf-8").strip()
            if text:
                return text
        self.data_dir.mkdir(parents=True, exist_ok=True)
        tok = secrets.token_urlsafe(24)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(tok + "\n")
        return tok

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        path = default_config_file()
        sources: list[PydanticBaseSettingsSource] = [init_settings, env_settings]
        if path.exists():
            sources.append(TomlConfigSettingsSource(settings_cls, toml_file=path))
        return tuple(sources)


def load_settings(**overrides: Any) -> Settings:
    """Settings from the file, the environment and ``overrides`` (None values are ignored).

    Raises
    ------
    SetupError
        A value is invalid; the message names the key and where it can be set.
    """
    given = {k: v for k, v in overrides.items() if v is not None}
    try:
        return Settings(**given)
    except ValidationError as err:
        first = err.errors()[0]
        key = ".".join(str(p) for p in first["loc"])
        raise SetupError(
            f"configuration item {key!r}: {first['msg']}; fix it in {default_config_file()}, "
            f"in DIMACQ_{key.upper()} or on the command line"
        ) from err
    except ValueError as err:  # e.g. malformed TOML
        raise SetupError(f"configuration {default_config_file()}: {err}") from err
