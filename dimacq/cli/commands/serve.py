"""``dimacq serve [--host H] [--port P]``: the lab service (REST API) on the simulated lab by default.

Configuration: ``config/dimacq.toml``, overridden by ``DIMACQ_*`` variables, overridden by these
arguments. Binds 127.0.0.1 unless told otherwise. State-changing calls need the token, printed once
at start in the lab page's address (kept in ``<data_dir>/token``, mode 0600, unless
``DIMACQ_TOKEN`` is set).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from dimacq.cli.progress import plain


def register(sub: Any) -> None:
    p = sub.add_parser(
        "serve",
        help="serve the REST API (simulated lab by default)",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--host", default=None, help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="TCP port (default 8765)")
    p.add_argument("--data-dir", type=Path, default=None, help="where the database and arrays live")
    p.add_argument(
        "--log-level", default="info", choices=("critical", "error", "warning", "info", "debug")
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from dimacq.api import create_app
    from dimacq.api.guards import is_loopback, is_wildcard
    from dimacq.api.server import bind_socket, serve
    from dimacq.config import load_settings

    settings = load_settings(host=args.host, port=args.port, data_dir=args.data_dir)
    # the port first: nothing (token included) is printed for a service that cannot start
    sock = bind_socket(settings.host, settings.port)

    def ready() -> None:
        # printed once the lab is open and the page's first reads answered (create_app's
        # on_ready): following this address right away gets the page at its usual speed
        print(
            f"lab page: http://{settings.host}:{settings.port}/#token={app.state.token}  "
            "(the token stays in the URL fragment, never sent to the server)",
            flush=True,
        )

    try:
        app = create_app(settings, on_ready=ready)
    except BaseException:
        sock.close()
        raise
    token_src = "DIMACQ_TOKEN / config" if settings.token else str(settings.data_dir / "token")
    if not is_loopback(settings.host):
        checked = (
            "the Host header is not checked (set allowed_hosts to the names clients use)"
            if is_wildcard(settings.host) and not settings.allowed_hosts
            else "the Host header must name this service"
        )
        print(
            f"warning: bound to {settings.host}, a non-loopback address: anyone on the network "
            f"can reach the service; every /api call, reads included, needs the token; {checked}",
            file=sys.stderr,
            flush=True,
        )
    print(
        f"dimacq serving http://{settings.host}:{settings.port}  (docs: /docs, spec: /openapi.json)"
    )
    from dimacq.persistence.db import masked_url

    print(
        f"stand: {settings.stand_name}  data: {settings.data_dir}  "
        f"database: {masked_url(settings.db_url)}"
    )
    reads = "every call" if not is_loopback(settings.host) else "state-changing calls"
    # the token itself is printed once, in the lab page's address (it ends up in logs and
    # terminal scroll-back; here only where it is kept)
    print(f"token for {reads}: in {token_src}")
    print("opening the lab (database, devices); the lab page's address follows", flush=True)
    serve(app, settings.host, settings.port, log_level=args.log_level, sock=sock)
    return 0
