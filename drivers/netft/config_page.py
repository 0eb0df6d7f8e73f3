"""The Net F/T's configuration page ``netftapi2.xml`` over HTTP: its counts per unit, units and
RDT rate, read from the sensor.

ATI's own Net F/T demo (``NetFTSampleGUI.readConfigurationInfo``, Java, ATI Industrial
Automation) reads ``http://<address>/netftapi2.xml?index=0`` for the active configuration's
number (``setcfgsel``), then ``netftapi2.xml?index=<that>`` for its name (``cfgnam``), counts per
force (``cfgcpf``) and per torque (``cfgcpt``), force and torque unit (``scfgfu``, ``scfgtu``:
"N", "N-m", "lbf", "lbf-in" ...), RDT output rate (``comrdtrate``, Hz) and maximum ratings
(``cfgmr``, six values separated by ';'). This module does the same with :mod:`http.client`
(the connection is made by the caller's host and port; loopback in the tests).

**Not on the page, so not read:** the sensor's internal sample rate (7000 S/s by the manual's
specification, the rig file's ``netft_ft_rate_hz``) and its low-pass filter setting: both stay
as the rig file states them and are named unverified where they are used.
"""

from __future__ import annotations

import http.client
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from dimacq.drivers.netft import protocol as p
from dimacq.errors import DeviceError, DeviceTimeoutError, ProtocolError

__all__ = ["CONFIG_PAGE", "HTTP_PORT", "NetFtConfig", "parse_config_page", "read_config_page"]

#: its web server's port and configuration page
HTTP_PORT = 80
CONFIG_PAGE = "/netftapi2.xml"


@dataclass(frozen=True)
class NetFtConfig:
    """What the page says of the active configuration.

    Attributes
    ----------
    index : int
        The active configuration (``setcfgsel``).
    name : str
    counts_per_force, counts_per_torque : int
    force_unit, torque_unit : str
        As the page writes them ("N", "N-m", ...).
    rdt_rate_hz : float
        Its RDT output rate.
    """

    index: int
    name: str
    counts_per_force: int
    counts_per_torque: int
    force_unit: str
    torque_unit: str
    rdt_rate_hz: float

    def calibration(self) -> p.CalibrationInfo:
        """As :class:`~dimacq.drivers.netft.protocol.CalibrationInfo` (unit names → codes).

        Raises
        ------
        ProtocolError
            A unit the codec does not know.
        """
        fu = {name: code for code, (name, _) in p.FORCE_UNITS.items()}.get(self.force_unit)
        tu = {name: code for code, (name, _) in p.TORQUE_UNITS.items()}.get(self.torque_unit)
        if fu is None or tu is None:
            raise ProtocolError(
                f"Net F/T configuration page: units {self.force_unit!r}/{self.torque_unit!r} "
                "are not ones this driver converts; set the sensor's units to N and N-m"
            )
        return p.CalibrationInfo(fu, tu, self.counts_per_force, self.counts_per_torque)


def _text(root: ET.Element, tag: str, where: str) -> str:
    v = root.findtext(f".//{tag}")
    if v is None:
        raise ProtocolError(f"{where}: netftapi2.xml has no <{tag}>")
    return v.strip()


def parse_config_page(xml: bytes, *, where: str = "Net F/T") -> NetFtConfig:
    """The page's fields (see the module docstring).

    Raises
    ------
    ProtocolError
        Not XML, or a field missing or not a number.
    """
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as err:
        raise ProtocolError(f"{where}: netftapi2.xml is not XML ({err})") from err
    try:
        return NetFtConfig(
            index=int(_text(root, "setcfgsel", where)),
            name=root.findtext(".//cfgnam", "").strip(),
            counts_per_force=int(float(_text(root, "cfgcpf", where))),
            counts_per_torque=int(float(_text(root, "cfgcpt", where))),
            force_unit=_text(root, "scfgfu", where),
            torque_unit=_text(root, "scfgtu", where),
            rdt_rate_hz=float(_text(root, "comrdtrate", where)),
        )
    except ValueError as err:
        raise ProtocolError(f"{where}: netftapi2.xml field not a number ({err})") from err


def _get(conn: http.client.HTTPConnection, path: str, where: str) -> bytes:
    conn.request("GET", path)
    r = conn.getresponse()
    body = r.read()
    if r.status != 200:
        raise DeviceError(f"{where}: GET {path} answered HTTP {r.status}")
    return body


def read_config_page(
    host: str, port: int = HTTP_PORT, *, timeout_s: float = 2.0, where: str = "Net F/T"
) -> NetFtConfig:
    """The active configuration: ``netftapi2.xml?index=0`` for its number, then its page.

    Raises
    ------
    DeviceTimeoutError, DeviceError, ProtocolError
    """
    conn = http.client.HTTPConnection(host, port, timeout=timeout_s)
    try:
        first = parse_config_page(_get(conn, f"{CONFIG_PAGE}?index=0", where), where=where)
        page = _get(conn, f"{CONFIG_PAGE}?index={first.index}", where)
        return parse_config_page(page, where=where)
    except TimeoutError as err:
        raise DeviceTimeoutError(f"{where}: no answer from http://{host}:{port} ({err})") from err
    except OSError as err:
        raise DeviceError(f"{where}: cannot read http://{host}:{port}{CONFIG_PAGE}: {err}") from err
    finally:
        conn.close()
