"""Several services on one database, on SQLite and on a real PostgreSQL server: migrations from
several processes at once, queued jobs claimed exactly once, one service per stand, every stand
reads every result, raw data served by its own stand, a server restart during an acquisition."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from _api_support import make_settings
from _lab_rig_support import IMPULSE_SETUP, impulse_rig_factory
from sqlalchemy import select

from dimacq.errors import DatabaseUnavailableError, DeviceStateError, SetupError
from dimacq.persistence import SCHEMA_VERSION, open_database
from dimacq.persistence import models as m
from dimacq.persistence.queue import claim_job, enqueue_job
from dimacq.persistence.stands import StandIdentity, claim_stand, heartbeat
from dimacq.services.lab import Lab


def _acq(info: object) -> dict:
    """An acquisition as the API shows it (dict)."""
    from dataclasses import asdict

    return asdict(info)  # type: ignore[call-overload]


def _url(database_url: str, tmp_path: Path) -> str:
    return database_url or f"sqlite:///{tmp_path / 'shared.sqlite'}"


_MIGRATE = """
import sys, time
from pathlib import Path
from dimacq.persistence.db import open_database
go = Path(sys.argv[2])
print("ready", flush=True)
while not go.exists():
    time.sleep(0.005)
db = open_database(sys.argv[1])
print(db.schema_version, flush=True)
db.close()
"""


@pytest.mark.slow
def test_migrations_from_several_processes_at_once(database_url: str, tmp_path: Path) -> None:
    """Three processes open (and migrate) one empty database at the same instant."""
    url = _url(database_url, tmp_path)
    go = tmp_path / "go"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _MIGRATE, url, str(go)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(3)
    ]
    try:
        for p in procs:
            assert p.stdout is not None and p.stdout.readline().strip() == "ready"
        go.touch()  # all three past their imports: go
        outs = [p.communicate(timeout=60) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    assert [o[0].strip() for o in outs] == [str(SCHEMA_VERSION)] * 3, [o[1] for o in outs]
    db = open_database(url)  # and once more: nothing to do
    try:
        with db.session() as s:
            versions = list(s.scalars(select(m.SchemaMigration.version)))
        assert sorted(versions) == list(range(1, SCHEMA_VERSION + 1))  # each applied once
    finally:
        db.close()


@pytest.mark.slow
def test_queued_jobs_are_claimed_exactly_once(database_url: str, tmp_path: Path) -> None:
    """Two services (two engines), three claiming threads each, 40 jobs: every job is claimed
    by exactly one of them, once."""
    url = _url(database_url, tmp_path)
    a, b = open_database(url), open_database(url)
    try:
        for i in range(40):
            enqueue_job(a, f"job{i:03d}", "work", {"i": i}, created_by="A")
        claimed: list[tuple[str, str]] = []
        lock = threading.Lock()

        def claimer(db, stand: str, instance: str) -> None:
            while True:
                got = claim_job(db, ["work"], stand=stand, instance=instance)
                if got is None:
                    return
                with lock:
                    claimed.append((got[0], instance))

        threads = [
            threading.Thread(target=claimer, args=(db, st, f"{st}{k}"))
            for db, st in ((a, "A"), (b, "B"))
            for k in range(3)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        ids = [c[0] for c in claimed]
        assert sorted(ids) == [f"job{i:03d}" for i in range(40)]  # each once, none missed
        with a.session() as s:
            rows = list(s.scalars(select(m.JobRow)))
        assert all(r.attempts == 1 and r.state == "running" for r in rows)
        assert {r.stand for r in rows} <= {"A", "B"}
        # a job bound to stand B is never claimed by A
        enqueue_job(a, "onlyB", "work", {}, created_by="A", runs_on="B")
        assert claim_job(a, ["work"], stand="A", instance="A0") is None
        assert claim_job(b, ["work"], stand="B", instance="B0") == ("onlyB", "work", {})
    finally:
        a.close()
        b.close()


@pytest.mark.slow
def test_one_service_per_stand(database_url: str, tmp_path: Path) -> None:
    url = _url(database_url, tmp_path)
    db = open_database(url)
    try:
        first = StandIdentity("bay-1", api_url="http://pc1:8765", pid=1, host="pc1")
        claim_stand(db, first)
        claim_stand(db, StandIdentity("bay-2"))  # another stand: fine
        with pytest.raises(SetupError, match="'bay-1' is already served by pid 1 on pc1"):
            claim_stand(db, StandIdentity("bay-1", pid=2, host="pc2"))
        # a stand whose service stopped renewing its heartbeat can be taken over
        with db.session() as s:
            row = s.get(m.StandRow, "bay-1")
            assert row is not None
            row.heartbeat_at = m.utcnow().replace(year=2000)
        second = StandIdentity("bay-1", pid=2, host="pc2")
        claim_stand(db, second)
        assert heartbeat(db, second) and not heartbeat(db, first)
    finally:
        db.close()


@pytest.mark.slow
def test_two_stands_share_results_but_not_devices(database_url: str, tmp_path: Path) -> None:
    """Stand A acquires; stand B lists A's setup, acquisition and FRFs (from the database), is
    refused A's raw time data (on A's disk) with A's address, and cannot stop A's acquisition."""
    url = _url(database_url, tmp_path)
    sa = make_settings(tmp_path / "a", database_url=url, stand="A", port=18001)
    sb = make_settings(tmp_path / "b", database_url=url, stand="B", port=18002)
    lab_a = Lab(sa, open_devices=False, rig_factory=impulse_rig_factory(pace_s=0.02))
    lab_b = Lab(sb, open_devices=False)
    try:
        sid = lab_a.store.save_setup(IMPULSE_SETUP)
        assert [x.id for x in lab_b.store.setups().items] == [sid]
        acq = _acq(
            lab_a.acquisitions.start(
                {"setup_id": sid, "averages_per_input": 3, "record_samples": 512}
            )
        )
        while _acq(lab_b.acquisitions.get(acq["id"]))["averages_accepted"] < 1:
            time.sleep(0.02)
        with pytest.raises(DeviceStateError, match=r"runs on stand .A..*http://127\.0\.0\.1:18001"):
            lab_b.acquisitions.stop(acq["id"])
        snap = lab_a.jobs.wait(acq["job_id"], 60)
        assert snap["state"] == "succeeded", snap
        seen_by_b = _acq(lab_b.acquisitions.get(acq["id"]))
        assert seen_by_b["stand"] == "A" and seen_by_b["state"] == "succeeded"
        assert seen_by_b["averages_accepted"] == 6
        frf_a, _ = lab_a.store.frf(seen_by_b["frf_id"])
        frf_b, setup_b = lab_b.store.frf(
            seen_by_b["frf_id"]
        )  # B has no file of it: from the database
        np.testing.assert_array_equal(frf_a.H, frf_b.H)
        assert setup_b.name == IMPULSE_SETUP.name
        assert not (tmp_path / "b" / "arrays" / "acquisitions").exists()
        raw = lab_a.acquisitions.average_data(acq["id"], 1)
        assert raw is not None and raw["stand"] == "A" and raw["shapes"]
        with pytest.raises(DeviceStateError, match=r"on stand .A..*http://127\.0\.0\.1:18001"):
            lab_b.acquisitions.average_data(acq["id"], 1)
        assert {s["name"] for s in lab_b.stands()} == {"A", "B"}
        # B's restart does not touch A's running work
        assert lab_b.job_store.interrupt_stale() == 0
    finally:
        lab_b.close()
        lab_a.close()


@pytest.mark.slow
def test_postgresql_restart_mid_acquisition_loses_nothing(pg_server, tmp_path: Path) -> None:
    """The database server restarts while averages are being acquired: the acquisition goes
    on, the averages acquired meanwhile wait on disk and in the outbox, the status says the
    database is down and why, and once it is back everything is registered and the FRFs are
    stored, without any intervention."""
    url = pg_server.create_database()
    settings = make_settings(tmp_path, database_url=url, stand="R")
    lab = Lab(settings, open_devices=False, rig_factory=impulse_rig_factory(pace_s=0.05))
    try:
        sid = lab.store.save_setup(IMPULSE_SETUP)
        acq = _acq(
            lab.acquisitions.start(
                {"setup_id": sid, "averages_per_input": 12, "record_samples": 512}
            )
        )
        deadline = time.monotonic() + 30
        while _acq(lab.acquisitions.get(acq["id"]))["averages_accepted"] < 3:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        pg_server.stop("fast")
        try:
            with pytest.raises(DatabaseUnavailableError, match="database unavailable"):
                _acq(lab.acquisitions.get(acq["id"]))
            # averages go on while the database is down: wait for one to queue its writes (the
            # state asserted), not for a time (0.6 s held no average on a loaded machine)
            deadline = time.monotonic() + 30
            while (status := lab.status().database)["writes_waiting"] < 1:
                assert time.monotonic() < deadline, status
                time.sleep(0.02)
            assert status["ok"] is False and status["error"]
            assert lab.jobs.snapshot(acq["job_id"])["state"] == "running"
        finally:
            pg_server.start()
        snap = lab.jobs.wait(acq["job_id"], 60)
        assert snap["state"] == "succeeded", snap
        a = _acq(lab.acquisitions.get(acq["id"]))
        assert a["state"] == "succeeded" and a["frf_id"] is not None
        assert a["averages_accepted"] == 24
        assert [av["number"] for av in a["averages"]] == list(range(1, 25))
        assert lab.status().database["ok"] and lab.status().database["outages"] >= 1
        assert len(lab.outbox) == 0
    finally:
        lab.close()
        pg_server.drop_database(url)


@pytest.mark.slow
def test_upgrade_from_schema_1_keeps_old_rows(database_url: str, tmp_path: Path) -> None:
    """A database of schema version 1 (FRF data in files, no stands) migrates to the current
    schema in place; its FRF set still reads from its file."""
    from sqlalchemy import Column, MetaData, Table, create_engine

    from dimacq.io.setup_file import dump_setup_dict
    from dimacq.persistence.migrations import migrate
    from dimacq.simulators.lab.forward import calibration_mass

    url = _url(database_url, tmp_path)
    added = {"stand", "data", "created_by", "runs_on", "owner", "params", "attempts"}
    v1 = MetaData()
    for t in m.Base.metadata.sorted_tables:
        if t.name != "stands":
            Table(
                t.name,
                v1,
                *[
                    Column(c.name, c.type, primary_key=c.primary_key, nullable=c.nullable)
                    for c in t.columns
                    if c.name not in added
                ],
            )
    engine = create_engine(url)
    v1.create_all(engine)
    frf = calibration_mass(1).frf(np.linspace(5, 50, 8))
    settings = make_settings(tmp_path / "data", database_url=url, stand="old")
    from dimacq.persistence import ArrayStore
    from dimacq.services.lab import frf_to_arrays

    ArrayStore(settings.data_dir / "arrays").write("frfs/old.h5", *frf_to_arrays(frf))
    now = m.utcnow()
    body = dump_setup_dict(calibration_mass(1).setup)
    with engine.begin() as c:
        c.execute(
            v1.tables["schema_migrations"]
            .insert()
            .values(version=1, description="v1", applied_at=now)
        )
        c.execute(v1.tables["setups"].insert().values(id=1, name="old", body=body, created_at=now))
        c.execute(
            v1.tables["frf_sets"]
            .insert()
            .values(
                id=1,
                setup_id=1,
                name="old",
                path="frfs/old.h5",
                n_lines=8,
                n_outputs=1,
                n_inputs=1,
                f_min_hz=5.0,
                f_max_hz=50.0,
                created_at=now,
            )
        )
    assert migrate(engine) == SCHEMA_VERSION
    assert migrate(engine) == SCHEMA_VERSION  # idempotent
    engine.dispose()
    lab = Lab(settings, open_devices=False)
    try:
        with lab.db.session() as s:
            row = s.get(m.FrfSet, 1)
            assert row is not None and row.stand == "" and row.data is None
        got = lab.store.frf(1)  # from its file, as before the upgrade
        assert got is not None
        np.testing.assert_array_equal(got[0].H, frf.H)
    finally:
        lab.close()
