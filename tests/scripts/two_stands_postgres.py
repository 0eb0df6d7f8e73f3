"""Must-show of issue 15: two stands on one PostgreSQL database, and a database restart in the
middle of an acquisition.

Starts a throwaway PostgreSQL 15 server (the installed binaries, durable: fsync on), then two
``dimacq serve`` processes, stands A and B, each with its own data folder and the same
``DIMACQ_DATABASE_URL``, and shows:

1. a setup imported through A (``POST /api/setups/import?format=toml`` with
   ``config/examples/six_triax_setup.toml``) is listed by B;
2. jobs created on A run exactly once: ``--jobs`` sensitivity studies posted to A are claimed
   by A or B (``SELECT ... FOR UPDATE SKIP LOCKED``), each once (``attempts = 1``, one result);
3. a PostgreSQL restart (``pg_ctl restart -m fast``, down ``--down-s`` seconds) in the middle of
   A's simulated-lab acquisition: A's status reports the outage, the averages acquired meanwhile
   wait on A's disk, and without intervention the acquisition finishes with every average
   registered and its FRFs stored; B reads those FRFs from the database, and A's raw time data
   only through A.

    python tests/scripts/two_stands_postgres.py [--jobs 20] [--down-s 3]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

from _pg_support import PgServer, pg_binaries_missing  # noqa: E402
from _serve_support import Service  # noqa: E402
from sqlalchemy import create_engine, text  # noqa: E402

from dimacq.api.server import free_port  # noqa: E402
from dimacq.io.setup_file import dump_setup_dict  # noqa: E402
from dimacq.simulators.lab.scenarios import build_scenario  # noqa: E402

TOKEN = "two-stands"
EXAMPLE = TESTS.parent / "config" / "examples" / "six_triax_setup.toml"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=20)
    ap.add_argument("--down-s", type=float, default=3.0)
    args = ap.parse_args()
    why = pg_binaries_missing()
    if why:
        print(why)
        return 2
    pg = PgServer(durable=True)
    services: list[Service] = []
    ok = True
    try:
        url = pg.create_database()
        tmp = Path(tempfile.mkdtemp(prefix="dimacq-stands-"))
        env = {"DIMACQ_DATABASE_URL": url, "DIMACQ_SCENARIO": "calibration-mass-bungee"}
        a = Service(
            tmp / "A",
            free_port(),
            TOKEN,
            {**env, "DIMACQ_STAND": "A", "DIMACQ_DIGITIZER_URL": "simdigitizer://standA"},
        )
        services.append(a)
        b = Service(
            tmp / "B",
            free_port(),
            TOKEN,
            {**env, "DIMACQ_STAND": "B", "DIMACQ_DIGITIZER_URL": "simdigitizer://standB"},
        )
        services.append(b)
        print(
            f"PostgreSQL {pg.url()} ; stand A {a.url} ({tmp / 'A'}) ; stand B {b.url} ({tmp / 'B'})"
        )

        # 1. a setup imported through A is listed by B
        r = a.client.post(
            "/api/setups/import", params={"format": "toml"}, content=EXAMPLE.read_bytes()
        )
        r.raise_for_status()
        sid = r.json()["id"]
        listed = [s for s in b.client.get("/api/setups").json() if s["id"] == sid]
        print(
            f"\n1. setup {sid} imported through A; listed by B: {bool(listed)} "
            f"(name {listed[0]['name']!r}, {listed[0]['n_responses']} responses, stand "
            f"{listed[0]['stand']!r})"
            if listed
            else f"\n1. setup {sid} imported through A is NOT listed by B"
        )
        ok &= bool(listed)

        # 2. jobs created on A run exactly once (on A or B)
        body = {"half_size_m": 0.02, "sensors": 1, "max_angle_deg": 1.0, "trials": 3000}
        t0 = time.monotonic()
        made = [
            a.client.post("/api/sensitivity", json={**body, "seed": i}).json()
            for i in range(args.jobs)
        ]
        deadline = time.monotonic() + 300
        while True:
            states = [a.client.get(f"/api/jobs/{j['job_id']}").json()["state"] for j in made]
            if all(s in ("succeeded", "failed", "cancelled", "interrupted") for s in states):
                break
            if time.monotonic() > deadline:
                print("jobs did not finish:", states)
                return 1
            time.sleep(0.2)
        eng = create_engine(url)
        with eng.connect() as c:
            rows = c.execute(
                text("SELECT id, stand, attempts, state FROM jobs WHERE kind = 'sensitivity'")
            ).all()
            studies = c.execute(
                text("SELECT count(*) FROM sensitivity_studies WHERE result IS NOT NULL")
            ).scalar()
        eng.dispose()
        by_stand = {st: sum(1 for r in rows if r.stand == st) for st in ("A", "B")}
        once = all(r.attempts == 1 and r.state == "succeeded" for r in rows)
        print(
            f"\n2. {args.jobs} sensitivity jobs created on A, all final after {time.monotonic() - t0:.1f} s: "
            f"run by A {by_stand['A']}, by B {by_stand['B']}; every job claimed once "
            f"(attempts = 1) and succeeded: {once}; studies with a result: {studies}"
        )
        ok &= once and len(rows) == args.jobs and studies == args.jobs

        # 3. PostgreSQL restart in the middle of an acquisition on A
        setup = build_scenario("calibration-mass-bungee").model.setup
        sid2 = a.client.post("/api/setups", json=dump_setup_dict(setup)).json()["id"]
        acq = a.client.post(
            "/api/acquisitions", json={"setup_id": sid2, "averages_per_input": 3}
        ).json()
        while a.client.get(f"/api/acquisitions/{acq['id']}").json()["averages_accepted"] < 6:
            time.sleep(0.05)
        before = a.client.get(f"/api/acquisitions/{acq['id']}").json()["averages_accepted"]
        t_down = time.monotonic()
        pg.stop("fast")
        print(f"\n3. PostgreSQL stopped during acquisition {acq['id']} ({before} averages stored)")
        seen_down = None
        while time.monotonic() - t_down < args.down_s:
            st = a.client.get("/api/status").json()["database"]
            if not st["ok"]:
                seen_down = st
            r = a.client.get(f"/api/acquisitions/{acq['id']}")
            time.sleep(0.25)
        print(
            f"   while down: GET /api/acquisitions/{acq['id']} -> {r.status_code} {r.json()['detail']!r}"
        )
        print(f"   while down: status.database = {seen_down}")
        pg.start()
        t_up = time.monotonic()
        print(f"   PostgreSQL started again after {t_up - t_down:.1f} s")
        deadline = time.monotonic() + 600
        while a.client.get("/api/status").json()["database"]["writes_waiting"] and (
            time.monotonic() < deadline
        ):
            time.sleep(0.05)
        print(
            f"   the waiting writes were stored {time.monotonic() - t_up:.1f} s after the restart "
            "(no intervention)"
        )
        while True:
            try:
                r = a.client.get(f"/api/acquisitions/{acq['id']}")
                if r.status_code == 200 and r.json()["state"] != "running":
                    break
            except Exception:  # the service is expected to answer throughout
                pass
            if time.monotonic() > deadline:
                print("acquisition did not finish")
                return 1
            time.sleep(0.2)
        fin = r.json()
        n_files = len(
            list((tmp / "A" / "arrays" / "acquisitions" / f"{acq['id']:06d}").glob("*.h5"))
        )
        numbers = [av["number"] for av in fin["averages"]]
        st = a.client.get("/api/status").json()["database"]
        frf_b = b.client.get(f"/api/frfs/{fin['frf_id']}") if fin["frf_id"] else None
        raw_b = b.client.get(f"/api/acquisitions/{acq['id']}/averages/1")
        raw_a = a.client.get(f"/api/acquisitions/{acq['id']}/averages/1")
        print(
            f"   acquisition {fin['state']} {time.monotonic() - t_up:.1f} s after the restart: "
            f"{fin['averages_accepted']} accepted + {fin['averages_rejected']} rejected averages "
            f"registered (numbers 1..{max(numbers)} contiguous: {numbers == list(range(1, len(numbers) + 1))}), "
            f"{n_files} HDF5 files on A's disk, FRF set {fin['frf_id']}"
        )
        print(
            f"   status after: database ok={st['ok']} outages={st['outages']} writes_waiting={st['writes_waiting']}"
        )
        print(
            f"   B reads the FRF set: {frf_b.status_code if frf_b else None}; raw time data of "
            f"average 1 through A: {raw_a.status_code} {raw_a.json().get('shapes')}; through B: "
            f"{raw_b.status_code} {raw_b.json().get('detail')!r}"
        )
        ok &= (
            fin["state"] == "succeeded"
            and len(numbers) == n_files
            and numbers == list(range(1, len(numbers) + 1))
            and st["ok"]
            and st["writes_waiting"] == 0
            and seen_down is not None
            and frf_b is not None
            and frf_b.status_code == 200
            and raw_a.status_code == 200
            and raw_b.status_code == 409
        )
    finally:
        for s in services:
            s.stop()
        pg.close()
        if "tmp" in locals():
            shutil.rmtree(tmp, ignore_errors=True)
    print("\nALL OK" if ok else "\nFAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
