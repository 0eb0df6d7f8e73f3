"""Backend ``"simulated"`` of every device kind: the virtual lab behind the real drivers' wires.

:class:`SimulatedWorld` is the lab of scenario ``scenario`` (:mod:`dimacq.simulators.lab`) cabled
as the rig file says — the hammer(s) and each accelerometer axis on their ``physical_channel`` of
a :class:`~dimacq.simulators.daq.backend.VirtualDaqBackend` (a pyusb backend), each load cell's
amplifier simulator on one python-can ``virtual`` channel with the rig file's ``node_id``, both
counting one SYNC clock. The transducers are the lab's own: each has a true sensitivity within
its datasheet tolerance (:mod:`dimacq.simulators.lab.transducers`) and each load cell its own
gauge matrix; the drivers learn them as on a real rig, only from the rig file's calibrated
sensitivities and the calibration files it names.

The entries then open the devices exactly as the hardware entries do:
:func:`open_daq` finds the DAQ through pyusb on the world's backend
(:func:`dimacq.backends.usb_daq.open_on_backend`), :func:`open_loadcell` opens each amplifier on
``can.Bus(interface="virtual", ...)`` with its calibration file
(:func:`dimacq.backends.can_loadcell.open_amplifier`), :func:`open_digitizer` opens
``digitizer_url`` (``simdigitizer://``) through pyserial's URL handler. The world's hand strikes
the article when the session asks (``ctx.operator``).

The devices are not kind: they play the imperfections of real ones
(:class:`~dimacq.simulators.imperfections.Imperfections`, on by default, the setting
``simulation_imperfections`` overrides any of them): the DAQ's clock free-runs in (time-lapse)
wall time with a bounded FIFO, keeps stale frames across START, stalls now and then; each
amplifier's crystal is off by up to ±50 ppm and CAN frames get lost; the digitizer's line
picks up noise and its port drops off.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.backends.base import DeviceContext, require_setup
from dimacq.backends.can_loadcell import open_amplifier
from dimacq.backends.serial_digitizer import open_digitizer as open_serial_digitizer
from dimacq.backends.usb_daq import open_on_backend
from dimacq.drivers.daq.driver import DaqTask
from dimacq.drivers.digitizer import SerialDigitizer
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.errors import SetupError
from dimacq.io.rig_file import LoadCellEntry, RigFile
from dimacq.model.channels import axis_name, gauge_names
from dimacq.model.frf import STANDARD_GRAVITY
from dimacq.simulators.daq.backend import DaqFaults, DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import Imperfections
from dimacq.simulators.lab import transducers as tr
from dimacq.simulators.lab.impact import virtual_lab
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.lab.timedomain import VirtualLab
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim, LoadCellFaults
from dimacq.simulators.loadcell.bench import SupportSideBench

__all__ = ["SimulatedWorld", "open_daq", "open_digitizer", "open_loadcell", "world"]

log = logging.getLogger(__name__)

_WORLD = "simulated-world"
_names = itertools.count()


class SimulatedWorld:
    """The virtual lab of ``scenario`` cabled as ``rig_file`` says.

    Parameters
    ----------
    scenario : str
    rig_file : RigFile
        Where each transducer is plugged in (``physical_channel``, node, direction, CAN
        ``node_id``); its sensitivities and calibration files are NOT read here.
    seed : int or None
        The scenario's noise seed (None: the scenario's own).
    noise_scale : float
        Factor on the scenario's noise and drift levels (0: noise-free).
    calibration_bench : int or None
        The article is the calibration mass on the inertial calibration bench of load cell
        ``calibration_bench``: the hand strikes a fixture on the cell's support side, so the cell
        carries every force on the mass
        (:class:`~dimacq.simulators.loadcell.bench.SupportSideBench`; the DAQ and the amplifier
        simulators read the bench). None: the article as the scenario mounts it.
    imperfections : Imperfections, optional
        The devices' imperfections (default: :data:`~dimacq.simulators.imperfections.DEFAULT`).

    Raises
    ------
    SetupError
        The rig file's sample rate differs from the lab's, or it names a sensor the scenario's
        article does not carry.
    """

    def __init__(
        self,
        scenario: str,
        rig_file: RigFile,
        seed: int | None = None,
        noise_scale: float = 1.0,
        calibration_bench: int | None = None,
        imperfections: Imperfections | None = None,
    ) -> None:
        self.scenario = scenario
        imp = imperfections if imperfections is not None else Imperfections()
        self.imperfections = imp
        fault_seed = 0 if seed is None else seed
        self.built = build_scenario(scenario, seed)
        # A test streams through the lab about once (the amplifier's tare a little behind):
        # 64 blocks cached, older ones recomputed from their stored states if read again.
        self.lab: VirtualLab = virtual_lab(
            self.built,
            noise_scale=noise_scale,
            hammer_noise=calibration_bench is None,
            cache_blocks=64,
        )
        where = f"rig file {rig_file.name} with scenario {scenario!r}"
        #: what the devices read and the hand strikes: the lab, or the bench around it
        self.source: VirtualLab | SupportSideBench = self._source(calibration_bench, where)
        if abs(rig_file.daq.sample_rate_hz - self.lab.sample_rate_hz) > 1e-9:
            raise SetupError(
                f"{where}: [daq] sample_rate_hz = {rig_file.daq.sample_rate_hz:g} but the virtual "
                f"lab samples at {self.lab.sample_rate_hz:g} Hz; set sample_rate_hz to it"
            )
        #: what is plugged into each DAQ input (what a simulated DAQ of another make reads)
        self.wiring = self._wiring(rig_file, where)
        self.clock = SampleClock()
        #: the DAQ's pyusb backend (``daq = "mcc-usb-simulated"`` puts its units here): what
        #: the operator's strikes are timed on (``world_sample``, ``clock``)
        self.backend: Any = self._daq_backend(imp, fault_seed)
        # each amplifier's crystal: within ±loadcell_oscillator_ppm of nominal
        ppm = np.random.default_rng([fault_seed, 0x0C]).uniform(
            -imp.loadcell_oscillator_ppm, imp.loadcell_oscillator_ppm, len(rig_file.load_cells)
        )
        # The bus's frame losses and bus-offs: a seeded world replays its seed's; an unseeded
        # one draws its own, as a bus does (seed 0 for every unseeded run lost the same frame,
        # pulse 3705 of node 1, at the first strike of every acquisition)
        fresh = np.random.SeedSequence().entropy  # an int when drawn from the OS
        assert isinstance(fresh, int)
        self.can_seed = fault_seed if seed is not None else fresh
        self.can_channel = f"dimacq-sim-{os.getpid()}-{next(_names)}"
        self._sims: list[LoadCellAmplifierSim] = []
        try:
            self._start_amplifiers(rig_file, imp, ppm)
        except BaseException:
            self.close()
            raise

    def _source(self, calibration_bench: int | None, where: str) -> VirtualLab | SupportSideBench:
        """The lab, or the inertial calibration bench of load cell ``calibration_bench`` around
        it (the cell must be on the scenario's article)."""
        if calibration_bench is None:
            return self.lab
        if calibration_bench not in {lc.node for lc in self.lab.model.setup.load_cells}:
            raise SetupError(
                f"{where}: load cell {calibration_bench} to calibrate is not on the "
                "scenario's article; give a scenario whose article hangs on that cell "
                "(calibration-mass-*)"
            )
        return SupportSideBench(self.lab, calibration_bench)

    def _wiring(self, rig_file: RigFile, where: str) -> dict[int, DaqInput]:
        """DAQ input → the lab channel plugged into it and its true sensitivity (V per unit).

        Hammers (mV/N) and accelerometers (mV/g) get a true sensitivity within their datasheet
        tolerance, drawn from their serial number; load cells cabled to DAQ inputs
        (``loadcell = "daq-channels"``) their bridge outputs, the same lab channels the
        amplifier simulators read.
        """
        article = self.lab.model.setup
        responses = {(c.node, c.direction): k for k, c in enumerate(article.responses)}
        hammer = self.lab.channel_index("hammer")
        wiring: dict[int, DaqInput] = {}
        for h in rig_file.hammers:
            mv = tr.true_sensitivity(
                tr.NOMINAL_HAMMER_MV_PER_N,
                tr.HAMMER_TOLERANCE,
                tr.hammer_serial(h.physical_channel),
            )
            wiring[h.physical_channel] = DaqInput(hammer, mv * 1e-3)
        absent = [r.key for r in rig_file.responses if (r.node, r.direction) not in responses]
        cells = {lc.node for lc in article.load_cells}
        absent += [f"load cell {e.node}" for e in rig_file.load_cells if e.node not in cells]
        if absent:
            raise SetupError(
                f"{where}: {', '.join(absent)} are not instrumented in the scenario's article; "
                f"give a rig file of this scenario (rig_file, DIMACQ_RIG_FILE; see config/rigs/) "
                "or use the scenario's node numbers (dimacq simulate --list)"
            )
        for r in rig_file.responses:
            mv = tr.true_sensitivity(
                tr.NOMINAL_ACCEL_MV_PER_G,
                tr.ACCEL_TOLERANCE,
                tr.accelerometer_serial(r.physical_channel),
            )
            wiring[r.physical_channel] = DaqInput(
                responses[(r.node, r.direction)], mv * 1e-3 / STANDARD_GRAVITY
            )
        for e in rig_file.load_cells:
            if e.daq_channels:
                wiring.update(self._bridge_inputs(e, where))
        return wiring

    def _daq_backend(self, imp: Imperfections, fault_seed: int) -> VirtualDaqBackend:
        """The DAQ's pyusb backend on the source, the wiring and the clock, with the DAQ's
        imperfections (free-running clock, bounded FIFO, stale frames, stalls, re-enumeration)."""
        return VirtualDaqBackend(
            self.source,
            self.wiring,
            clock=self.clock,
            free_running=imp.daq_free_running,
            time_scale=imp.daq_time_scale,
            fifo_bytes=imp.daq_fifo_bytes,
            adaptive=imp.daq_adaptive_time_lapse,
            seed=fault_seed,
            faults=DaqFaults(
                stale_frames_survive_start=imp.daq_stale_frames,
                stall_rate=imp.daq_stall_rate,
                stall_s=imp.daq_stall_s,
                reenumerate_rate=imp.daq_reenumerate_rate,
                reenumerate_s=imp.daq_reenumerate_s,
            ),
        )

    def _start_amplifiers(
        self, rig_file: RigFile, imp: Imperfections, ppm: NDArray[np.float64]
    ) -> None:
        """One amplifier simulator per load cell on CAN (``node_id`` set) on the world's
        ``virtual`` channel, crystal ``ppm[k]`` off nominal; each joins ``_sims`` as it starts
        (a failure closes those already started)."""
        for k, e in enumerate(rig_file.load_cells):
            if e.node_id is None:  # not on CAN: its gauges are DAQ inputs
                continue
            gauges = [self.lab.channel_index(n) for n in gauge_names(e.node)]
            self._sims.append(
                LoadCellAmplifierSim(
                    self.can_channel,
                    self.source,
                    gauges,
                    clock=self.clock,
                    node_id=e.node_id,
                    serial_number=e.node,
                    oscillator_ppm=float(ppm[k]),
                    faults=LoadCellFaults(
                        frame_loss_rate=imp.can_frame_loss_rate,
                        bus_off_rate=imp.can_bus_off_rate,
                        bus_off_s=imp.can_bus_off_s,
                        seed=self.can_seed,
                    ),
                )
            )

    def _bridge_inputs(self, entry: LoadCellEntry, where: str) -> dict[int, DaqInput]:
        """DAQ inputs of load cell ``entry``'s gauges: the lab's bridge outputs (mV/V, a
        DC-coupled strain-gauge cell) times its true excitation, or its AC-coupled gauges'
        volts; no IEPE."""
        names = gauge_names(entry.node)
        if entry.daq_signals != "gauges" or len(entry.daq_channels) != len(names):
            raise SetupError(
                f"{where}: load cell {entry.node} has daq_signals = {entry.daq_signals!r} on "
                f"{len(entry.daq_channels)} DAQ inputs; the simulated cell is cabled by its "
                f"{len(names)} gauges (daq_signals = 'gauges')"
            )
        idx = [self.lab.channel_index(n) for n in names]
        bridge = (self.lab.bridges or {}).get(entry.node)
        out = {}
        for ch, i in zip(entry.daq_channels, idx, strict=True):
            unit = self.lab.channel_units[i]
            sens = 1e-3 * bridge.excitation_v if unit == "mV/V" and bridge is not None else 1.0
            out[ch] = DaqInput(i, sens, iepe=False)
        return out

    def operator(self, ctx: DeviceContext) -> Any:
        """The hand that strikes the article's input the setup's input ``j`` names (node and
        direction), at the DAQ sample the session asks for."""
        setup = require_setup(ctx, "the simulated operator")
        inputs = {(e.node, e.direction): i for i, e in enumerate(self.lab.model.setup.excitations)}
        missing = [
            axis_name(e.node, e.direction)
            for e in setup.excitations
            if (e.node, e.direction) not in inputs
        ]
        if missing:
            raise SetupError(
                f"setup inputs {missing} are not input points of scenario {self.scenario!r}; "
                "use the scenario's node numbers (see dimacq simulate --list)"
            )
        index = [inputs[(e.node, e.direction)] for e in setup.excitations]
        source, backend = self.source, self.backend

        def strike(j: int, daq_sample: int) -> None:
            # A free-running lab has gone on past what the host has read (the load cells have
            # read it already): the hand strikes at the asked sample or, when that is past, now.
            with backend.clock.source_lock:
                source.excite(index[j], max(backend.world_sample(daq_sample), source.frontier))

        return strike

    def close(self) -> None:
        while self._sims:
            self._sims.pop().close()


def world(ctx: DeviceContext) -> SimulatedWorld:
    """The context's simulated world (made on first use, closed with the context)."""
    w = ctx.shared.get(_WORLD)
    if w is None:
        w = SimulatedWorld(
            ctx.settings.scenario,
            ctx.rig_file,
            ctx.seed,
            ctx.noise_scale,
            calibration_bench=ctx.calibration_bench,
            imperfections=imperfections(ctx),
        )
        ctx.shared[_WORLD] = w
        ctx.on_close(w.close)
    assert isinstance(w, SimulatedWorld)
    return w


def imperfections(ctx: DeviceContext) -> Imperfections:
    """The simulated devices' imperfections of the settings (``simulation_imperfections``).

    The RDT sensor (``netft-udp-simulated``) samples on its own clock at the set time-lapse and
    its driver aligns on it: the DAQ's time-lapse stays fixed (not adaptive) with it."""
    imp = Imperfections.from_mapping(ctx.settings.simulation_imperfections)
    if str(ctx.settings.loadcell) == "netft-udp-simulated" and imp.daq_adaptive_time_lapse:
        imp = dataclasses.replace(imp, daq_adaptive_time_lapse=False)
    return imp


def open_daq(ctx: DeviceContext) -> DaqTask:
    """The table entry ``daq = "simulated"``: the DAQ driver on the world's pyusb backend."""
    w = world(ctx)
    task = open_on_backend(ctx, w.backend, f"daq = 'simulated' (scenario {w.scenario!r})")
    if ctx.setup is not None:
        ctx.operator = w.operator(ctx)
    # The lab can only be struck at or after what it has generated (whole blocks).
    ctx.fixed.update({"hit_delay_samples": w.lab.block_samples, "block_samples": 512})
    return task


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> LoadCellAmplifier:
    """The table entry ``loadcell = "simulated"``: the amplifier driver on the world's
    python-can ``virtual`` channel, calibrated from the entry's calibration file (the cell on
    the calibration bench, ``ctx.calibration_bench``, may have none yet)."""
    w = world(ctx)
    return open_amplifier(
        ctx,
        entry,
        interface="virtual",
        channel=w.can_channel,
        where=f"loadcell = 'simulated' (scenario {w.scenario!r})",
        timeout_s=5.0,
        require_calibration=ctx.calibration_bench != entry.node,
    )


def open_digitizer(ctx: DeviceContext) -> SerialDigitizer:
    """The table entry ``digitizer = "simulated"``: ``digitizer_url = "simdigitizer://NAME?..."``
    through pyserial's URL handler (the simulated device is made on first use and forgotten
    when the context closes)."""
    import urllib.parse

    import dimacq.simulators.digitizer as simdig

    url = ctx.settings.digitizer_url
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != simdig.SCHEME:
        raise SetupError(
            f"digitizer = 'simulated' with digitizer_url = {url!r}: give a "
            "'simdigitizer://NAME?seed=S' URL, or digitizer = 'serial' for a real port"
        )
    imp = imperfections(ctx)
    simdig.get_device(url).set_imperfections(
        noise_rate=imp.digitizer_noise_rate,
        port_loss_rate=imp.digitizer_port_loss_rate,
        port_loss_s=imp.digitizer_port_loss_s,
    )
    ctx.on_close(lambda: simdig.unregister_device(parts.netloc))
    return open_serial_digitizer(ctx)


def open_dead_weight_bench(
    ctx: DeviceContext,
    *,
    node: int = 501,
    sample_rate_hz: float = 20.0,
    time_scale: float = 200.0,
    cell: Any = None,
    seed: int = 0,
) -> tuple[LoadCellAmplifier, Any, Any]:
    """The simulated dead-weight bench of strain-gauge cell ``node`` behind the amplifier
    simulator (its own clock, ``time_scale`` × real time) on a python-can ``virtual`` channel,
    and the real driver on it.

    Returns ``(amplifier, operator, cell)``: ``operator(case, sample)`` is the virtual operator
    (sets the load case up on the bench, then confirms like a person: returns None); ``cell``
    the simulated :class:`~dimacq.simulators.lab.bridge.StrainGaugeCell` (truth, for tests and
    the simulated command's figures). Closers go to ``ctx``.
    """
    import can
    import numpy as np

    from dimacq.simulators.lab.bridge import strain_gauge_cell
    from dimacq.simulators.loadcell.bench import DeadWeightBench

    if cell is None:
        cell = strain_gauge_cell(node, temperature_ramp_k_per_s=2e-4)
    bench = DeadWeightBench(cell, node=node, sample_rate_hz=sample_rate_hz, seed=seed)
    name = f"dimacq-bench-{os.getpid()}-{next(_bench_names)}"
    sim = LoadCellAmplifierSim(
        name, bench, list(range(12)), serial_number=node, time_scale=time_scale
    )
    ctx.on_close(sim.close)
    sim.rate_hz = float(sample_rate_hz)
    bus = can.Bus(interface="virtual", channel=name, fd=True)
    ctx.on_close(bus.shutdown)
    amp = LoadCellAmplifier(bus, timeout_s=5.0)

    def operator(case: Any, _sample: int) -> None:
        bench.place(case.mass_kg, np.array(case.position_m), np.array(case.gravity))

    return amp, operator, cell


_bench_names = itertools.count()


def article_truth(scenario: str) -> dict[str, Any]:
    """The simulated article's true properties (``dimacq solve --json`` keys, about the
    scenario's reference point), for the demonstration only: the page shows them beside a
    solution, marked as the simulator's. Never an input of the solve, which reads only FRFs and
    the setup."""
    out: dict[str, Any] = build_scenario(scenario, None).truth_json()
    return out


def article_geometry(scenario: str) -> dict[str, Any]:
    """Where the simulated article's sensors, impact points and load cells are (the scenario's
    geometry, in the setup-file format, GCS metres): what the engineer's hand knows in the
    virtual lab, so that a client can point the simulated digitizer's probe at them. The true
    inertia properties are not part of it."""
    from dimacq.io.setup_file import dump_setup_dict

    built = build_scenario(scenario, None)
    return {
        "scenario": scenario,
        "setup": dump_setup_dict(built.model.setup),
        "band_hz": [float(b) for b in built.band_hz],
    }
