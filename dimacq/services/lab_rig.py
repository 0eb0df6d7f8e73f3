"""The acquisition rig behind :meth:`dimacq.services.lab.Lab.start_acquisition`.

:class:`Rig` bundles a configured DAQ task, the load cell amplifiers, the channel names of each
input's hammer and of each response, and (in simulation) the virtual operator who strikes.
:func:`build_rig` makes one from the settings: the simulated DAQ (pyusb backend) and load cell
(python-can ``virtual``) fed by the configured virtual-lab scenario, or real devices.
:func:`run_impact_test` runs an :class:`~dimacq.services.acquisition.ImpactSession` on it and
hands every completed average to a callback *as soon as it is decided*, so the caller can make it
durable before the next strike.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dimacq.config import Settings
from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup, direction_label

if TYPE_CHECKING:
    from dimacq.drivers.daq.driver import DaqDevice
    from dimacq.drivers.loadcell.driver import LoadCellAmplifier
    from dimacq.io.rig_file import LoadCellEntry, RigFile
    from dimacq.services.acquisition import AverageCallback

__all__ = [
    "Rig",
    "build_real_rig",
    "build_rig",
    "daq_backend",
    "input_key",
    "open_daq",
    "open_loadcell",
    "run_impact_test",
]

log = logging.getLogger(__name__)

ProgressCallback = Callable[[float, str], None]


@dataclass
class Rig:
    """Devices ready for an impact test.

    Attributes
    ----------
    daq : Daq task (channels and timing configured, not started)
    input_channels : DAQ channel name of the hammer force, per setup excitation (in order)
    response_channels : DAQ channel name per setup response (in order)
    loadcells : amplifiers in the order of ``setup.load_cells``
    operator : callable (input_index, daq_sample), optional
        Simulation: strikes the virtual lab. None: a person strikes; :func:`run_impact_test`
        asks through the progress callback ("strike input N: <node+dir> ...").
    closers : called in reverse order by :meth:`close`
    defaults : impact settings used where the request leaves a value out (None)
    fixed : impact settings the rig imposes (e.g. how far ahead the simulated lab can be struck)
    """

    daq: Any
    input_channels: list[str]
    response_channels: list[str]
    loadcells: list[Any] = field(default_factory=list)
    operator: Callable[[int, int], None] | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)
    defaults: dict[str, Any] = field(default_factory=dict)
    fixed: dict[str, Any] = field(default_factory=dict)

    def close(self) -> None:
        while self.closers:
            fn = self.closers.pop()
            try:
                fn()
            except Exception:  # closing must go on for the others
                log.exception("closing part of the acquisition rig failed")


def build_rig(settings: Settings, setup: TestSetup, cfg: Mapping[str, Any]) -> Rig:
    """The rig for ``setup``.

    - ``daq_backend = "simulated"``: the configured virtual-lab scenario behind the simulated USB
      DAQ and CAN FD load cells (:class:`dimacq.services.simulated_lab.SimulatedRig`, real
      drivers). The service's setup (e.g. built from digitized geometry) is matched to the
      scenario's article channel by channel (node and direction); the virtual operator strikes the
      article's input that the session asks for.
    - otherwise real devices (:func:`build_real_rig`): the DAQ on the configured pyusb backend,
      the load cell amplifiers on ``can.Bus(interface=loadcell_interface, ...)``, the channel
      map from ``rig_file``; the operator strikes by hand when asked ("strike input N").
    """
    if not settings.simulated:
        return build_real_rig(settings, setup, cfg)
    from dimacq.services.simulated_lab import SimulatedRig
    from dimacq.simulators.lab.impact import virtual_lab
    from dimacq.simulators.lab.scenarios import build_scenario

    seed = cfg.get("seed")
    built = build_scenario(settings.scenario, None if seed is None else int(seed))
    lab = virtual_lab(built)
    true = lab.model.setup
    resp = {(c.node, c.direction): i for i, c in enumerate(true.responses)}
    inp = {(e.node, e.direction): i for i, e in enumerate(true.excitations)}
    cells = {lc.node: i for i, lc in enumerate(true.load_cells)}
    missing = [c.name for c in setup.responses if (c.node, c.direction) not in resp]
    missing += [e.name for e in setup.excitations if (e.node, e.direction) not in inp]
    missing += [lc.name for lc in setup.load_cells if lc.node not in cells]
    if missing:
        raise SetupError(
            f"setup channels {missing} are not instrumented in scenario {settings.scenario!r}; "
            "use the scenario's node numbers (see dimacq simulate --list)"
        )
    rig = SimulatedRig(lab)
    in_index = [inp[(e.node, e.direction)] for e in setup.excitations]

    def operator(j: int, daq_sample: int) -> None:
        rig.strike(in_index[j], daq_sample)

    acq = built.spec.acquisition
    return Rig(
        daq=rig.task,
        input_channels=["hammer"] * len(setup.excitations),
        response_channels=[
            rig.response_channels[resp[(c.node, c.direction)]] for c in setup.responses
        ],
        loadcells=[rig.loadcells[cells[lc.node]] for lc in setup.load_cells],
        operator=operator,
        closers=[rig.close],
        defaults={
            "record_samples": acq.record_samples,
            "pretrigger_samples": acq.pretrigger_samples,
            "averages_per_input": acq.averages,
            "exponential_tau_s": acq.exponential_tau_s,
            "force_window_samples": 64,
        },
        fixed={"hit_delay_samples": lab.block_samples, "block_samples": 512},
    )


# ---------------------------------------------------------------------------------------------
# Real devices: the same drivers, transports chosen by configuration
# ---------------------------------------------------------------------------------------------
def input_key(node: int, direction: int) -> str:
    """``"101+X"``: how the rig file names a setup input or response."""
    return f"{node}{direction_label(direction)}"


def daq_backend(settings: Settings) -> Any:
    """The pyusb backend ``daq_backend`` names: None for ``"libusb"`` (pyusb's default: libusb1,
    libusb0 or openusb, whichever is installed), or what ``"package.module:factory"`` returns.

    Raises
    ------
    SetupError
        ``daq_backend`` is ``"simulated"`` (no backend: the virtual lab builds its own), or the
        factory cannot be imported or fails.
    """
    name = settings.daq_backend
    if name == "simulated":
        raise SetupError(
            "daq_backend = 'simulated' has no pyusb backend of its own; the simulated lab builds "
            "its rig itself"
        )
    if name == "libusb":
        return None
    module_name, _, attr = name.partition(":")
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as err:
        raise SetupError(
            f"daq_backend = {name!r}: cannot import {attr!r} from module {module_name!r} ({err}); "
            "give 'libusb', 'simulated' or the import path 'package.module:factory' of a "
            "function returning a pyusb backend"
        ) from err
    if not callable(obj):
        raise SetupError(f"daq_backend = {name!r}: {attr!r} is not callable; give a factory")
    backend = obj()
    if backend is None:
        raise SetupError(
            f"daq_backend = {name!r}: the factory returned None; it must return a pyusb backend "
            "object (usb.backend.IBackend)"
        )
    return backend


def open_daq(settings: Settings, rig_file: RigFile) -> DaqDevice:
    """Find and open the DAQ: USB ``daq_vendor_id:daq_product_id`` on :func:`daq_backend`, the
    one with ``[daq] serial_number`` of the rig file if given.

    Raises
    ------
    DeviceNotFoundError
        No USB backend library (``libusb``) or no such device; the message names the settings.
    """
    import usb.core
    import usb.util

    from dimacq.drivers.daq.driver import DaqDevice

    backend = daq_backend(settings)
    vid, pid = settings.daq_vendor_id, settings.daq_product_id
    where = (
        f"daq_backend = {settings.daq_backend!r}, USB {vid:04x}:{pid:04x} "
        "(daq_vendor_id/daq_product_id)"
    )
    try:
        devices = list(
            usb.core.find(find_all=True, idVendor=vid, idProduct=pid, backend=backend) or []
        )
    except usb.core.NoBackendError as err:
        raise DeviceNotFoundError(
            f"{where}: pyusb finds no USB library on this machine ({err}); install libusb-1.0 "
            "(e.g. apt install libusb-1.0-0) or set daq_backend (DIMACQ_DAQ_BACKEND) to "
            "'simulated' or to a backend factory"
        ) from err
    timeout = rig_file.daq.timeout_s
    serial = rig_file.daq.serial_number
    for dev in devices:
        daq = DaqDevice(dev, timeout_s=timeout)
        if not serial:
            return daq
        try:
            if daq.identify().serial_number == serial:
                return daq
        except BaseException:
            daq.close()
            raise
        daq.close()
    wanted = (
        f" with serial number {serial!r} ([daq] serial_number of {rig_file.path})" if serial else ""
    )
    seen = f" ({len(devices)} other DAQ found)" if devices else ""
    raise DeviceNotFoundError(
        f"{where}: no DAQ{wanted} found{seen}; check the cable, the power and the USB "
        "permissions (udev rule), correct daq_vendor_id/daq_product_id, or set daq_backend "
        "(DIMACQ_DAQ_BACKEND) = 'simulated'"
    )


def _loadcell_ids(node_id: int) -> list[dict[str, Any]]:
    from dimacq.drivers.loadcell import protocol as lp

    ids = (lp.response_id(node_id), lp.data_id(node_id), lp.heartbeat_id(node_id))
    return [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids]


def open_loadcell(
    settings: Settings, rig_file: RigFile, entry: LoadCellEntry, *, timeout_s: float = 2.0
) -> tuple[LoadCellAmplifier, Callable[[], None]]:
    """Open the amplifier of ``entry`` on its own python-can bus handle
    (``interface=loadcell_interface``, ``channel`` = the entry's or ``loadcell_channel``, CAN FD,
    filtered to the node's identifiers), with the matrix of its calibration file; its serial
    number must match the file's. Returns the driver and the bus's closer.

    Raises
    ------
    DeviceNotFoundError
        The bus cannot be opened, or the amplifier does not answer.
    SetupError
        The calibration file is unreadable or belongs to another cell.
    """
    import can

    from dimacq.drivers.loadcell.driver import LoadCellAmplifier
    from dimacq.errors import DataError, DeviceTimeoutError
    from dimacq.io.loadcell_calibration import read_calibration

    cal_path = rig_file.calibration_path(entry)
    try:
        cal = read_calibration(cal_path)
    except (OSError, DataError) as err:
        raise SetupError(
            f"load cell {entry.node} (calibration_file of {rig_file.path}): {err}; give the "
            "cell's calibration file (dimacq loadcell calibrate writes one)"
        ) from err
    channel = entry.channel or settings.loadcell_channel
    where = (
        f"loadcell_interface = {settings.loadcell_interface!r}, channel {channel!r} "
        "(loadcell_channel)"
    )
    try:
        bus = can.Bus(
            interface=settings.loadcell_interface,
            channel=channel,
            fd=True,
            can_filters=_loadcell_ids(entry.node_id),
        )
    except (can.CanError, OSError, ImportError, ValueError) as err:
        raise DeviceNotFoundError(
            f"{where}: cannot open the CAN bus ({err}); check the adapter and the driver, or set "
            "loadcell_interface/loadcell_channel (DIMACQ_LOADCELL_INTERFACE/_CHANNEL)"
        ) from err
    try:
        amp = LoadCellAmplifier(
            bus, node_id=entry.node_id, timeout_s=timeout_s, calibration_matrix=cal.matrix
        )
        try:
            ident = amp.identify()
        except DeviceTimeoutError as err:
            raise DeviceNotFoundError(
                f"{where}: load cell amplifier node_id {entry.node_id} (load cell {entry.node}) "
                f"does not answer ({err}); check its power, the bit rate and node_id in "
                f"{rig_file.path}"
            ) from err
        if str(ident.serial_number) != str(cal.serial_number):
            raise SetupError(
                f"load cell {entry.node}: amplifier node_id {entry.node_id} reports serial number "
                f"{ident.serial_number} but {cal_path} calibrates {cal.serial_number}; give this "
                "cell's own calibration file or correct node_id"
            )
    except BaseException:
        bus.shutdown()
        raise
    return amp, bus.shutdown


def build_real_rig(settings: Settings, setup: TestSetup, cfg: Mapping[str, Any]) -> Rig:
    """Real devices with the same drivers as the simulated lab, chosen by configuration.

    The DAQ (:func:`open_daq`) gets one task: per hammer of the rig file a force channel (mV/N),
    per setup response the accelerometer channel the rig file assigns to its node and direction
    (mV/g), with their ranges, IEPE currents and couplings. Each setup load cell is the
    amplifier the rig file names (:func:`open_loadcell`). Nobody strikes automatically: the
    session asks the operator ("strike input N") and the trigger waits up to
    ``[daq] strike_timeout_s``.
    """
    from dimacq.drivers.daq.driver import DaqTask
    from dimacq.io.rig_file import load_rig_file

    path = settings.rig_path
    rf = load_rig_file(path)
    where = f"rig file {rf.path}"
    by_key = {r.key: r for r in rf.responses}
    missing = [
        input_key(c.node, c.direction)
        for c in setup.responses
        if input_key(c.node, c.direction) not in by_key
    ]
    if missing:
        raise SetupError(
            f"setup responses {missing} have no [[responses]] entry in {where}; add their node, "
            "direction, physical_channel and sensitivity_mv_per_g"
        )
    claimed: dict[str, int] = {}
    catch_all = [i for i, h in enumerate(rf.hammers) if not h.inputs]
    if len(catch_all) > 1:
        raise SetupError(
            f"{where}: hammers {catch_all} all have inputs = []; list the inputs of all but one"
        )
    for i, h in enumerate(rf.hammers):
        for k in h.inputs:
            claimed[k.replace(" ", "").upper()] = i
    hammer_of: list[int] = []
    for e in setup.excitations:
        k = input_key(e.node, e.direction).upper()
        if k in claimed:
            hammer_of.append(claimed[k])
        elif catch_all:
            hammer_of.append(catch_all[0])
        else:
            raise SetupError(
                f"setup input {input_key(e.node, e.direction)} is struck by no hammer in {where}; "
                "add it to a hammer's inputs or give one hammer inputs = []"
            )
    cells = {lc.node: lc for lc in rf.load_cells}
    lc_missing = [lc.node for lc in setup.load_cells if lc.node not in cells]
    if lc_missing:
        raise SetupError(
            f"setup load cells {lc_missing} have no [[load_cells]] entry in {where}; add node, "
            "node_id and calibration_file"
        )

    closers: list[Callable[[], None]] = []
    rig_ok = False
    try:
        device = open_daq(settings, rf)
        closers.append(device.close)
        task = DaqTask(device, "impact")
        hammer_names = [f"hammer ch{h.physical_channel}" for h in rf.hammers]
        for h, name in zip(rf.hammers, hammer_names, strict=True):
            task.add_force_channel(
                h.physical_channel,
                name,
                h.sensitivity_mv_per_n,
                range_v=h.range_v,
                iepe_current_ma=h.iepe_current_ma,
                coupling=h.coupling,
            )
        response_names = []
        for c in setup.responses:
            r = by_key[input_key(c.node, c.direction)]
            task.add_accel_channel(
                r.physical_channel,
                r.key,
                r.sensitivity_mv_per_g,
                range_v=r.range_v,
                iepe_current_ma=r.iepe_current_ma,
                coupling=r.coupling,
            )
            response_names.append(r.key)
        task.configure_timing(rf.daq.sample_rate_hz, rf.daq.samples_per_frame)
        loadcells = []
        for lc in setup.load_cells:
            amp, close_bus = open_loadcell(settings, rf, cells[lc.node])
            closers.append(close_bus)
            loadcells.append(amp)
        rig_ok = True
    finally:
        if not rig_ok:
            for fn in reversed(closers):
                try:
                    fn()
                except Exception:  # keep the original error
                    log.exception("closing part of a half-built rig failed")
    fs = rf.daq.sample_rate_hz
    log.info(
        "real rig: %d hammer(s), %d responses, %d load cell(s) at %g Hz (%s)",
        len(rf.hammers),
        len(response_names),
        len(loadcells),
        fs,
        rf.path,
    )
    return Rig(
        daq=task,
        input_channels=[hammer_names[i] for i in hammer_of],
        response_channels=response_names,
        loadcells=loadcells,
        operator=None,
        closers=closers,
        defaults=rf.acquisition.given(),
        fixed={"trigger_timeout_samples": max(1, round(rf.daq.strike_timeout_s * fs))},
    )


def run_impact_test(
    rig: Rig,
    setup: TestSetup,
    cfg: Mapping[str, Any],
    *,
    on_average: AverageCallback,
    on_progress: ProgressCallback,
) -> FrfData:
    """Run the impact test; return FRFs in the setup's channel order (SI units)."""
    from dimacq.services.acquisition import ImpactSession, ImpactSettings, Progress

    if len(rig.input_channels) != len(setup.excitations):
        raise SetupError(
            f"rig has {len(rig.input_channels)} hammer channels for {len(setup.excitations)} inputs"
        )
    if len(rig.response_channels) != len(setup.responses):
        raise SetupError(
            f"rig has {len(rig.response_channels)} response channels for {len(setup.responses)} responses"
        )

    def value(key: str, fallback: Any) -> Any:
        v = cfg.get(key)
        return rig.defaults.get(key, fallback) if v is None else v

    settings = ImpactSettings(
        record_samples=int(value("record_samples", 2048)),
        pretrigger_samples=int(value("pretrigger_samples", 32)),
        trigger_level=float(value("trigger_level_n", 5.0)),
        averages_per_input=int(value("averages_per_input", 5)),
        force_window_samples=value("force_window_samples", None),
        exponential_tau_s=value("exponential_tau_s", None),
        estimator=value("estimator", "H1"),
        **rig.fixed,
    )
    n_in = len(setup.excitations)
    wanted = settings.averages_per_input

    fraction = [0.0]
    accepted = [0] * n_in

    def progress(p: Progress) -> None:
        done = p.input_index * wanted + p.accepted
        fraction[0] = done / (n_in * wanted)
        accepted[p.input_index] = p.accepted
        on_progress(fraction[0], p.message)

    operator = rig.operator
    if operator is None:
        asked = [0]

        def ask(j: int, _daq_sample: int) -> None:
            e = setup.excitations[j]
            asked[0] += 1
            on_progress(
                fraction[0],
                f"strike input {j + 1}: {input_key(e.node, e.direction)} "
                f"(average {accepted[j] + 1} of {wanted}, input {j + 1} of {n_in}, "
                f"request {asked[0]})",
            )

        operator = ask

    session = ImpactSession(
        rig.daq,
        rig.input_channels,
        rig.response_channels,
        rig.loadcells,
        settings=settings,
        operator=operator,
        progress=progress,
        on_average=on_average,
    )
    res = session.run()
    outputs = [Channel(c.node, c.direction) for c in setup.responses]
    kinds: list[Any] = ["acceleration"] * len(outputs)
    for lc in setup.load_cells:
        outputs += [Channel(lc.node, k) for k in range(1, 7)]
        kinds += ["reaction"] * 6
    inputs = tuple(Channel(e.node, e.direction) for e in setup.excitations)
    keep = res.frequencies_hz > 0
    return FrfData(
        frequencies_hz=res.frequencies_hz[keep],
        H=res.H[keep],
        outputs=tuple(outputs),
        output_kinds=tuple(kinds),
        inputs=inputs,
        coherence=res.coherence[keep],
        meta={"source": "dimacq impact acquisition"},
    )
