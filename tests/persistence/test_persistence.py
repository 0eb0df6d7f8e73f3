"""Database (migrations, WAL), atomic HDF5 array files, and recovery after a crash."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _api_support import make_settings
from sqlalchemy import select, text

from dimacq.errors import DataError, SetupError
from dimacq.persistence import ArrayStore, current_version, migrate, open_database
from dimacq.persistence import models as m
from dimacq.persistence.migrations import SCHEMA_VERSION
from dimacq.services.lab import Lab, frf_from_arrays, frf_to_arrays


def test_migrations_versioned_idempotent_and_wal(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite'}"
    db = open_database(url)
    assert db.schema_version == SCHEMA_VERSION == current_version(db.engine)
    assert migrate(db.engine) == SCHEMA_VERSION  # again: nothing to do
    with db.engine.connect() as c:
        assert c.execute(text("PRAGMA journal_mode")).scalar() == "wal"
        rows = c.execute(select(m.SchemaMigration.version)).scalars().all()
    assert rows == list(range(1, SCHEMA_VERSION + 1))
    db.close()


def test_newer_database_is_refused(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite'}"
    db = open_database(url)
    with db.session() as s:
        s.add(m.SchemaMigration(version=SCHEMA_VERSION + 1, description="from the future"))
    db.close()
    with pytest.raises(SetupError, match="newer than this dimacq"):
        open_database(url)


def test_array_store_atomic_round_trip_and_orphans(tmp_path: Path) -> None:
    store = ArrayStore(tmp_path)
    x = np.arange(12.0).reshape(3, 4)
    store.write("acquisitions/000001/avg-00001.h5", {"x": x}, {"accepted": True})
    arrays, attrs = store.read("acquisitions/000001/avg-00001.h5")
    np.testing.assert_array_equal(arrays["x"], x)
    assert attrs == {"accepted": True}
    assert not list(tmp_path.rglob("*.tmp"))  # no temporary left behind
    assert store.orphans("acquisitions", set()) == ["acquisitions/000001/avg-00001.h5"]
    assert store.orphans("acquisitions", {"acquisitions/000001/avg-00001.h5"}) == []
    with pytest.raises(DataError, match="outside the data directory"):
        store.write("../evil.h5", {"x": x})
    with pytest.raises(DataError, match="missing"):
        store.read("nope.h5")


def test_frf_arrays_round_trip() -> None:
    from dimacq.simulators.lab.forward import calibration_mass

    frf = calibration_mass(1).frf(np.linspace(5, 50, 10))
    back = frf_from_arrays(*frf_to_arrays(frf))
    np.testing.assert_array_equal(back.H, frf.H)
    assert back.outputs == frf.outputs and back.inputs == frf.inputs
    assert back.output_kinds == frf.output_kinds


@pytest.mark.slow
def test_restart_recovers_interrupted_jobs_and_orphan_averages(
    tmp_path: Path, database_url: str
) -> None:
    settings = make_settings(tmp_path, database_url=database_url)
    lab = Lab(settings, open_devices=False)
    with lab.db.session() as s:
        s.add(m.JobRow(id="j1", kind="acquisition", state="running", progress=0.4))
        acq = m.Acquisition(config={}, state="running")
        s.add(acq)
        s.flush()
        acq_id = acq.id
    # an average written to disk whose row was never committed (killed in between)
    lab.arrays.write(
        f"acquisitions/{acq_id:06d}/avg-00001.h5",
        {"force": np.ones((1, 8))},
        {"acquisition_id": acq_id, "input_index": 0, "number": 1, "accepted": True, "reason": ""},
    )
    lab.close()
    lab2 = Lab(settings, open_devices=False)
    try:
        assert lab2.jobs.snapshot("j1")["state"] == "interrupted"
        a = lab2.acquisitions.get(acq_id)
        assert a is not None and a.state == "interrupted"
        assert a.averages_accepted == 1
    finally:
        lab2.close()
