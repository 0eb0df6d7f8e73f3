"""Integers in query strings (ids, indices, paging) are read in canonical form only, as ids in
paths: ``?test_id=01``, ``+1``, `` 1``, ``1_0``, ``1.0`` are refused (422 naming the parameter),
never read as another name of item 1; the plain form is answered as before."""

from __future__ import annotations

import pytest
from _api_support import Api

#: (path, parameter): every integer a query string carries, on a route that reads it
PARAMETERS = [
    ("/api/setups", "test_id"),
    ("/api/frfs", "test_id"),
    ("/api/solutions", "frf_id"),
    ("/api/solutions", "test_id"),
    ("/api/tests", "limit"),
    ("/api/tests", "offset"),
    ("/api/digitizer/points", "offset"),
]

REFUSED = [
    "01",
    "+1",
    " 1",
    "1 ",
    "1_0",
    "1.0",
    "1e0",
    "0x1",
    "١",
    "-01",
    "1" * 21,
    "0" * 5000 + "1",
]


@pytest.mark.slow
@pytest.mark.parametrize(("path", "name"), PARAMETERS)
@pytest.mark.parametrize("value", REFUSED)
def test_non_canonical_query_integers_refused_naming_the_parameter(
    api: Api, path: str, name: str, value: str
) -> None:
    r = api.client.get(path, params={name: value})
    assert r.status_code == 422, (path, name, value, r.text[:200])
    body = r.json()
    assert body["field"] == f"query.{name}", body
    assert "written plainly" in body["detail"] or "integer" in body["detail"], body


@pytest.mark.parametrize(("path", "name"), PARAMETERS)
def test_canonical_query_integers_answered(api: Api, path: str, name: str) -> None:
    r = api.client.get(path, params={name: "1"})
    assert r.status_code == 200, (path, name, r.text[:200])


def test_integers_inside_other_routes_queries(api: Api) -> None:
    """The FRF selection (indices, nodes, signed UFF directions) and the import's setup id."""
    c = api.client
    for name, value in (("response_direction", "+3"), ("input_node", "007"), ("input", "01")):
        r = c.get("/api/frfs/1/data", params={name: value})
        assert r.status_code == 422, r.text[:200]
        assert r.json()["field"].startswith(f"query.{name}"), r.json()
    r = c.post("/api/frfs/import", params={"setup_id": "01"}, content=b"x")
    assert r.status_code == 422 and r.json()["field"] == "query.setup_id", r.text[:200]
    # a minus sign is part of a direction's canonical form: refused only for what it names
    r = c.get("/api/frfs/1/data", params={"response_direction": "-3"})
    assert r.status_code == 404, r.text[:200]  # no FRF set 1; the direction itself was read


@pytest.mark.parametrize("job_id", ["a%00b", "%00", "x%E2%80%A8y", "%C2%85", "x" * 65, "a.b"])
@pytest.mark.parametrize(
    ("method", "template"),
    [
        ("GET", "/api/jobs/{}"),
        ("POST", "/api/jobs/{}/cancel"),
        ("GET", "/api/jobs/{}/events"),
        ("GET", "/api/calibrations/runs/{}/prompt"),
        ("POST", "/api/calibrations/runs/{}/confirm"),
    ],
)
def test_job_ids_in_paths_name_no_job_unless_plain(
    api: Api, method: str, template: str, job_id: str
) -> None:
    """A job id is letters, digits, '-' and '_': anything else (NUL, which PostgreSQL cannot
    store or compare, line separators) names no job: 404 before any lookup, on both databases."""
    r = api.client.request(method, template.format(job_id), json={})
    assert r.status_code == 404, (method, template, job_id, r.text[:200])
    assert "does not exist" in r.json()["detail"]
