"""The acquisition rig: the one place devices are opened for an impact test.

:func:`build_rig` opens the configured devices through the backend tables
(:mod:`dimacq.backends`: ``daq``, ``loadcell``; simulated or real is only the name) and configures
them from the rig file (``rig_file``, :mod:`dimacq.io.rig_file`): per hammer a force channel,
per setup response the accelerometer channel the rig file assigns to its node and direction,
with the calibrated sensitivities, ranges, IEPE currents and couplings; each setup load cell the
amplifier the rig file names, calibrated from its calibration file. :func:`run_impact_test` runs
an :class:`~dimacq.services.acquisition.session.ImpactSession` on it and hands every completed average to
a callback *as soon as it is decided*, so the caller can make it durable before the next strike.
:func:`check_devices` opens one kind of device, identifies it and closes it again (what the
service's ``connect`` shows).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import ValidationError

from dimacq.backends import DeviceKind, lookup
from dimacq.backends.base import DeviceContext, Operator
from dimacq.config import Settings
from dimacq.devices.daq import Daq
from dimacq.devices.loadcell import LoadCell
from dimacq.errors import SetupError
from dimacq.io.rig_file import RigFile
from dimacq.model.channels import axis_name, input_name
from dimacq.model.frf import FrfData
from dimacq.model.impact import ImpactSettings
from dimacq.model.setup import TestSetup

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from dimacq.io.acquisition_hdf5 import AcquisitionWriter
    from dimacq.services.acquisition.session import AverageCallback, ImpactResult, ReviewCallback

__all__ = [
    "Rig",
    "StrikeRequest",
    "build_rig",
    "check_devices",
    "impact_settings",
    "raw_writer",
    "run_impact_session",
    "run_impact_test",
]

log = logging.getLogger(__name__)

ProgressCallback = Callable[[float, str], None]


@dataclass(frozen=True)
class StrikeRequest:
    """A person is asked to strike (a rig without a world that strikes by itself): what the
    acquisition's page says as "strike point 101 along −X".

    Attributes
    ----------
    input_index : int
        0-based, in the setup's input order; ``n_inputs`` of them.
    node, direction : int
        The input's node and UFF direction (±1..±3).
    direction_gcs : (3,) float
        Its line of action, unit vector in the GCS.
    average, averages : int
        The average asked for (1-based) of the ones wanted per input.
    request : int
        Running count of requests in this session (a rejected hit is asked again).
    message : str
        The progress line ("strike input N: 101+X (average ...)").
    """

    input_index: int
    n_inputs: int
    node: int
    direction: int
    direction_gcs: tuple[float, float, float]
    average: int
    averages: int
    request: int
    message: str

    def to_json(self) -> dict[str, Any]:
        from dimacq.model.setup import direction_label

        return {
            "input_index": self.input_index,
            "n_inputs": self.n_inputs,
            "node": self.node,
            "direction": direction_label(self.direction),
            "direction_gcs": list(self.direction_gcs),
            "average": self.average,
            "averages": self.averages,
            "request": self.request,
            "message": self.message,
        }


StrikeCallback = Callable[[StrikeRequest], None]


@dataclass
class Rig:
    """Devices ready for an impact test.

    Attributes
    ----------
    daq : Daq
        The task, channels and timing configured, not started.
    input_channels : DAQ channel name of the hammer force, per setup excitation (in order)
    response_channels : DAQ channel name per setup response (in order)
    loadcells : amplifiers in the order of ``setup.load_cells``
    operator : callable (input_index, daq_sample), optional
        A world that strikes by itself (the simulated lab). None: a person strikes;
        :func:`run_impact_test` asks through the progress callback ("strike input N: ...").
    closers : called in reverse order by :meth:`close`
    defaults : the rig file's impact settings (a request's values win)
    fixed : impact settings the devices impose (they win over the request)
    daq_units : engineering unit of each DAQ channel, in ``daq.channel_names`` order
    """

    daq: Daq
    input_channels: list[str]
    response_channels: list[str]
    loadcells: list[LoadCell] = field(default_factory=list)
    operator: Operator | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)
    defaults: dict[str, Any] = field(default_factory=dict)
    fixed: dict[str, Any] = field(default_factory=dict)
    daq_units: tuple[str, ...] = ()

    def close(self) -> None:
        while self.closers:
            fn = self.closers.pop()
            try:
                fn()
            except Exception:  # closing must go on for the others
                log.exception("closing part of the acquisition rig failed")


def _channels(rf: RigFile, setup: TestSetup) -> tuple[list[int], list[int], list[int]]:
    """Rig file entries per setup hammer input, response and load cell (indices)."""
    where = f"rig file {rf.name}"
    by_key = {r.key: i for i, r in enumerate(rf.responses)}
    missing = [
        axis_name(c.node, c.direction)
        for c in setup.responses
        if axis_name(c.node, c.direction) not in by_key
    ]
    if missing:
        raise SetupError(
            f"setup responses {missing} have no [[responses]] entry in {where}; add their node, "
            "direction, physical_channel and sensitivity_mv_per_g"
        )
    catch_all = [i for i, h in enumerate(rf.hammers) if not h.inputs]
    if len(catch_all) > 1:
        raise SetupError(
            f"{where}: hammers {catch_all} all have inputs = []; list the inputs of all but one"
        )
    claimed = {k.replace(" ", "").upper(): i for i, h in enumerate(rf.hammers) for k in h.inputs}
    hammer_of: list[int] = []
    for e in setup.excitations:
        k = axis_name(e.node, e.direction).upper()
        if k in claimed:
            hammer_of.append(claimed[k])
        elif catch_all:
            hammer_of.append(catch_all[0])
        else:
            raise SetupError(
                f"setup input {axis_name(e.node, e.direction)} is struck by no hammer in {where}; "
                "add it to a hammer's inputs or give one hammer inputs = []"
            )
    cells = {lc.node: i for i, lc in enumerate(rf.load_cells)}
    lc_missing = [lc.node for lc in setup.load_cells if lc.node not in cells]
    if lc_missing:
        raise SetupError(
            f"setup load cells {lc_missing} have no [[load_cells]] entry in {where}; add node, "
            "node_id and calibration_file"
        )
    response_of = [by_key[axis_name(c.node, c.direction)] for c in setup.responses]
    return hammer_of, response_of, [cells[lc.node] for lc in setup.load_cells]


@contextmanager
def _item(rf: RigFile, item: str) -> Iterator[None]:
    """A value the device refuses is refused naming the rig file's item."""
    try:
        yield
    except SetupError as err:
        raise SetupError(f"rig file {rf.name}, {item}: {err}") from err


