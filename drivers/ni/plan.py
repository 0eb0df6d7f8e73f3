"""The plan of an NI cDAQ task: which module and AI each rig input is, the IEPE current and
bridge excitation each gets from what its module offers, the one data rate the modules run at
on their shared timebase, and each channel's input delay. Pure (no ``nidaqmx``): the dry run
prints it without hardware and :class:`~dimacq.drivers.ni.task.NiDsaTask` places its channels
with it.

Rate of the task: every module of one task runs on one master timebase ``fM``: an NI 9234's
13.1072 MHz when the task has one (a 9237 in a task with a 9234 runs at the 9234's rates by
default: NI KB "Valid Sampling Rates for the NI 9233, NI 9234, and NI 9237";
:attr:`~dimacq.drivers.ni.modules.ModuleSpec.leads_mixed_task`), else the internal timebase of
the module of the task's lowest input; each module coerces the rig's rate with
:func:`~dimacq.drivers.ni.modules.coerce_rate` on that ``fM`` and the task's rate is theirs (they
agree: one ``fM``, one rule). NI-DAQmx makes that choice itself; the task reads its
``timing.samp_clk_rate`` back and refuses to start when it is not the plan's.

Delay: channel ``c`` of a module sees the signal ``tau_c = D/fs + t_a`` late
(:func:`~dimacq.drivers.ni.modules.input_delay_s`); between a 9234 and a 9237 channel the
difference ``Δtau`` turns an FRF's phase by ``360° f Δtau``. The task removes each channel's
delay (NI-DAQmx ``ai_remove_filter_delay`` plus ``ai_filter_delay_adjustment`` for the rest of
the published figure) so that every channel is referred to its sampling instant.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from dimacq.drivers.ni.modules import CATALOGUE, ModuleSpec, coerce_rate, input_delay_s, module_spec
from dimacq.errors import SetupError

__all__ = [
    "ChannelKind",
    "ChannelRequest",
    "ModuleSlot",
    "NiPlan",
    "PlannedChannel",
    "catalogue_slots",
    "locate",
    "make_plan",
    "place",
    "propose_modules",
    "task_rate",
]

ChannelKind = Literal["accel", "force", "voltage", "bridge"]

#: relative tolerance of an asked IEPE current against an offered one (2.0 mA asked, 2.1 mA given)
_CURRENT_TOL = 0.10
#: relative tolerance of an asked excitation voltage against an offered one
_EXCITATION_TOL = 0.01


@dataclass(frozen=True)
class ChannelRequest:
    """One rig input as the rig file asks it.

    ``item`` names the rig file entry (``"responses.3"``) for messages; ``excitation_v`` is the
    bridge excitation of a ``"bridge"`` channel, V.
    """

    input: int
    name: str
    kind: ChannelKind
    item: str = ""
    iepe_current_ma: float = 0.0
    excitation_v: float | None = None
    range_v: float = 5.0
    coupling: Literal["AC", "DC"] = "AC"


@dataclass(frozen=True)
class ModuleSlot:
    """A module of the chassis and the rig inputs it carries: ``inputs[k]`` is its ``ai<k>``
    (fewer than ``n_channels``: the rest of its AIs are not cabled).

    ``iepe_currents_a`` and ``excitation_v`` are what the module offers: the device's own
    answers on a live system, the catalogue's in a dry run.
    """

    device: str
    model: str
    inputs: tuple[int, ...]
    n_channels: int
    iepe_currents_a: tuple[float, ...] = ()
    excitation_v: tuple[float, ...] = ()

    @property
    def first_input(self) -> int:
        return self.inputs[0]

    def describe_inputs(self) -> str:
        """``"0..3"``, ``"24"`` or ``"1, 5, 9"``."""
        i = self.inputs
        if len(i) > 1 and list(i) == list(range(i[0], i[0] + len(i))):
            return f"{i[0]}..{i[-1]}"
        return ", ".join(str(k) for k in i)

    @property
    def spec(self) -> ModuleSpec | None:
        return module_spec(self.model)

    @property
    def kind(self) -> str:
        spec = self.spec
        if spec is not None:
            return spec.kind
        return "bridge" if self.excitation_v and not self.iepe_currents_a else "iepe"


@dataclass(frozen=True)
class PlannedChannel:
    """A rig input placed on a module: ``physical`` is NI-DAQmx's name (``"cDAQ1Mod1/ai0"``);
    ``iepe_current_a`` 0 = IEPE off; ``delay_s`` the published input delay at the plan's rate
    (None: the module is not in the catalogue); ``refusal`` what the module refuses ("")."""

    request: ChannelRequest
    slot: ModuleSlot
    ai: int
    iepe_current_a: float
    excitation_v: float | None
    delay_s: float | None = None
    refusal: str = ""

    @property
    def physical(self) -> str:
        return f"{self.slot.device}/ai{self.ai}"


@dataclass(frozen=True)
class NiPlan:
    """The plan of one cDAQ task.

    Attributes
    ----------
    slots : the chassis's modules
    channels : the placed inputs, in input order
    asked_rate_hz, rate_hz : the rig's rate and the one the modules run at (None: not known
        without the device, or refused)
    timebase_hz, timebase_device : the shared master timebase and the module it comes from
    refusals : what the hardware would refuse, each naming the rig file item and the fix
    """

    slots: tuple[ModuleSlot, ...]
    channels: tuple[PlannedChannel, ...]
    asked_rate_hz: float
    rate_hz: float | None
    timebase_hz: float | None
    timebase_device: str
    refusals: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        return not self.refusals

    def delay_spread_s(self) -> float | None:
        """``max(tau) - min(tau)`` over the channels, s (None when a delay is unknown)."""
        d = [c.delay_s for c in self.channels]
        if not d or any(x is None for x in d):
            return None
        known = [x for x in d if x is not None]
        return max(known) - min(known)

    def raise_if_refused(self) -> None:
        if self.refusals:
            more = f" (and {len(self.refusals) - 1} more)" if len(self.refusals) > 1 else ""
            raise SetupError(self.refusals[0] + more)


def catalogue_slots(
    entries: Sequence[tuple[str, str, Sequence[int]]],
) -> list[ModuleSlot]:
    """Slots of ``(device, model, inputs)`` entries from the catalogue (``inputs`` empty: all
    its AIs, following the previous module's last input).

    Raises
    ------
    SetupError
        A model not in the catalogue, more inputs than the module has AIs, or two modules
        claiming one input.
    """
    out: list[ModuleSlot] = []
    nxt = 0
    for i, (device, model, inputs) in enumerate(entries):
        spec = module_spec(model)
        if spec is None:
            raise SetupError(
                f"daq.modules.{i}: model {model!r} is not in the catalogue "
                f"({', '.join(CATALOGUE)}); the dry run knows only these"
            )
        slot = ModuleSlot(
            device,
            spec.model,
            slot_inputs(inputs, nxt, spec.n_channels, f"daq.modules.{i}"),
            spec.n_channels,
            spec.iepe_currents_a,
            spec.excitation_v,
        )
        no_overlap(out, slot, f"daq.modules.{i}")
        out.append(slot)
        nxt = max(slot.inputs) + 1
    return out


def slot_inputs(inputs: Sequence[int], nxt: int, n_ai: int, item: str) -> tuple[int, ...]:
    """A module's rig inputs: ``inputs`` as given, or all ``n_ai`` from ``nxt`` on."""
    if not inputs:
        return tuple(range(nxt, nxt + n_ai))
    if len(inputs) > n_ai:
        raise SetupError(
            f"{item}: {len(inputs)} inputs for a module with {n_ai} AI channels; list at most "
            f"{n_ai}"
        )
    return tuple(inputs)


def no_overlap(slots: Sequence[ModuleSlot], slot: ModuleSlot, item: str) -> None:
    for s in slots:
        both = sorted(set(s.inputs) & set(slot.inputs))
        if both:
            raise SetupError(
                f"{item}: {slot.device} and {s.device} both carry input(s) "
                f"{', '.join(map(str, both))}; give each module its own inputs"
            )


def propose_modules(
    requests: Sequence[ChannelRequest],
    *,
    chassis: str = "cDAQ1",
    iepe_model: str = "NI 9234",
    bridge_model: str = "NI 9237",
) -> list[ModuleSlot]:
    """The catalogue's modules for the requests: in input order, each input on the current
    module's next AI, a new module whenever the kind of input changes (IEPE/voltage:
    ``iepe_model``, bridge: ``bridge_model``) or the current one is full; slots
    ``{chassis}Mod1`` ..."""
    out: list[ModuleSlot] = []
    for r in sorted(requests, key=lambda r: r.input):
        want = CATALOGUE[bridge_model if r.kind == "bridge" else iepe_model]
        cur = out[-1] if out else None
        if cur is not None and cur.model == want.model and len(cur.inputs) < cur.n_channels:
            out[-1] = ModuleSlot(
                cur.device,
                cur.model,
                (*cur.inputs, r.input),
                cur.n_channels,
                cur.iepe_currents_a,
                cur.excitation_v,
            )
            continue
        out.append(
            ModuleSlot(
                f"{chassis}Mod{len(out) + 1}",
                want.model,
                (r.input,),
                want.n_channels,
                want.iepe_currents_a,
                want.excitation_v,
            )
        )
    return out


def _mA(values: Sequence[float]) -> str:
    return ", ".join(f"{v * 1e3:g}" for v in values)


def place(req: ChannelRequest, slots: Sequence[ModuleSlot]) -> PlannedChannel:
    """The module, AI, IEPE current and excitation of one input.

    Range: at most the module's input range. IEPE current: 0 asked = off; otherwise the
    offered current within 10 % of the asked one.
    Bridge excitation: the offered internal voltage within 1 % of the asked one.

    Raises
    ------
    SetupError
        No module carries the input; an input kind the module cannot take; a current or
        voltage the module does not offer (naming the rig field and the fix).
    """
    slot, ai = locate(req.input, slots)
    where = slot.model
    if req.kind == "bridge":
        if slot.kind != "bridge":
            raise SetupError(
                f"input {req.input} is {slot.device}/ai{ai} ({slot.model}, no bridge excitation): "
                "a load cell's bridge needs a bridge module (NI 9237); cable it there"
            )
        v = req.excitation_v
        if v is None:
            raise SetupError("a bridge input needs excitation_v (V); give it in the rig file")
        got = [e for e in slot.excitation_v if abs(e - v) <= _EXCITATION_TOL * v]
        if not got:
            offered = ", ".join(f"{e:g}" for e in slot.excitation_v) or "none"
            raise SetupError(
                f"excitation_v = {v:g} V: {where} offers internal excitation of {offered} V; set "
                "excitation_v to one of them (a calibration in mV/V stays valid: a bridge's "
                "output is ratiometric)"
            )
        return PlannedChannel(req, slot, ai, 0.0, got[0])
    if slot.kind == "bridge":
        raise SetupError(
            f"input {req.input} is {slot.device}/ai{ai} ({slot.model}, a bridge module): an "
            f"{req.kind} input needs an IEPE module (NI 9234); cable it there"
        )
    problems: list[str] = []
    top = slot.spec.range_v if slot.spec is not None else None
    if top is not None and req.range_v > top * (1 + 1e-9):
        problems.append(
            f"range_v = {req.range_v:g} V: {where} measures ±{top:g} V; set range_v = {top:g} "
            "(or a sensor whose output stays within it)"
        )
    asked = req.iepe_current_ma * 1e-3
    got = [0.0]
    if asked > 0 and req.coupling == "DC":
        problems.append(
            f"iepe_current_ma = {req.iepe_current_ma:g} mA with coupling = 'DC': {where} gives "
            "IEPE current in AC coupling only; set coupling = 'AC' (or iepe_current_ma = 0)"
        )
    elif asked > 0:
        got = [c for c in slot.iepe_currents_a if abs(c - asked) <= _CURRENT_TOL * asked]
        if not got:
            offered = _mA(slot.iepe_currents_a)
            fix = (
                f"set iepe_current_ma = {slot.iepe_currents_a[0] * 1e3:g} (or 0 = off), or "
                f"cable the sensor to a module that offers {req.iepe_current_ma:g} mA"
                if slot.iepe_currents_a
                else "set iepe_current_ma = 0, or cable the sensor to an IEPE module"
            )
            problems.append(
                f"iepe_current_ma = {req.iepe_current_ma:g} mA: {where} offers "
                f"{offered + ' mA' if offered else 'no IEPE current'} (or off); {fix}"
            )
    if problems:
        raise SetupError("; and ".join(problems))
    return PlannedChannel(req, slot, ai, got[0], None)


def locate(rig_input: int, slots: Sequence[ModuleSlot]) -> tuple[ModuleSlot, int]:
    """The module carrying a rig input and its AI number.

    Raises
    ------
    SetupError
        No module carries it.
    """
    for s in slots:
        if rig_input in s.inputs:
            return s, s.inputs.index(rig_input)
    have = "; ".join(f"{s.device} {s.describe_inputs()}" for s in slots) or "none"
    raise SetupError(
        f"physical_channel {rig_input}: no module carries it (modules: {have}); add the module "
        "to [[daq.modules]] or use an input one carries"
    )


def task_rate(slots: Sequence[ModuleSlot], asked_hz: float) -> tuple[float, float, ModuleSlot]:
    """The data rate of a task over ``slots``, its ``fM`` and the module whose timebase it is:
    the first module that leads a mixed task (an NI 9234), else the first one.

    Raises
    ------
    SetupError
        A module not in the catalogue (the rate is then NI-DAQmx's to say), or a rate a module
        cannot run at (:func:`~dimacq.drivers.ni.modules.coerce_rate`).
    """
    if not slots:
        raise SetupError("the task has no module; add channels first")
    unknown = [s for s in slots if s.spec is None]
    if unknown:
        raise SetupError(
            f"{', '.join(f'{s.model} ({s.device})' for s in unknown)} not in the catalogue "
            f"({', '.join(CATALOGUE)}): the rate is known once NI-DAQmx has the task"
        )
    master = next((s for s in slots if s.spec is not None and s.spec.leads_mixed_task), slots[0])
    spec0 = master.spec
    assert spec0 is not None
    fm = spec0.timebase_hz
    rates = set()
    for s in slots:
        spec = s.spec
        assert spec is not None
        try:
            rate, _n = coerce_rate(spec, asked_hz, fm)
        except SetupError as err:
            raise SetupError(f"{s.device}: {err}") from err
        rates.add(round(rate, 9))
    (rate,) = rates  # one fM, one divisor rule: one rate
    return rate, fm, master


def make_plan(
    requests: Sequence[ChannelRequest], slots: Sequence[ModuleSlot], asked_rate_hz: float
) -> NiPlan:
    """Place every request, take the task's rate and each channel's delay; what the hardware
    would refuse is collected (each message names the rig file item), not raised: a refused
    input stays in the plan on its module with ``refusal`` set."""
    refusals: list[str] = []
    placed: list[PlannedChannel] = []
    for r in sorted(requests, key=lambda r: r.input):
        try:
            placed.append(place(r, slots))
        except SetupError as err:
            refusals.append(f"{r.item or r.name}: {err}")
            try:
                slot, ai = locate(r.input, slots)
            except SetupError:
                continue
            placed.append(PlannedChannel(r, slot, ai, 0.0, None, None, str(err)))
    used = [s for s in slots if any(c.slot == s for c in placed)]
    rate: float | None = None
    fm: float | None = None
    master = used[0].device if used else ""
    if used:
        try:
            rate, fm, lead = task_rate(used, asked_rate_hz)
            master = lead.device
        except SetupError as err:
            refusals.append(f"daq.sample_rate_hz: {err}")
    chans = []
    for c in placed:
        spec = c.slot.spec
        delay = input_delay_s(spec, rate) if spec is not None and rate is not None else None
        chans.append(
            PlannedChannel(
                c.request, c.slot, c.ai, c.iepe_current_a, c.excitation_v, delay, c.refusal
            )
        )
    return NiPlan(
        tuple(slots), tuple(chans), float(asked_rate_hz), rate, fm, master, tuple(refusals)
    )
