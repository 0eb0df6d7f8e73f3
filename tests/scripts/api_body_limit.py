"""On demand: a 300 MB JSON body against the service (issue 14: it used to be parsed, 1.2 GB of
memory). Prints the answer, the time to it and the growth of the server process's peak RSS, for a
body with Content-Length and for a chunked one.

    python tests/scripts/api_body_limit.py [--mb 300]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.config import load_settings

TOKEN = "body-limit-script"


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--mb", type=int, default=300, help="body size, MB")
    args = ap.parse_args()
    size = args.mb * 1_000_000
    chunk = b" " * 1_000_000
    with tempfile.TemporaryDirectory() as tmp:
        settings = load_settings(
            data_dir=Path(tmp), token=TOKEN, digitizer_url="simdigitizer://bodylimit?seed=0"
        )
        app = create_app(settings)
        with (
            BackgroundServer(app) as srv,
            httpx.Client(
                base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=120
            ) as c,
        ):
            print(f"max_body_bytes = {settings.max_body_bytes}; body {args.mb} MB")
            for label, chunked in (("Content-Length", False), ("chunked", True)):

                def body() -> Iterator[bytes]:
                    for _ in range(size // len(chunk)):
                        yield chunk

                headers = {"content-type": "application/json"}
                if not chunked:
                    headers["content-length"] = str(size)
                rss0 = _peak_rss_mb()
                t0 = time.perf_counter()
                try:
                    r = c.post("/api/setups", content=body(), headers=headers)
                    answer = f"{r.status_code} {r.json()['detail'][:70]}"
                except httpx.HTTPError as err:  # the server closed after answering early
                    answer = f"connection closed after the answer ({type(err).__name__})"
                dt = time.perf_counter() - t0
                grew = _peak_rss_mb() - rss0
                print(f"{label:15s} → {answer}  in {dt:.2f} s, peak RSS +{grew:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