def _configure(daq: Daq, rf: RigFile, response_of: list[int]) -> tuple[list[str], list[str]]:
    """Add the hammer and response channels the rig file describes; set the timing."""

    hammer_names = [f"hammer ch{h.physical_channel}" for h in rf.hammers]
    for i, (h, name) in enumerate(zip(rf.hammers, hammer_names, strict=True)):
        with _item(rf, f"hammers.{i}"):
            daq.add_force_channel(
                h.physical_channel,
                name,
                h.effective_sensitivity_mv_per_n,
                range_v=h.range_v,
                iepe_current_ma=h.iepe_current_ma,
                coupling=h.coupling,
            )
    names = []
    for i in response_of:
        r = rf.responses[i]
        with _item(rf, f"responses.{i}"):
            daq.add_accel_channel(
                r.physical_channel,
                r.key,
                r.sensitivity_mv_per_g,
                range_v=r.range_v,
                iepe_current_ma=r.iepe_current_ma,
                coupling=r.coupling,
            )
        names.append(r.key)
    with _item(rf, "daq"):
        daq.configure_timing(rf.daq.sample_rate_hz, rf.daq.samples_per_frame)
    return hammer_names, names


def build_rig(
    settings: Settings,
    setup: TestSetup,
    cfg: Mapping[str, Any],
    *,
    calibration_bench: int | None = None,
) -> Rig:
    """Open and configure the rig for ``setup``.

    Parameters
    ----------
    settings : Settings
        ``daq`` and ``loadcell`` name the backends (:data:`dimacq.backends.BACKENDS`);
        ``rig_file`` the channel map.
    setup : TestSetup
    cfg : mapping
        The acquisition request; ``seed`` seeds a simulated world, ``noise_scale`` scales its
        noise (0: noise-free; default 1).
    calibration_bench : int, optional
        The rig is the inertial calibration bench of this load cell (the calibration mass on
        it, struck on the cell's support side): its amplifier opens without a calibration file;
        run the test with ``loadcell_outputs="gauges"`` (:func:`run_impact_session`).

    Raises
    ------
    SetupError
        The rig file does not cover the setup, or a value is refused by the device.
    DeviceNotFoundError
        A device is not there (the message names the setting).
    """
    seed = cfg.get("seed")
    noise_scale = cfg.get("noise_scale")
    ctx = DeviceContext(
        settings,
        setup=setup,
        seed=None if seed is None else int(seed),
        noise_scale=1.0 if noise_scale is None else float(noise_scale),
        calibration_bench=calibration_bench,
    )
    rf = ctx.rig_file
    hammer_of, response_of, cell_of = _channels(rf, setup)
    ok = False
    try:
        daq: Daq = lookup("daq", settings.daq)(ctx)
        ctx.daq = daq
        hammer_names, response_names = _configure(daq, rf, response_of)
        loadcells: list[LoadCell] = []
        if cell_of:
            open_cell = lookup("loadcell", settings.loadcell)
            loadcells = [open_cell(ctx, rf.load_cells[i]) for i in cell_of]
        # a load cell read through the DAQ ("daq-channels") has wrapped it: the rig reads that
        daq = ctx.daq
        # the rate the DAQ runs at (a DAQ may coerce the rig file's: NI's modules do)
        fs = daq.sample_rate_hz or rf.daq.sample_rate_hz
        ok = True
    finally:
        if not ok:
            ctx.close()
    fixed = dict(ctx.fixed)
    if ctx.operator is None:
        fixed["trigger_timeout_samples"] = max(1, round(rf.daq.strike_timeout_s * fs))
    log.info(
        "rig: daq %r, loadcell %r, %d hammer(s), %d responses, %d load cell(s) at %g Hz (%s)",
        settings.daq,
        settings.loadcell,
        len(rf.hammers),
        len(response_names),
        len(loadcells),
        fs,
        rf.path,
    )
    return Rig(
        daq=daq,
        input_channels=[hammer_names[i] for i in hammer_of],
        response_channels=response_names,
        loadcells=loadcells,
        operator=ctx.operator,
        closers=[ctx.close],
        defaults=rf.acquisition.given(),
        fixed=fixed,
        daq_units=("N",) * len(hammer_names) + ("m/s^2",) * len(response_names),
    )


