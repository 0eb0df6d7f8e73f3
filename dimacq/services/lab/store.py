"""Test store: setups, FRF sets and DIM solutions, in the database and the array files.

FRF arrays live in HDF5 files (:class:`~dimacq.persistence.ArrayStore`), each referenced by a
database row written after the file. Lookups of unknown ids return ``None`` (the API's 404).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, BinaryIO, Literal

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select

from dimacq.errors import DataError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup
from dimacq.persistence import ArrayStore, Database
from dimacq.persistence import models as m
from dimacq.persistence.arrays import arrays_from_bytes, arrays_to_bytes
from dimacq.services.lab.common import json_safe, vec

__all__ = [
    "ExportedFile",
    "FrfSummary",
    "FrfValues",
    "Imported",
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


# ---------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class SetupSummary:
    """A stored setup: counts and the setup document (setup-file keys)."""

    id: int
    name: str
    n_responses: int
    n_excitations: int
    n_load_cells: int
    setup: dict[str, Any]
    stand: str = ""  # the test stand that stored it

    @classmethod
    def of(cls, r: m.SetupRow) -> SetupSummary:
        return cls(
            id=r.id,
            name=r.name,
            n_responses=len(r.body.get("responses", [])),
            n_excitations=len(r.body.get("excitations", [])),
            n_load_cells=len(r.body.get("load_cells", [])),
            setup=r.body,
            stand=r.stand,
        )


@dataclass(frozen=True)
class Imported:
    """What an import stored: the setup, and the FRF set of a whole-test UFF."""

    setup_id: int
    frf_id: int | None = None


@dataclass(frozen=True)
class ExportedFile:
    content: bytes
    media_type: str


@dataclass(frozen=True)
class FrfSummary:
    """A stored FRF set (the arrays stay in their file)."""

    id: int
    setup_id: int
    acquisition_id: int | None
    name: str
    n_lines: int
    n_outputs: int
    n_inputs: int
    f_min_hz: float
    f_max_hz: float
    stand: str = ""  # the test stand that stored it

    @classmethod
    def of(cls, r: m.FrfSet) -> FrfSummary:
        return cls(
            id=r.id,
            setup_id=r.setup_id,
            acquisition_id=r.acquisition_id,
            name=r.name,
            n_lines=r.n_lines,
            n_outputs=r.n_outputs,
            n_inputs=r.n_inputs,
            f_min_hz=r.f_min_hz,
            f_max_hz=r.f_max_hz,
            stand=r.stand,
        )


@dataclass(frozen=True)
class FrfValues:
    """FRF values of some outputs × inputs: ``real``/``imag``/``coherence`` have the shape
    (n_lines, n_outputs, n_inputs)."""

    frequencies_hz: list[float]
    outputs: list[dict[str, int]]
    inputs: list[dict[str, int]]
    real: list[Any]
    imag: list[Any]
    coherence: list[Any] | None


@dataclass(frozen=True)
class StoredSolution:
    """A DIM solution: the options it was solved with and the result document (the keys of
    ``dimacq solve --json``)."""

    id: int
    frf_id: int
    options: dict[str, Any]
    result: dict[str, Any]

    @classmethod
    def of(cls, r: m.Solution) -> StoredSolution:
        return cls(id=r.id, frf_id=r.frf_id, options=r.options, result=r.result)


# ---------------------------------------------------------------------------------- service
class TestStore:
    """Setups, FRF sets and solutions."""

    __test__ = False  # not a pytest class

    def __init__(self, db: Database, arrays: ArrayStore, stand: str = "") -> None:
        self.db = db
        self.arrays = arrays
        self.stand = stand  # this service's test stand, recorded with what it stores

    # ------------------------------------------------------------------ setups
    def save_setup(self, setup: TestSetup) -> int:
        from dimacq.io.setup_file import dump_setup_dict

        with self.db.session() as s:
            row = m.SetupRow(name=setup.name, body=dump_setup_dict(setup), stand=self.stand)
            s.add(row)
            s.flush()
            return int(row.id)

    def setup(self, setup_id: int) -> TestSetup | None:
        from dimacq.io.setup_file import parse_setup

        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            return None if row is None else parse_setup(row.body, f"setup {setup_id}")

    def require_setup(self, setup_id: int) -> TestSetup:
        """The setup, or SetupError naming ``setup_id`` and the fix."""
        setup = self.setup(setup_id)
        if setup is None:
            raise SetupError(
                f"setup_id {setup_id} does not exist; create or import the setup first"
            )
        return setup

    def setups(self) -> list[SetupSummary]:
        with self.db.session() as s:
            return [
                SetupSummary.of(r) for r in s.scalars(select(m.SetupRow).order_by(m.SetupRow.id))
            ]

    def setup_summary(self, setup_id: int) -> SetupSummary | None:
        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            return None if row is None else SetupSummary.of(row)

    def import_setup(
        self,
        data: bytes | BinaryIO,
        fmt: Literal["json", "toml", "uff"],
        name: str | None = None,
    ) -> Imported:
        """Import a setup file (``json``/``toml``) or a whole-test UFF (``uff``: setup + FRFs)."""
        from dimacq.io.setup_file import read_setup
        from dimacq.io.uff import read_uff_test

        if fmt == "uff":
            setup, frf = read_uff_test(data, name=name)
            sid = self.save_setup(setup)
            return Imported(sid, self.save_frf(frf, sid, name=name or setup.name))
        setup = read_setup(data, fmt, "uploaded setup")
        if name:
            setup = setup.model_copy(update={"name": name})
        return Imported(self.save_setup(setup))

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

    def frfs(self) -> list[FrfSummary]:
        with self.db.session() as s:
            return [FrfSummary.of(r) for r in s.scalars(select(m.FrfSet).order_by(m.FrfSet.id))]

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

    def frf_values(
        self, frf_id: int, output: int | None = None, input_: int | None = None
    ) -> FrfValues | None:
        """FRF values (real/imag) of one output/input pair or all of them."""
        got = self.frf(frf_id)
        if got is None:
            return None
        frf, _ = got
        n_out, n_in = frf.H.shape[1:]
        for k, n, what in ((output, n_out, "output"), (input_, n_in, "input")):
            if k is not None and not 0 <= k < n:
                raise SetupError(f"{what} index {k} is outside 0..{n - 1}")
        oi = list(range(n_out)) if output is None else [output]
        ii = list(range(n_in)) if input_ is None else [input_]
        h = frf.H[:, oi][:, :, ii]
        return FrfValues(
            frequencies_hz=vec(frf.frequencies_hz),
            outputs=[frf.outputs[i].as_dict() for i in oi],
            inputs=[frf.inputs[j].as_dict() for j in ii],
            real=h.real.tolist(),
            imag=h.imag.tolist(),
            # NaN (one average: no coherence) → null, so the JSON is strict
            coherence=None if frf.coherence is None else json_safe(frf.coherence[:, oi][:, :, ii]),
        )

    # ------------------------------------------------------------------ solutions
    def save_solution(
        self, frf_id: int, options: Mapping[str, Any], result: Mapping[str, Any]
    ) -> StoredSolution:
        with self.db.session() as s:
            row = m.Solution(
                frf_id=frf_id,
                options=json_safe(dict(options)),
                result=json_safe(dict(result)),
                stand=self.stand,
            )
            s.add(row)
            s.flush()
            return StoredSolution.of(row)

    def solution(self, solution_id: int) -> StoredSolution | None:
        with self.db.session() as s:
            row = s.get(m.Solution, solution_id)
            return None if row is None else StoredSolution.of(row)

    def solutions(self) -> list[StoredSolution]:
        with self.db.session() as s:
            return [
                StoredSolution.of(r) for r in s.scalars(select(m.Solution).order_by(m.Solution.id))
            ]
