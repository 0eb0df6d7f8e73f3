"""Shared test configuration.

- ``--device KIND`` opts in to tests that need real hardware (marker ``device``); they are
  skipped otherwise.
- Under xdist (``-n``) every process runs one BLAS thread (see ``pytest_configure``).
- Every test must leave no thread running: a test that leaves a simulator, reader thread or bus
  notifier alive fails (python-can's own suite does the same for virtual channels).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Iterator

import pytest

# The simulated devices play real imperfections by default (free-running DAQ clock in wall time,
# stalls, CAN frame loss, serial noise and port loss, ...), and the drivers ride them out by
# waiting, retrying and striking again: in wall time. The suite runs the devices without them,
# so that its tests measure what they are about; the imperfections and the drivers surviving them
# are tested where they are set explicitly, which wins over this: tests/backends/
# test_imperfections.py, tests/simulators/daq, the per-fault driver tests, tests/cli/test_soak.py
# (the real service with every fault turned up).
os.environ.setdefault("DIMACQ_SIMULATION_IMPERFECTIONS", json.dumps({"enabled": False}))
from _pg_support import BACKENDS, database_url_for


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--device",
        action="append",
        default=[],
        metavar="KIND",
        help="run tests that need real hardware of this kind (digitizer, loadcell, daq, mcc, ni)",
    )


# One BLAS thread per process under xdist. OpenBLAS starts a thread per core in every worker
# (and every ``dimacq serve`` a test starts) and spins them while it waits: with two workers per
# core all of them competing, that spinning was a third of a numerical test's CPU time
# (tests/pipeline/test_uncertainty.py::test_interval_covers_the_truth: 10.4 s -> 6.9 s of CPU
# alone, 21 s in a loaded parallel run). Set here, in the controller, before the workers start:
# they, and the processes their tests start, inherit it. An explicit setting wins.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config: pytest.Config) -> None:
    if getattr(config.option, "numprocesses", None):
        for name in BLAS_THREAD_VARIABLES:
            os.environ.setdefault(name, "1")


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``pytest -n auto``: two workers per core. A third of the workers' time is waiting, not
    computing (``dimacq serve`` processes starting, simulated devices in wall time, the browser,
    jobs in a server's threads): with one worker per core the cores idle then."""
    return 2 * len(os.sched_getaffinity(0))


@pytest.hookimpl(tryfirst=True)  # before xdist's, which reads the xdist_group marks added here
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    wanted = set(config.getoption("--device"))
    for item in items:
        marker = item.get_closest_marker("device")
        if marker is None:
            continue
        kinds = set(marker.args) or {"any"}
        if not (wanted & kinds or ("any" in kinds and wanted)):
            item.add_marker(
                pytest.mark.skip(reason=f"needs real hardware: --device {'/'.join(sorted(kinds))}")
            )
    # the long tests first (stable order otherwise): under -n the workers start on them and the
    # short ones fill in behind, instead of one worker finishing a long test alone at the end
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
    for item in items:
        group = _shared_fixture_group(item)
        if group and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(group))


def _shared_fixture_group(item: pytest.Item) -> str:
    """The xdist group of a test that uses a module-scoped fixture (a live API server, a solved
    analysis): its module, and the server's database backend. ``--dist loadgroup`` (pyproject's
    addopts) sends a group to one worker, so the fixture is built once, not once per worker
    that happens to get one of its tests; the other tests are shared out one by one."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return ""
    shared = any(d.scope == "module" for defs in info.name2fixturedefs.values() for d in defs[-1:])
    if not shared:
        return ""
    callspec = getattr(item, "callspec", None)
    backend = callspec.params.get("api_database_url", "") if callspec is not None else ""
    return f"{item.nodeid.split('::', 1)[0]}:{backend}"


@pytest.fixture
def thread_leak_allowed() -> tuple[str, ...]:
    """Name prefixes of threads a test may leave running (none; a folder may override this)."""
    return ()


@pytest.fixture(autouse=True)
def no_thread_leaks(thread_leak_allowed: tuple[str, ...]) -> Iterator[None]:
    """Fail any test that leaves a thread running (given 2 s to end), the one leak check of the
    suite: every test runs under it; fixtures that must close their threads before a check of
    their own (:func:`_acq_support.no_leaks`) request it by name to run inside it."""
    before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + 2.0
    while True:
        leaked = [
            t
            for t in threading.enumerate()
            if t not in before and t.is_alive() and not t.name.startswith(thread_leak_allowed)
        ]
        if not leaked or time.monotonic() > deadline:
            break
        time.sleep(0.02)
    if leaked:
        pytest.fail(
            "test left threads running: " + ", ".join(t.name for t in leaked) + " — close the "
            "simulator, bus or device in the test (use a fixture with a finally)",
            pytrace=False,
        )


# -- database backends -----------------------------------------------------------------------------
@pytest.fixture(scope="session")
def pg_server() -> Iterator[object]:
    """One throwaway PostgreSQL server for the session (started on first use). Skipped with the
    reason where the binaries are absent; under ``CI=true`` or ``DIMACQ_TEST_POSTGRES=required``
    (set by ``.ci/run``) their absence fails instead."""
    import os

    from _pg_support import PgServer, pg_binaries_missing

    why = pg_binaries_missing()
    if why:
        if (
            os.environ.get("CI", "").lower() == "true"
            or os.environ.get("DIMACQ_TEST_POSTGRES") == "required"
        ):
            pytest.fail(f"PostgreSQL tests are required here but {why}", pytrace=False)
        pytest.skip(why)
    srv = PgServer()
    try:
        yield srv
    finally:
        srv.close()


@pytest.fixture(params=BACKENDS)
def database_url(request: pytest.FixtureRequest) -> Iterator[str]:
    """Each test using it runs on SQLite and on a fresh PostgreSQL database."""
    yield from database_url_for(request, request.param)