def _identity(ident: Any) -> dict[str, Any]:
    if is_dataclass(ident) and not isinstance(ident, type):
        return dict(asdict(ident))
    return {"identity": str(ident)}


def check_devices(settings: Settings, kind: DeviceKind) -> dict[str, Any]:
    """Open the ``daq`` or every load cell of the rig file through its backend, identify,
    close; the identity (what ``connect`` reports).

    Raises
    ------
    SetupError, DeviceNotFoundError
        As :func:`build_rig`.
    """
    with DeviceContext(settings) as ctx:
        if kind == "daq":
            daq = lookup("daq", settings.daq)(ctx)
            return {"backend": settings.daq, **_identity(daq.identify())}
        if kind != "loadcell":
            raise SetupError(f"check_devices: kind {kind!r} is not 'daq' or 'loadcell'")
        open_cell = lookup("loadcell", settings.loadcell)
        cells = {}
        for entry in ctx.rig_file.load_cells:
            cell = open_cell(ctx, entry)
            cells[str(entry.node)] = {"node_id": entry.node_id, **_identity(cell.identify())}
        return {"backend": settings.loadcell, "load_cells": cells}


def impact_settings(rig: Rig, cfg: Mapping[str, Any]) -> ImpactSettings:
    """Built-in defaults < the rig file's ``[acquisition]`` < the request < what the rig fixes;
    :class:`SetupError` naming the setting when the layers do not agree."""
    try:
        return ImpactSettings.layered(rig.defaults, cfg, rig.fixed)
    except ValidationError as err:
        e = err.errors(include_url=False)[0]
        where = ".".join(str(p) for p in e["loc"])
        raise SetupError(
            (f"{where}: " if where else "")
            + f"{e['msg'].removeprefix('Value error, ')} (the request with the rig file's "
            "[acquisition] table)"
        ) from None


def check_impact_test(rig: Rig, setup: TestSetup, cfg: Mapping[str, Any]) -> ImpactSettings:
    """Everything an impact test checks before its first strike: the rig's hammer and response
    channels against the setup's inputs and responses, and the settings as applied
    (:func:`impact_settings`). Raises :class:`SetupError`; the API calls it when the
    acquisition is created, so a bad setting is a 422 and no job starts."""
    if len(rig.input_channels) != len(setup.excitations):
        raise SetupError(
            f"setup_id: the rig has {len(rig.input_channels)} hammer channels for "
            f"{len(setup.excitations)} inputs of the setup; use a setup of this rig"
        )
    if len(rig.response_channels) != len(setup.responses):
        raise SetupError(
            f"setup_id: the rig has {len(rig.response_channels)} response channels for "
            f"{len(setup.responses)} responses of the setup; use a setup of this rig"
        )
    return impact_settings(rig, cfg)


@contextmanager
def raw_writer(rig: Rig, path: Path | None) -> Iterator[AcquisitionWriter | None]:
    """The writer that keeps every raw block of an impact test on ``rig`` in the HDF5 file
    ``path`` (:class:`~dimacq.io.acquisition_hdf5.AcquisitionWriter`: the DAQ's channels
    ``rig.daq.channel_names`` in units ``rig.daq_units``, each load cell's loads), closed on
    leaving; None when ``path`` is None (nothing kept)."""
    if path is None:
        yield None
        return
    from dimacq.io.acquisition_hdf5 import AcquisitionWriter

    sample_rate_hz = rig.daq.sample_rate_hz
    assert sample_rate_hz is not None  # configured by build_rig
    path.parent.mkdir(parents=True, exist_ok=True)
    with AcquisitionWriter(
        path,
        sample_rate_hz=sample_rate_hz,
        daq_channels=rig.daq.channel_names,
        daq_units=rig.daq_units,
        n_loadcells=len(rig.loadcells),
    ) as writer:
        yield writer


