"""A simulated Net F/T's Ethernet side beside its CAN or RDT interface: its web server's
configuration page ``netftapi2.xml`` (HTTP) and Read Calibration Info (TCP), on loopback.

The page is the sensor's own (what ATI's demo reads from it: ``setcfgsel`` the active
configuration, then per configuration ``cfgnam``, ``cfgcpf``, ``cfgcpt``, ``scfgfu``,
``scfgtu``, ``comrdtrate``, ``cfgmr``; ``?index=N`` selects configuration N, none or a bad one
gives configuration 0). Sixteen configurations, the active one holding its calibration, the
others a factory default of their own. Read Calibration Info is answered only to a 20-byte
command whose first byte is 1 (anything else: the connection is closed without an answer).
"""

from __future__ import annotations

import logging
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlparse

from dimacq.drivers.netft import protocol as p

__all__ = ["NetFtEthernetSim"]

log = logging.getLogger(__name__)

#: how the sensor prints its unit codes on its pages
_FORCE_NAMES = {1: "lbf", 2: "N", 3: "klbf", 4: "kN", 5: "kgf", 6: "gf"}
_TORQUE_NAMES = {1: "lbf-in", 2: "lbf-ft", 3: "N-m", 4: "N-mm", 5: "kgf-cm", 6: "kN-m"}
_N_CONFIGS = 16


class NetFtEthernetSim:
    """Use as a context manager; :attr:`http_address` and :attr:`tcp_address` are where it
    listens (loopback, free ports)."""

    def __init__(
        self,
        calibration: p.CalibrationInfo,
        *,
        rdt_rate_hz: float = 1000.0,
        active: int = 2,
        name: str = "dimacq sim",
        host: str = "127.0.0.1",
    ) -> None:
        self.calibration = calibration
        self.rdt_rate_hz = rdt_rate_hz
        self.active = active
        self.name = name
        self.requests: list[str] = []
        sim = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                url = urlparse(self.path)
                sim.requests.append(self.path)
                if url.path != "/netftapi2.xml":
                    self.send_error(404)
                    return
                q = parse_qs(url.query).get("index", ["0"])[0]
                idx = int(q) if q.isdigit() and int(q) < _N_CONFIGS else 0
                body = sim.page(idx).encode()
                self.send_response(200)
                self.send_header("Content-Type", "text/xml")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.http = ThreadingHTTPServer((host, 0), Handler)
        self.http_address: tuple[str, int] = self.http.server_address[:2]  # type: ignore[assignment]
        self.tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.tcp.bind((host, 0))
        self.tcp.listen(4)
        self.tcp.settimeout(0.05)
        self.tcp_address: tuple[str, int] = self.tcp.getsockname()[:2]
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self.http.serve_forever, kwargs={"poll_interval": 0.05}),
            threading.Thread(target=self._serve_tcp),
        ]
        for t in self._threads:
            t.start()

    def page(self, index: int) -> str:
        """Configuration ``index``'s page, as the sensor writes it."""
        cal = self.calibration if index == self.active else p.CalibrationInfo(1, 1, 1, 1)
        name = self.name if index == self.active else f"config {index}"
        fields = {
            "setcfgsel": self.active,
            "cfgcalsel": 0,
            "cfgnam": name,
            "cfgcpf": cal.counts_per_force,
            "cfgcpt": cal.counts_per_torque,
            "scfgfu": _FORCE_NAMES[cal.force_unit],
            "scfgtu": _TORQUE_NAMES[cal.torque_unit],
            "comrdtrate": int(self.rdt_rate_hz),
            "cfgmr": "500;500;1000;30;30;30",
            "runstat": "0x00000000",
        }
        inner = "".join(f"<{k}>{v}</{k}>" for k, v in fields.items())
        return f'<?xml version="1.0" encoding="utf-8"?>\r\n<netft>{inner}</netft>'

    def _serve_tcp(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.tcp.accept()
            except (TimeoutError, OSError):
                continue
            with conn:
                conn.settimeout(1.0)
                try:
                    cmd = b""
                    while len(cmd) < 20:
                        chunk = conn.recv(20 - len(cmd))
                        if not chunk:
                            break
                        cmd += chunk
                    if len(cmd) == 20 and cmd[0] == 1:
                        conn.sendall(self.calibration.encode())
                except OSError:
                    log.debug("Net F/T Ethernet simulator: TCP client went away")

    def close(self) -> None:
        self._stop.set()
        self.http.shutdown()
        self.http.server_close()
        for t in self._threads:
            t.join(timeout=5.0)
        self.tcp.close()

    def __enter__(self) -> NetFtEthernetSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
