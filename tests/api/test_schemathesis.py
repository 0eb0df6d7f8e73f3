"""Property-based API testing against the OpenAPI spec (schemathesis): no 500, no schema violation.

Bounded: 6 generated examples per operation, besides schemathesis's coverage cases (boundary
and negative values, most of the run); on PostgreSQL the schema-valid ones only. Runs against the
live server of this module on loopback, with the token, so state-changing operations are exercised
past the access check. Every default check runs (no server error, status codes, content types,
headers, response schemas, negative data rejected, Allow headers, ...) except
``positive_data_acceptance``: a schema-valid request may still be refused on its meaning with a
documented 4xx naming the item (registering a patch that has no reference nodes, solving an FRF
set that does not exist, a simulated probe placed outside the digitizer's volume).

A second run sends every state-changing operation (POST/PUT/PATCH/DELETE, generated bodies)
without the token: each must answer 401 before its body is read, and start nothing. Ids have
their range in the spec (1..2³¹−1), so the negative examples probe ids out of range too (404 in
the path, 422 in bodies and queries).

All requests of a test go over one keep-alive connection (``http``: a ``requests`` session that
does not read proxy settings from the environment): a new connection and an environment scan
per case cost about a third of the run's time on both ends, and test nothing of the service.
Run time (idle, alone): the SQLite run about 25 s, the token run 4 s, the PostgreSQL run 15 s.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import requests
import schemathesis
from _api_support import TOKEN, Api
from _pg_support import SQLITE_ONLY
from hypothesis import HealthCheck, settings
from schemathesis.specs.openapi.checks import positive_data_acceptance


@pytest.fixture(scope="module")
def api_schema(api: Api):
    return schemathesis.openapi.from_url(f"{api.url}/openapi.json")


@pytest.fixture(scope="module")
def api_schema_positive(api: Api):
    """Schema-valid requests only: the ones that reach the store."""
    schema = schemathesis.openapi.from_url(f"{api.url}/openapi.json")
    schema.config.generation.update(modes=[schemathesis.GenerationMode.POSITIVE])
    return schema


@pytest.fixture(scope="module")
def api_schema_fuzzing(api: Api):
    """Generated cases only (the fuzzing phase, schema-valid and schema-invalid data), not the
    coverage phase's boundary and negative values: for the token check a request is a request,
    whatever its values (the token is checked before the body is read)."""
    schema = schemathesis.openapi.from_url(f"{api.url}/openapi.json")
    schema.config.phases.update(phases=["fuzzing"])
    return schema


@pytest.fixture(scope="module")
def http(api: Api) -> Iterator[requests.Session]:
    """One keep-alive connection for the module's cases (no token: each call sends its own)."""
    with requests.Session() as session:
        session.trust_env = False  # no proxy or netrc lookup per request: loopback only
        yield session


schema = schemathesis.pytest.from_fixture("api_schema")
positive_schema = schemathesis.pytest.from_fixture("api_schema_positive")
fuzzing_schema = schemathesis.pytest.from_fixture("api_schema_fuzzing")


@pytest.fixture
def jobs_finish(api: Api):
    """Every job the generated requests started ends before the next test looks: load cell
    calibration runs (minutes of simulated bench work) are cancelled, the running ones waited
    for, and sensitivity studies still *queued* in the store (the service was at its job limit
    when they were asked for) cancelled. Those last were the flake of
    ``test_state_changing_operations_need_the_token`` (issue 27): the lab's ticker claimed one
    during that test, between its two reads of ``jobs_running`` (a ``sensitivity`` job,
    message "started", after a request that got 401)."""
    yield
    jobs = api.lab.jobs
    while True:
        for snap in jobs.list_jobs():
            if snap["state"] == "pending":
                jobs.cancel(snap["id"])
        for kind in ("loadcell-calibration", "plan"):  # plans: up to 200 solves
            for job in jobs.running(kind):
                jobs.cancel(job.id)
        running = jobs.running()
        if not running and all(snap["state"] != "pending" for snap in jobs.list_jobs()):
            break
        for job in running:
            jobs.wait(job.id, 60)


def _conforms(case, http: requests.Session) -> None:  # type: ignore[no-untyped-def]
    case.call_and_validate(
        session=http,
        headers={"Authorization": f"Bearer {TOKEN}"},
        timeout=30,
        excluded_checks=[positive_data_acceptance],
    )


@schema.parametrize()
@settings(
    max_examples=6,
    deadline=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)
@pytest.mark.parametrize("api_database_url", ["sqlite"], indirect=True)
@pytest.mark.slow
def test_api_conforms_to_its_spec(case, http: requests.Session, jobs_finish: None) -> None:
    _conforms(case, http)


@positive_schema.parametrize()
@settings(
    max_examples=6,
    deadline=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)
@pytest.mark.parametrize("api_database_url", ["postgresql"], indirect=True)
@pytest.mark.slow
def test_api_conforms_to_its_spec_on_postgresql(
    case, http: requests.Session, jobs_finish: None
) -> None:
    """The same on PostgreSQL with schema-valid data only (coverage and fuzzing phases): those
    are the requests that reach the store, whose refusals differ there (NUL in text, integer
    ranges, constraints). Schema-invalid data (4 of 5 of the cases) is refused by validation at
    the edge (pydantic bodies, ids 1..MAX_ID in paths) before any handler or database work: the
    SQLite run checks it."""
    _conforms(case, http)


@fuzzing_schema.include(method=["POST", "PUT", "PATCH", "DELETE"]).parametrize()
@settings(
    max_examples=2,
    deadline=None,
    derandomize=True,
    suppress_health_check=list(HealthCheck),
)
@SQLITE_ONLY  # the token is checked before any handler or database work: once, on SQLite
@pytest.mark.slow
def test_state_changing_operations_need_the_token(case, api: Api, http: requests.Session) -> None:
    """Every state-changing operation of the spec, with generated bodies, answers 401 without
    the token (before its body is read) and changes nothing.

    Two generated cases per operation (derandomized: the same ones every run), schema-valid and
    schema-invalid: every operation gets a valid one (a route that forgot the token check would
    run its handler and answer 2xx/4xx, not 401) and 36 of the 41 an invalid one too (a route
    that read its body before the check would answer 422). It was the coverage phase's 2,700
    cases (18 s), which vary the values, not whether the token is asked for."""
    if case.method.upper() != case.operation.method.upper():
        return  # schemathesis's unsupported-method probe (OPTIONS): 405, checked by the run above
    before = api.client.get("/api/status").json()["jobs_running"]
    response = case.call(session=http, timeout=30)
    assert response.status_code == 401, (case.method, case.path, response.text[:200])
    assert response.json()["field"] == "Authorization"
    assert api.client.get("/api/status").json()["jobs_running"] == before