def run_impact_test(
    rig: Rig,
    setup: TestSetup,
    cfg: Mapping[str, Any],
    *,
    on_average: AverageCallback,
    on_progress: ProgressCallback,
    writer: AcquisitionWriter | None = None,
    meta: Mapping[str, str] | None = None,
    review: ReviewCallback | None = None,
    should_finish: Callable[[], bool] | None = None,
    on_input: Callable[[int, NDArray[np.float64]], None] | None = None,
    on_strike: StrikeCallback | None = None,
    on_event: Callable[[dict[str, object]], None] | None = None,
    prior: Sequence[Sequence[Mapping[str, NDArray[np.float64]]]] | None = None,
    on_lost: Callable[[int, str], None] | None = None,
) -> FrfData:
    """Run the impact test; return FRFs in the setup's channel order (SI units).

    ``review``, ``should_finish``, ``on_input``, ``on_event`` and ``on_lost`` go to the
    :class:`~dimacq.services.acquisition.session.ImpactSession` (the operator's accept / reject / redo
    of each hit; stop striking and keep the accepted averages; each input's coherence; the
    devices' events: DAQ lost and found again, gaps; each strike lost to a gap).

    ``writer`` keeps every raw block (:class:`~dimacq.io.acquisition_hdf5.AcquisitionWriter`,
    channels ``rig.daq.channel_names`` in units ``rig.daq_units``); ``meta`` goes into the
    FRFs' metadata (default: the source). ``on_strike`` is told every request to a person to
    strike (:class:`StrikeRequest`; none where the world strikes by itself). ``prior``: the
    accepted averages an interrupted acquisition kept, per input (a resumed acquisition strikes
    only the missing ones; see :class:`~dimacq.services.acquisition.session.ImpactSession`).
    """
    from dimacq.services.acquisition.session import impact_frf

    result = run_impact_session(
        rig,
        setup,
        cfg,
        on_average=on_average,
        on_progress=on_progress,
        writer=writer,
        review=review,
        should_finish=should_finish,
        on_input=on_input,
        on_strike=on_strike,
        on_event=on_event,
        prior=prior,
        on_lost=on_lost,
    )
    return impact_frf(result, setup, meta=dict(meta or {"source": "dimacq impact acquisition"}))


def run_impact_session(
    rig: Rig,
    setup: TestSetup,
    cfg: Mapping[str, Any],
    *,
    on_average: AverageCallback | None = None,
    on_progress: ProgressCallback,
    writer: AcquisitionWriter | None = None,
    loadcell_outputs: Literal["forces", "gauges"] = "forces",
    review: ReviewCallback | None = None,
    should_finish: Callable[[], bool] | None = None,
    on_input: Callable[[int, NDArray[np.float64]], None] | None = None,
    on_strike: StrikeCallback | None = None,
    on_event: Callable[[dict[str, object]], None] | None = None,
    prior: Sequence[Sequence[Mapping[str, NDArray[np.float64]]]] | None = None,
    on_lost: Callable[[int, str], None] | None = None,
) -> ImpactResult:
    """Run the impact session of :func:`run_impact_test` and return its raw result: FRFs of
    the responses, then per load cell its six loads (``loadcell_outputs="forces"``) or its 12
    gauges (``"gauges"``: a cell being calibrated). Without a world that strikes by itself
    (``rig.operator``) the person is asked through ``on_progress`` ("strike input N: ...") and,
    structured, through ``on_strike``."""
    from dimacq.services.acquisition.session import ImpactSession, Progress

    settings = check_impact_test(rig, setup, cfg)
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
            message = (
                f"strike input {j + 1}: {input_name(e)} "
                f"(average {accepted[j] + 1} of {wanted}, input {j + 1} of {n_in}, "
                f"request {asked[0]})"
            )
            if on_strike is not None:
                d = setup.input_directions[j]
                on_strike(
                    StrikeRequest(
                        j,
                        n_in,
                        e.node,
                        e.direction,
                        (float(d[0]), float(d[1]), float(d[2])),
                        accepted[j] + 1,
                        wanted,
                        asked[0],
                        message,
                    )
                )
            on_progress(fraction[0], message)

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
        writer=writer,
        review=review,
        should_finish=should_finish,
        on_input=on_input,
        loadcell_outputs=loadcell_outputs,
        on_event=on_event,
        on_lost=on_lost,
        input_labels=[input_name(e) for e in setup.excitations],
        prior=prior,
    )
    return session.run()
