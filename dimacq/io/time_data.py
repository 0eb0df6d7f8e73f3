"""Impact-test time data from files: UFF dataset 58 time responses and LabVIEW TDMS.

Both become :class:`TimeRecord` lists that :func:`dimacq.services.acquisition.time_frf.frf_from_time`
turns into FRFs with the same estimator and windows as an acquisition.

**UFF 58, function type 1** (time response; pyuff reads it): one record per channel per
average; response node/direction = the channel, reference node/direction = the input struck;
ordinate type 13 (excitation force) for the hammer (its response = its reference), 12
(acceleration, m/s²) for an accelerometer, 9 (reaction force) with directions 1..6 for a load
cell's six loads (N, N·m); abscissa increment = the sample interval, s. The records of one
(channel, input) are that input's averages in file order. SI units (a dataset 164 that says
otherwise is refused).

**TDMS** (``nptdms``): one group per average of one input; the group's property ``input`` names
it (``"101+X"``); its channels are named as dimacq names them — ``"force"`` (the hammer, N), a
response axis ``"1103+Y"`` (m/s²), a load cell's loads ``"LC501 Fx"`` .. ``"LC501 Mz"`` (N, N·m)
— each with the waveform property ``wf_increment`` (s).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.model.channels import LOAD_AXES, axis_name

__all__ = [
    "TimeRecord",
    "read_tdms_time",
    "read_time_data",
    "read_uff_time",
    "uff_sample_interval",
    "write_tdms_time",
    "write_uff_time",
]

TimeKind = Literal["force", "acceleration", "reaction"]

_UFF_KIND: dict[int, TimeKind] = {13: "force", 12: "acceleration", 9: "reaction"}
_AXIS = re.compile(r"^\s*(\d+)\s*([+-])\s*([XYZxyz])\s*$")
_LOAD = re.compile(r"^\s*LC(\d+)\s+(Fx|Fy|Fz|Mx|My|Mz)\s*$")
_DIRS = {"X": 1, "Y": 2, "Z": 3}


@dataclass(frozen=True, eq=False)
class TimeRecord:
    """One channel of one average.

    Attributes
    ----------
    node, direction : int
        The channel (direction ±1..±3; a load cell's loads 1..6, Fx..Mz).
    ref_node, ref_direction : int
        The input struck in this average.
    kind : {"force", "acceleration", "reaction"}
    dt_s : float
    data : ndarray, shape (n,)
        SI: N, m/s², N or N·m.
    """

    node: int
    direction: int
    ref_node: int
    ref_direction: int
    kind: TimeKind
    dt_s: float
    data: NDArray[np.float64]


def _axis(text: str, where: str) -> tuple[int, int]:
    m = _AXIS.match(text)
    if m is None:
        raise DataError(f"{where}: {text!r} is not an axis like '101+X'")
    sign = 1 if m.group(2) == "+" else -1
    return int(m.group(1)), sign * _DIRS[m.group(3).upper()]


def read_uff_time(path: str | Path) -> list[TimeRecord]:
    """The time records (58, function type 1) of a UFF file (ASCII or binary).

    Raises
    ------
    DataError
        Unreadable file, no time records, an ordinate type other than 13/12/9, non-SI units.
    """
    import pyuff

    p = Path(path)
    try:
        sets: list[dict[str, Any]] = pyuff.UFF(str(p)).read_sets()
    except Exception as err:  # pyuff raises anything on a damaged file
        raise DataError(f"{p}: cannot read UFF ({type(err).__name__}: {err})") from err
    if isinstance(sets, dict):
        sets = [sets]
    out: list[TimeRecord] = []
    for k, d in enumerate(sets):
        t = int(d.get("type", 0))
        if t == 164:
            factors = [float(d.get(f, 1.0)) for f in ("length", "force", "temp")]
            if not np.allclose(factors[:2], 1.0):
                raise DataError(
                    f"{p}: dataset 164 gives length/force factors {factors[:2]}; time data are "
                    "read in SI (m, N): export them in SI"
                )
            continue
        if t != 58 or int(d.get("func_type", 0)) != 1:
            continue
        o_type = int(d.get("ordinate_spec_data_type", 0))
        ident = f"{p}: 58 record #{k} ({d.get('rsp_node')}:{d.get('rsp_dir')})"
        if o_type not in _UFF_KIND:
            raise DataError(
                f"{ident}: ordinate type {o_type}; time records must be excitation force (13), "
                "acceleration (12) or reaction force (9)"
            )
        x = np.asarray(d.get("x"), dtype=float)
        dt = uff_sample_interval(float(d.get("abscissa_inc") or (x[1] - x[0] if x.size > 1 else 0)))
        if not dt > 0:
            raise DataError(f"{ident}: no sample interval (abscissa increment); re-export it")
        out.append(
            TimeRecord(
                int(d["rsp_node"]),
                int(d["rsp_dir"]),
                int(d["ref_node"]),
                int(d["ref_dir"]),
                _UFF_KIND[o_type],
                dt,
                np.asarray(d["data"], dtype=float).real.copy(),
            )
        )
    if not out:
        raise DataError(f"{p}: no time records (dataset 58, function type 1)")
    return out


def uff_sample_interval(dt_s: float) -> float:
    """The sample interval a UFF 58 header means: its abscissa increment is written in E13.5
    (6 significant digits: 1/2048 Hz reads 4.88281e-04, 2048.001 Hz), so a rate within that
    precision (5·10⁻⁶) of a whole number of Hz is taken as that rate: ``1 / round(1 / dt)``."""
    if not dt_s > 0:
        return dt_s
    fs = 1.0 / dt_s
    whole = round(fs)
    return 1.0 / whole if whole and abs(fs - whole) <= 5e-6 * fs else dt_s


def _uff58_time(r: TimeRecord, text: str) -> str:
    """One ASCII dataset 58, function type 1 (time response), real double, even abscissa
    (records 1–11 as the UFF 58 layout gives them; ordinates in E20.12)."""
    o_type = {v: k for k, v in _UFF_KIND.items()}[r.kind]
    lines = [
        "    -1",
        "    58",
        f"{'Time Response':<80}",
        f"{text:<80}"[:80],
        f"{'dimacq':<80}",
        f"{'NONE':<80}",
        f"{'NONE':<80}",
        "%5i%10i%5i%10i %10s%10i%4i %10s%10i%4i"  # noqa: UP031 (Fortran record layout)
        % (1, 0, 0, 0, "NONE", r.node, r.direction, "NONE", r.ref_node, r.ref_direction),
        "%10i%10i%10i%13.5e%13.5e%13.5e" % (4, r.data.size, 1, 0.0, r.dt_s, 0.0),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (17, 0, 0, 0, "Time", "s"),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (o_type, 0, 0, 0, r.kind, "SI"),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (0, 0, 0, 0, "NONE", "NONE"),  # noqa: UP031
        "%10i%5i%5i%5i %-20s %-20s" % (0, 0, 0, 0, "NONE", "NONE"),  # noqa: UP031
    ]
    cells = [f"{v:20.12e}" for v in r.data.tolist()]
    lines += ["".join(cells[i : i + 4]) for i in range(0, len(cells), 4)]
    lines.append("    -1")
    return "\n".join(lines) + "\n"


def write_uff_time(path: str | Path, records: list[TimeRecord], text: str = "") -> None:
    """``records`` as ASCII UFF 58 time records (function type 1) that :func:`read_uff_time`
    (and other UFF readers) read: SI units, one record per channel per average, in order."""
    with Path(path).open("w", encoding="ascii") as fh:
        for r in records:
            fh.write(_uff58_time(r, text))


def write_tdms_time(path: str | Path, records: list[TimeRecord]) -> None:
    """``records`` as a TDMS file laid out as the module docstring says: per input struck, the
    ``a``-th force record opens group ``"<input> average <a>"`` and the records after it up to
    the next force record of any input are its channels."""
    from nptdms import ChannelObject, GroupObject, TdmsWriter

    count: dict[tuple[int, int], int] = {}
    with TdmsWriter(str(path)) as w:
        objs: list[Any] = []
        group = ""
        for r in records:
            if r.kind == "force":
                if objs:
                    w.write_segment(objs)
                ref = (r.ref_node, r.ref_direction)
                count[ref] = count.get(ref, 0) + 1
                name = axis_name(*ref)
                group = f"{name} average {count[ref]}"
                objs = [GroupObject(group, properties={"input": name})]
                channel = "force"
            elif not objs:
                raise DataError("time records: the first record must be a force record")
            elif r.kind == "reaction":
                channel = f"LC{r.node} {LOAD_AXES[r.direction - 1]}"
            else:
                channel = axis_name(r.node, r.direction)
            unit = "N*m" if r.kind == "reaction" and r.direction > 3 else _SI[r.kind]
            props = {"wf_increment": r.dt_s, "unit_string": unit}
            objs.append(ChannelObject(group, channel, r.data, properties=props))
        if objs:
            w.write_segment(objs)


_SI = {"force": "N", "acceleration": "m/s^2", "reaction": "N"}


def read_tdms_time(path: str | Path) -> list[TimeRecord]:
    """The time records of a TDMS file laid out as the module docstring says.

    Raises
    ------
    DataError
        Unreadable file, a group without ``input``, a channel name dimacq does not know, a
        channel without ``wf_increment``.
    """
    from nptdms import TdmsFile

    p = Path(path)
    try:
        f = TdmsFile.read(str(p))
    except Exception as err:  # nptdms raises anything on a damaged file
        raise DataError(f"{p}: cannot read TDMS ({type(err).__name__}: {err})") from err
    out: list[TimeRecord] = []
    for g in f.groups():
        where = f"{p}: group {g.name!r}"
        inp = g.properties.get("input")
        if not isinstance(inp, str):
            raise DataError(f"{where}: no 'input' property; give the input struck, e.g. '101+X'")
        rn, rd = _axis(inp, where)
        for ch in g.channels():
            dt = ch.properties.get("wf_increment")
            if dt is None or not float(dt) > 0:
                raise DataError(f"{where}, channel {ch.name!r}: no wf_increment (s)")
            data = np.asarray(ch[:], dtype=float)
            name = ch.name.strip()
            load = _LOAD.match(name)
            if name.lower() in ("force", "hammer"):
                rec = TimeRecord(rn, rd, rn, rd, "force", float(dt), data)
            elif load is not None:
                d = 1 + LOAD_AXES.index(load.group(2))
                rec = TimeRecord(int(load.group(1)), d, rn, rd, "reaction", float(dt), data)
            else:
                node, direction = _axis(name, f"{where}, channel")
                rec = TimeRecord(node, direction, rn, rd, "acceleration", float(dt), data)
            out.append(rec)
    if not out:
        raise DataError(f"{p}: no channels")
    return out


def read_time_data(path: str | Path) -> list[TimeRecord]:
    """By suffix: ``.tdms`` → :func:`read_tdms_time`, else UFF (:func:`read_uff_time`)."""
    return read_tdms_time(path) if Path(path).suffix.lower() == ".tdms" else read_uff_time(path)
