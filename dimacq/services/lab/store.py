"""Test store: setups, FRF sets and DIM solutions, in the database and the array files.

FRF arrays live in HDF5 files (:class:`~dimacq.persistence.ArrayStore`), each referenced by a
database row written after the file. Lookups of unknown ids return ``None`` (the API's 404).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from typing import Any, BinaryIO, Literal

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import defer

from dimacq.errors import DataError, DeviceStateError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import MAX_NAME_CHARS, TestSetup
from dimacq.persistence import ArrayStore, Database
from dimacq.persistence import models as m
from dimacq.persistence.arrays import arrays_from_bytes, arrays_to_bytes
from dimacq.pipeline.frf_summary import magnitude_envelope
from dimacq.services.lab.common import json_safe, vec
from dimacq.services.lab.records import (
    FRF_UNIT,
    ChannelQuery,
    ExportedFile,
    FrfSummary,
    FrfValues,
    Imported,
    Page,
    SetupSummary,
    StoredSolution,
)

#: Control characters: not in a name or label (dimacq.model.setup.one_line).
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def _one_line(text: Any) -> Any:
    if not isinstance(text, str):
        return text
    return (
        " ".join(text.split())[:MAX_NAME_CHARS] if _CONTROL.search(text) else text[:MAX_NAME_CHARS]
    )


def _stored_names(body: dict[str, Any]) -> dict[str, Any]:
    """A stored setup with its name and labels as one line of at most MAX_NAME_CHARS: rows stored
    before names had that rule stay readable (line breaks become spaces, the rest is
    cut); a body that keeps the rule is returned as it is."""
    lists = ("responses", "inputs", "excitations", "load_cells")
    names = [body.get("name")] + [
        c.get("label")
        for k in lists
        if isinstance(body.get(k), list)
        for c in body[k]
        if isinstance(c, dict)
    ]
    if all(
        not isinstance(n, str) or (len(n) <= MAX_NAME_CHARS and not _CONTROL.search(n))
        for n in names
    ):
        return body
    out = {**body, "name": _one_line(body.get("name", ""))}
    for k in lists:
        if isinstance(body.get(k), list):
            out[k] = [
                {**c, "label": _one_line(c["label"])} if isinstance(c, dict) and "label" in c else c
                for c in body[k]
            ]
    return out


#: States of an acquisition whose job is still running (it may still merge into an FRF set).
_RUNNING_STATES = ("running", "configured-running")

#: Most values of one envelope curve (points × responses × inputs): ~50 MB of JSON at most, for
#: its two curves. A report's figure asks for ~60 curves of ~1,000 points.
MAX_ENVELOPE_VALUES = 500_000

__all__ = [
    "MAX_ENVELOPE_VALUES",
    "ChannelQuery",
    "ExportedFile",
    "FrfSummary",
    "FrfValues",
    "Imported",
    "Page",
    "SetupSummary",
    "StoredSolution",
    "TestStore",
    "frf_from_arrays",
    "frf_to_arrays",
]


# ---------------------------------------------------------------------------------- FRF files
def frf_to_arrays(frf: FrfData) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """FRF data as HDF5 datasets and attributes."""
    arrays: dict[str, NDArray[Any]] = {"frequencies_hz": frf.frequencies_hz, "H": frf.H}
    if frf.coherence is not None:
        arrays["coherence"] = frf.coherence
    attrs = {
        "outputs": [c.as_dict() for c in frf.outputs],
        "output_kinds": list(frf.output_kinds),
        "inputs": [c.as_dict() for c in frf.inputs],
        "meta": dict(frf.meta),
    }
    return arrays, attrs


def frf_from_arrays(arrays: Mapping[str, NDArray[Any]], attrs: Mapping[str, Any]) -> FrfData:
    """Inverse of :func:`frf_to_arrays`."""
    return FrfData(
        frequencies_hz=np.asarray(arrays["frequencies_hz"], dtype=float),
        H=np.asarray(arrays["H"], dtype=complex),
        outputs=tuple(Channel(int(c["node"]), int(c["direction"])) for c in attrs["outputs"]),
        output_kinds=tuple(attrs["output_kinds"]),
        inputs=tuple(Channel(int(c["node"]), int(c["direction"])) for c in attrs["inputs"]),
        coherence=None if "coherence" not in arrays else np.asarray(arrays["coherence"], float),
        meta={str(k): str(v) for k, v in dict(attrs.get("meta", {})).items()},
    )


# ---------------------------------------------------------------------------------- service


def _strict(a: NDArray[np.float64]) -> Any:
    """An array as nested lists, NaN → None (JSON) only where there is one (fast path)."""
    return a.tolist() if np.isfinite(a).all() else json_safe(a)


def _setups_of_test(test_id: int) -> Any:
    """The ids of the setups of test ``test_id`` (a subquery)."""
    return select(m.SetupRow.id).where(m.SetupRow.test_id == test_id)


class TestStore:
    """Setups, FRF sets and solutions."""

    __test__ = False  # not a pytest class

    def __init__(self, db: Database, arrays: ArrayStore, stand: str = "") -> None:
        self.db = db
        self.arrays = arrays
        self.stand = stand  # this service's test stand, recorded with what it stores

    # ------------------------------------------------------------------ setups
    def save_setup(self, setup: TestSetup, test_id: int | None = None) -> int:
        """Store a setup (of test ``test_id``, which must exist); its id."""
        from dimacq.io.setup_file import dump_setup_dict

        with self.db.session() as s:
            if test_id is not None and s.get(m.TestRow, test_id) is None:
                raise SetupError(
                    f"test_id {test_id} does not exist; create the test first (POST /api/tests)"
                )
            row = m.SetupRow(
                name=setup.name, body=dump_setup_dict(setup), stand=self.stand, test_id=test_id
            )
            s.add(row)
            s.flush()
            return int(row.id)

    def setup(self, setup_id: int) -> TestSetup | None:
        from dimacq.io.setup_file import parse_setup

        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            body = None if row is None else row.body
        return None if body is None else parse_setup(_stored_names(body), f"setup {setup_id}")

    def require_setup(self, setup_id: int) -> TestSetup:
        """The setup, or SetupError naming ``setup_id`` and the fix."""
        setup = self.setup(setup_id)
        if setup is None:
            raise SetupError(
                f"setup_id {setup_id} does not exist; create or import the setup first"
            )
        return setup

    def setups(
        self, limit: int | None = None, offset: int = 0, test_id: int | None = None
    ) -> Page[SetupSummary]:
        """Setups in id order (of one test when ``test_id`` is given): ``limit`` of them (None:
        all) after the first ``offset``."""
        where = [] if test_id is None else [m.SetupRow.test_id == test_id]
        with self.db.session() as s:
            total = int(s.scalar(select(func.count()).select_from(m.SetupRow).where(*where)) or 0)
            q = select(m.SetupRow).where(*where).order_by(m.SetupRow.id).offset(offset).limit(limit)
            return Page([SetupSummary.of(r) for r in s.scalars(q)], total)

    def delete_setup(self, setup_id: int) -> bool | None:
        """Delete a setup; None if it does not exist. Refused (:class:`DeviceStateError`, 409)
        while FRF sets or acquisitions refer to it: delete those first."""
        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            if row is None:
                return None
            frfs = list(s.scalars(select(m.FrfSet.id).where(m.FrfSet.setup_id == setup_id)))
            acqs = list(
                s.scalars(select(m.Acquisition.id).where(m.Acquisition.setup_id == setup_id))
            )
            if frfs or acqs:
                raise DeviceStateError(
                    f"setup {setup_id} is used by "
                    + "; ".join(
                        x
                        for x in (
                            f"FRF sets {frfs}" if frfs else "",
                            f"acquisitions {acqs}" if acqs else "",
                        )
                        if x
                    )
                    + ": delete those first (DELETE /api/frfs/{id}, /api/acquisitions/{id})"
                )
            s.delete(row)
            return True

    def setup_summary(self, setup_id: int) -> SetupSummary | None:
        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            return None if row is None else SetupSummary.of(row)

    def import_setup(
        self,
        data: bytes | BinaryIO,
        fmt: Literal["json", "toml", "uff"],
        name: str | None = None,
        test_id: int | None = None,
    ) -> Imported:
        """Import a setup file (``json``/``toml``) or a whole-test UFF (``uff``: setup + FRFs),
        into test ``test_id`` when given."""
        from dimacq.io.setup_file import read_setup
        from dimacq.io.uff import read_uff_test

        if fmt == "uff":
            setup, frf = read_uff_test(data, name=name)
            sid = self.save_setup(setup, test_id)
            return Imported(sid, self.save_frf(frf, sid, name=name or setup.name))
        setup = read_setup(data, fmt, "uploaded setup")
        if name:
            setup = setup.model_copy(update={"name": name})
        return Imported(self.save_setup(setup, test_id))

    def export_setup(self, setup_id: int, fmt: Literal["json", "toml"]) -> ExportedFile | None:
        """Setup as ``json`` or ``toml`` text; None if it does not exist."""
        from dimacq.io.setup_file import dump_setup_dict

        setup = self.setup(setup_id)
        if setup is None:
            return None
        if fmt == "json":
            return ExportedFile(
                json.dumps(dump_setup_dict(setup), indent=2).encode(), "application/json"
            )
        import tomli_w

        return ExportedFile(
            tomli_w.dumps(dump_setup_dict(setup, toml=True)).encode(), "application/toml"
        )

    # ------------------------------------------------------------------ FRF sets
    def save_frf(
        self, frf: FrfData, setup_id: int, *, name: str = "", acquisition_id: int | None = None
    ) -> int:
        """Store FRFs: the HDF5 image in the database row, so every stand reads them."""
        arrays, attrs = frf_to_arrays(frf)
        with self.db.session() as s:
            if s.get(m.SetupRow, setup_id) is None:
                raise SetupError(
                    f"setup_id {setup_id} does not exist; create or import the setup first"
                )
        data = arrays_to_bytes(arrays, attrs)
        with self.db.session() as s:
            row = m.FrfSet(
                setup_id=setup_id,
                acquisition_id=acquisition_id,
                name=name,
                path="",
                data=data,
                stand=self.stand,
                n_lines=frf.n_lines,
                n_outputs=int(frf.H.shape[1]),
                n_inputs=int(frf.H.shape[2]),
                f_min_hz=float(frf.frequencies_hz[0]),
                f_max_hz=float(frf.frequencies_hz[-1]),
            )
            s.add(row)
            s.flush()
            return int(row.id)

    def frf_summary(self, frf_id: int) -> FrfSummary | None:
        with self.db.session() as s:
            row = s.get(m.FrfSet, frf_id)
            return None if row is None else FrfSummary.of(row)

    def frfs(
        self, limit: int | None = None, offset: int = 0, test_id: int | None = None
    ) -> Page[FrfSummary]:
        """FRF sets in id order (of the setups of one test when ``test_id`` is given; their data
        are not read)."""
        where = [] if test_id is None else [m.FrfSet.setup_id.in_(_setups_of_test(test_id))]
        with self.db.session() as s:
            total = int(s.scalar(select(func.count()).select_from(m.FrfSet).where(*where)) or 0)
            q = (
                select(m.FrfSet)
                .where(*where)
                .options(defer(m.FrfSet.data))
                .order_by(m.FrfSet.id)
                .offset(offset)
                .limit(limit)
            )
            return Page([FrfSummary.of(r) for r in s.scalars(q)], total)

    def delete_frf(self, frf_id: int) -> bool | None:
        """Delete an FRF set and the solutions of it; None if it does not exist. The
        acquisition that measured it stays (its raw averages are still on disk). Refused
        (:class:`DeviceStateError`, 409, naming the acquisition) while a running acquisition
        merges its new inputs into the set (it would end failed, its FRFs lost)."""
        with self.db.session() as s:
            row = s.get(m.FrfSet, frf_id, options=[defer(m.FrfSet.data)])
            if row is None:
                return None
            merging = [
                a.id
                for a in s.scalars(
                    select(m.Acquisition).where(m.Acquisition.state.in_(_RUNNING_STATES))
                )
                if isinstance(a.config, dict) and a.config.get("merge_frf_id") == frf_id
            ]
            if merging:
                raise DeviceStateError(
                    f"FRF set {frf_id} is being merged into by running acquisition "
                    f"{merging[0]}; stop it (POST /api/acquisitions/{merging[0]}/stop) or wait "
                    "for it to end, then delete the set"
                )
            for sol in s.scalars(select(m.Solution).where(m.Solution.frf_id == frf_id)):
                s.delete(sol)
            s.flush()
            for acq in s.scalars(select(m.Acquisition).where(m.Acquisition.frf_id == frf_id)):
                acq.frf_id = None
            s.delete(row)
            return True

    def frf(self, frf_id: int) -> tuple[FrfData, TestSetup] | None:
        """The FRFs of a set and its setup."""
        with self.db.session() as s:
            row = s.get(m.FrfSet, frf_id)
            if row is None:
                return None
            rel, setup_id, data = row.path, row.setup_id, row.data
        # schema-1 rows (and their files) predate FRF data in the database
        arrays, attrs = arrays_from_bytes(data) if data is not None else self.arrays.read(rel)
        setup = self.setup(setup_id)
        if setup is None:
            raise DataError(f"FRF set {frf_id}: its setup {setup_id} is missing from the database")
        return frf_from_arrays(arrays, attrs), setup

    def import_frf(self, data: bytes | BinaryIO, setup_id: int, name: str = "") -> int:
        """FRFs from a UFF file (58 records) matched to an existing setup."""
        from dimacq.io.uff import read_frf_uff

        frf = read_frf_uff(data, self.require_setup(setup_id))
        return self.save_frf(frf, setup_id, name=name)

    def export_frf_uff(self, frf_id: int, whole_test: bool = True) -> bytes | None:
        """The FRFs as UFF 58 (with the geometry 164/2420/2411 when ``whole_test``)."""
        from dimacq.io.uff import dump_uff

        got = self.frf(frf_id)
        if got is None:
            return None
        frf, setup = got
        return dump_uff(frf, setup if whole_test else None)

    def _frf_selection(
        self,
        frf_id: int,
        response: ChannelQuery,
        input_: ChannelQuery,
        band_hz: tuple[float | None, float | None],
    ) -> tuple[FrfData, list[int], list[int], NDArray[np.intp]] | None:
        """The set, the response and input indices chosen and its lines within ``band_hz``."""
        got = self.frf(frf_id)
        if got is None:
            return None
        frf, _ = got
        oi = response.pick(frf.outputs, "response")
        ii = input_.pick(frf.inputs, "input")
        f = frf.frequencies_hz
        lo, hi = band_hz
        if lo is not None and hi is not None and not lo <= hi:
            raise SetupError(f"f_min_hz {lo} is above f_max_hz {hi}: give f_min_hz ≤ f_max_hz")
        keep = np.ones(f.size, dtype=bool)
        if lo is not None:
            keep &= f >= lo
        if hi is not None:
            keep &= f <= hi
        return frf, oi, ii, np.nonzero(keep)[0]

    @staticmethod
    def _channels(frf: FrfData, oi: list[int], ii: list[int]) -> dict[str, Any]:
        def resp(i: int) -> dict[str, Any]:
            c, kind = frf.outputs[i], frf.output_kinds[i]
            unit = FRF_UNIT[kind] if abs(c.direction) <= 3 or kind != "reaction" else "N·m/N"
            return {**c.as_dict(), "kind": kind, "unit": unit}

        return {
            "responses": [resp(i) for i in oi],
            "inputs": [{**frf.inputs[j].as_dict(), "kind": "input", "unit": "N"} for j in ii],
        }

    def frf_values(
        self,
        frf_id: int,
        response: ChannelQuery = ChannelQuery(),
        input_: ChannelQuery = ChannelQuery(),
        band_hz: tuple[float | None, float | None] = (None, None),
    ) -> FrfValues | None:
        """FRF values (real/imag/coherence) of the chosen responses × inputs on the lines
        within ``band_hz`` (either end None: open); None if the set does not exist."""
        got = self._frf_selection(frf_id, response, input_, band_hz)
        if got is None:
            return None
        frf, oi, ii, lines = got
        h = frf.H[lines][:, oi][:, :, ii]
        coh = None
        if frf.coherence is not None:
            # NaN (one average: no coherence) → null, so the JSON is strict
            coh = json_safe(frf.coherence[lines][:, oi][:, :, ii])
        return FrfValues(
            frf_id=frf_id,
            layout="[line][response][input]",
            frequencies_hz=vec(frf.frequencies_hz[lines]),
            **self._channels(frf, oi, ii),
            real=h.real.tolist(),
            imag=h.imag.tolist(),
            coherence=coh,
        )

    def frf_values_f32(
        self,
        frf_id: int,
        response: ChannelQuery = ChannelQuery(),
        input_: ChannelQuery = ChannelQuery(),
        band_hz: tuple[float | None, float | None] = (None, None),
    ) -> bytes | None:
        """:meth:`frf_values` as one float32 message (:func:`dimacq.io.frf_binary.encode_f32`):
        arrays ``real``, ``imag`` and (when the set has it) ``coherence``, each shape
        (n_lines, n_responses, n_inputs); the frequencies and channels in its header."""
        from dimacq.io.frf_binary import encode_f32

        got = self._frf_selection(frf_id, response, input_, band_hz)
        if got is None:
            return None
        frf, oi, ii, lines = got
        whole = (
            lines.size == frf.H.shape[0]
            and oi == list(range(frf.H.shape[1]))
            and ii == list(range(frf.H.shape[2]))
        )

        def pick(a: NDArray[Any]) -> NDArray[Any]:
            return (
                a if whole else a[np.ix_(lines, np.asarray(oi, np.intp), np.asarray(ii, np.intp))]
            )

        h = pick(frf.H)
        arrays: dict[str, NDArray[Any]] = {"real": h.real, "imag": h.imag}
        if frf.coherence is not None:
            arrays["coherence"] = pick(frf.coherence)
        header = {
            "frf_id": frf_id,
            "layout": "[line][response][input]",
            "frequencies_hz": vec(frf.frequencies_hz[lines]),
            **self._channels(frf, oi, ii),
        }
        return encode_f32(header, arrays)

    def frf_envelope(
        self,
        frf_id: int,
        points: int,
        response: ChannelQuery = ChannelQuery(),
        input_: ChannelQuery = ChannelQuery(),
        band_hz: tuple[float | None, float | None] = (None, None),
    ) -> dict[str, Any] | None:
        """The |H| envelope of the chosen responses × inputs on the lines within ``band_hz`` in
        at most ``points`` points, and their mean coherence over those lines
        (:func:`dimacq.pipeline.frf_summary.magnitude_envelope`); None if the set does not
        exist. SetupError when points × responses × inputs passes :data:`MAX_ENVELOPE_VALUES`
        (the answer would be ~50 bytes a value: 100,000 points of 18 × 50 inputs were 126 MB)."""
        got = self._frf_selection(frf_id, response, input_, band_hz)
        if got is None:
            return None
        frf, oi, ii, lines = got
        n_points = min(points, int(lines.size))
        if n_points * len(oi) * len(ii) > MAX_ENVELOPE_VALUES:
            raise SetupError(
                f"envelope of {n_points} points × {len(oi)} responses × {len(ii)} inputs = "
                f"{n_points * len(oi) * len(ii)} values per curve, more than "
                f"{MAX_ENVELOPE_VALUES} (MAX_ENVELOPE_VALUES); ask for fewer points, responses "
                "or inputs"
            )
        coh = None if frf.coherence is None else frf.coherence[lines][:, oi][:, :, ii]
        env = magnitude_envelope(
            frf.frequencies_hz[lines], frf.H[lines][:, oi][:, :, ii], coh, points
        )
        return {
            "frf_id": frf_id,
            "layout": "[point][response][input]",
            "n_lines": int(lines.size),
            "lines_per_point": env.lines_per_point,
            "frequencies_hz": vec(env.frequencies_hz),
            "f_lo_hz": vec(env.f_lo_hz),
            "f_hi_hz": vec(env.f_hi_hz),
            **self._channels(frf, oi, ii),
            "magnitude_max": _strict(env.magnitude_max),
            "magnitude_min": _strict(env.magnitude_min),
            "coherence_mean": None if env.coherence_mean is None else json_safe(env.coherence_mean),
        }

    # ------------------------------------------------------------------ solutions
    def save_solution(
        self, frf_id: int, options: Mapping[str, Any], result: Mapping[str, Any]
    ) -> StoredSolution:
        """Store a solution of FRF set ``frf_id``.

        Raises
        ------
        DeviceStateError
            The set was deleted while it was solved (409; its foreign key refused the row, an
            IntegrityError, which was a 500).
        """
        gone = DeviceStateError(
            f"FRF set {frf_id} was deleted while it was being solved; the solution is not "
            "stored (import or acquire the set again to solve it)"
        )
        try:
            with self.db.session() as s:
                if s.get(m.FrfSet, frf_id, options=[defer(m.FrfSet.data)]) is None:
                    raise gone
                row = m.Solution(
                    frf_id=frf_id,
                    options=json_safe(dict(options)),
                    result=json_safe(dict(result)),
                    stand=self.stand,
                )
                s.add(row)
                s.flush()
                return StoredSolution.of(row)
        except IntegrityError as err:  # deleted between the check and the insert
            raise gone from err

    def solution(self, solution_id: int) -> StoredSolution | None:
        with self.db.session() as s:
            row = s.get(m.Solution, solution_id)
            return None if row is None else StoredSolution.of(row)

    def solutions(
        self,
        limit: int | None = None,
        offset: int = 0,
        frf_id: int | None = None,
        test_id: int | None = None,
    ) -> Page[StoredSolution]:
        """Solutions in id order (of one FRF set when ``frf_id`` is given, of the FRF sets of one
        test's setups when ``test_id`` is)."""
        with self.db.session() as s:
            where = [] if frf_id is None else [m.Solution.frf_id == frf_id]
            if test_id is not None:
                sets = select(m.FrfSet.id).where(m.FrfSet.setup_id.in_(_setups_of_test(test_id)))
                where.append(m.Solution.frf_id.in_(sets))
            total = int(s.scalar(select(func.count()).select_from(m.Solution).where(*where)) or 0)
            q = select(m.Solution).where(*where).order_by(m.Solution.id).offset(offset).limit(limit)
            return Page([StoredSolution.of(r) for r in s.scalars(q)], total)

    def delete_solution(self, solution_id: int) -> bool | None:
        with self.db.session() as s:
            row = s.get(m.Solution, solution_id)
            if row is None:
                return None
            s.delete(row)
            return True
