"""Backend ``loadcell = "netft-udp"``: an ATI Net F/T's Raw Data Transfer over UDP.

The rig file's entry gives ``netft_host`` (its IP address) and ``netft_port`` (49152), the
sensor's RDT output and internal rates as its settings page shows them (``netft_rdt_rate_hz``,
``netft_ft_rate_hz``), and the alignment's phase budget (``netft_band_hz``,
``netft_max_phase_deg``, ``netft_latency_floor_s``, ``netft_time_base``, ``netft_fit_lo_hz``);
the sensor's counts per unit are read from
it (Read Calibration Info over TCP, port 49151) unless the entry states them (as for
``"netft-can"``). The driver streams buffered records and puts them on the DAQ's sample grid
through the host's clock, the residual delay fitted from the data by the acquisition
(:mod:`dimacq.drivers.netft.udp_driver`), refusing a run whose alignment costs more phase than
allowed.
"""

from __future__ import annotations

import socket

from dimacq.backends.base import DeviceContext
from dimacq.backends.netft_can import calibration_info
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.tcp_calibration import read_calibration_info
from dimacq.drivers.netft.udp_driver import NetFtUdp
from dimacq.errors import DeviceError, DeviceNotFoundError, DeviceTimeoutError, SetupError
from dimacq.io.rig_file import LoadCellEntry

__all__ = ["device_calibration", "open_loadcell", "open_rdt"]


def device_calibration(host: str, port: int, *, where: str) -> p.CalibrationInfo:
    """The sensor's counts per unit read from it (Read Calibration Info over TCP).

    Raises
    ------
    DeviceNotFoundError
        It cannot be reached or does not answer.
    """
    try:
        with socket.create_connection((host, port), timeout=2.0) as tcp:
            return read_calibration_info(tcp, where=where)
    except (OSError, DeviceTimeoutError, DeviceError) as err:
        raise DeviceNotFoundError(
            f"{where}: cannot read its calibration from {host}:{port} ({err}); check the "
            "address, or give netft_counts_per_force/_torque in the rig file"
        ) from err


def open_rdt(
    ctx: DeviceContext,
    entry: LoadCellEntry,
    host: str,
    port: int,
    *,
    where: str,
    tcp_port: int = p.TCP_PORT,
    time_scale: float = 1.0,
    latency_floor_s: float | None = None,
    timeout_s: float = 1.0,
) -> NetFtUdp:
    """The driver on a UDP socket connected to ``host:port`` (closed with ``ctx``), identified;
    its counts per unit read from the device (``tcp_port``) unless the rig file states them;
    ``timeout_s``: how long a read waits for the sensor's records, s.

    Raises
    ------
    DeviceNotFoundError
        No record came back, or the calibration could not be read.
    """
    if entry.netft_counts_per_force is None and entry.netft_counts_per_torque is None:
        cal = device_calibration(host, tcp_port, where=where)
    else:
        cal = calibration_info(entry, where)
    try:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.connect((host, port))
    except OSError as err:
        raise DeviceNotFoundError(f"{where}: cannot reach {host}:{port} ({err})") from err
    try:
        drv = NetFtUdp(
            sock,
            calibration=cal,
            serial_number=entry.node,
            label=f"Net F/T of load cell {entry.node}",
            rdt_rate_hz=entry.netft_rdt_rate_hz,
            ft_rate_hz=entry.netft_ft_rate_hz,
            time_scale=time_scale,
            band_hz=entry.netft_band_hz,
            max_phase_deg=entry.netft_max_phase_deg,
            latency_floor_s=(
                entry.netft_latency_floor_s if latency_floor_s is None else latency_floor_s
            ),
            time_base=entry.netft_time_base,
            fit_lo_hz=entry.netft_fit_lo_hz,
            timeout_s=timeout_s,
        )
        try:
            drv.identify()
        except DeviceTimeoutError as err:
            raise DeviceNotFoundError(f"{where}: {err}") from err
    except BaseException:
        sock.close()
        raise
    ctx.on_close(sock.close)
    ctx.on_close(drv.close)
    return drv


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> NetFtUdp:
    """The table entry ``loadcell = "netft-udp"``."""
    where = f"loadcell = 'netft-udp' (load cell {entry.node})"
    if not entry.netft_host:
        raise SetupError(
            f"load cell {entry.node}: {where} needs the Net F/T's IP address; give netft_host "
            "in its [[load_cells]] entry of the rig file"
        )
    return open_rdt(ctx, entry, entry.netft_host, entry.netft_port, where=where)
