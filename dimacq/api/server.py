"""Run the app with uvicorn: in the foreground (``dimacq serve``) or on a background thread
on a loopback port (``dimacq demo``, tests, benchmarks)."""

from __future__ import annotations

import socket
import sys
import threading
import time
from types import TracebackType

import uvicorn
from fastapi import FastAPI

from dimacq.errors import DeviceError

__all__ = ["BackgroundServer", "free_port", "serve"]


def free_port(host: str = "127.0.0.1") -> int:
    """A free TCP port on ``host`` (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


#: GIL switch interval of the service process, s. Acquisition threads are CPU-bound (decoding,
#: checks); with Python's default 5 ms the event loop can wait that long for the GIL at every
#: step of a request, which is what status pollers would see as latency.
SWITCH_INTERVAL_S = 0.0005


def serve(app: FastAPI, host: str, port: int, log_level: str = "info") -> None:
    """Serve in the foreground until interrupted (this process is the service)."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    uvicorn.run(app, host=host, port=port, log_level=log_level, access_log=False)


class BackgroundServer:
    """uvicorn on a thread; ``with BackgroundServer(app) as srv: httpx.get(srv.url + ...)``."""

    def __init__(self, app: FastAPI, host: str = "127.0.0.1", port: int | None = None) -> None:
        self.host = host
        self.port = port or free_port(host)
        config = uvicorn.Config(
            app, host=host, port=self.port, log_level="warning", access_log=False, lifespan="on"
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(
            target=self.server.run, name=f"dimacq-uvicorn-{self.port}", daemon=True
        )

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def start(self, timeout_s: float = 30.0) -> None:
        self.thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                self.stop()
                raise DeviceError(f"the API server on {self.url} did not start")
            time.sleep(0.01)

    def stop(self, timeout_s: float = 30.0) -> None:
        self.server.should_exit = True
        if self.thread.is_alive():
            self.thread.join(timeout_s)

    def __enter__(self) -> BackgroundServer:
        self.start()
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
