"""Backend ``daq = "uldaq"``: MCC devices through MCC's official ``uldaq`` package.

Optional: ``pip install "dimacq[mcc]"`` and MCC's library ``libuldaq`` (built from
``github.com/mccdaq/uldaq``: ``./configure && make && sudo make install``), which loads each
device's firmware and FPGA itself. For MCC's IEPE DAQs (DT9837A/B/C: IEPE excitation and AC
coupling per channel) and any other uldaq device with analogue inputs. The rig file's
``[daq] units`` names the device by its serial number (uldaq's ``unique_id``); ``[]`` takes the
first found. The task is :class:`~dimacq.drivers.mcc.uldaq_task.UldaqTask`. No simulated twin:
the mapping to uldaq's enums is tested without the library, the rest needs one.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.errors import DeviceNotFoundError, SetupError

__all__ = ["import_uldaq", "open_daq"]

_WHERE = "daq = 'uldaq'"


def import_uldaq() -> Any:
    """The ``uldaq`` package, its library loaded.

    Raises
    ------
    SetupError
        The package is not installed.
    DeviceNotFoundError
        ``libuldaq`` (MCC's C library the package loads) is not installed.
    """
    try:
        import uldaq
    except ImportError as err:
        raise SetupError(
            f"{_WHERE}: the Python package uldaq is not installed; pip install 'dimacq[mcc]' "
            "(and libuldaq from github.com/mccdaq/uldaq), or choose another daq (DIMACQ_DAQ)"
        ) from err
    except OSError as err:
        raise DeviceNotFoundError(
            f"{_WHERE}: MCC's library libuldaq is not installed ({err}); build and install it "
            "from github.com/mccdaq/uldaq (./configure && make && sudo make install), or choose "
            "another daq (DIMACQ_DAQ)"
        ) from err
    return uldaq


def open_daq(ctx: DeviceContext) -> Any:
    """The table entry ``"uldaq"``: a :class:`~dimacq.drivers.mcc.uldaq_task.UldaqTask`."""
    from dimacq.drivers.mcc.uldaq_task import UldaqTask

    ul = import_uldaq()
    rig = ctx.rig_file
    found = list(ul.get_daq_device_inventory(ul.InterfaceType.ANY))
    by_serial = {str(d.unique_id): d for d in found}
    wanted = list(rig.daq.units)[:1] or list(by_serial)[:1]
    if not wanted or wanted[0] not in by_serial:
        have = ", ".join(f"{d.product_name} {d.unique_id}" for d in found) or "none"
        raise DeviceNotFoundError(
            f"{_WHERE}: device {', '.join(wanted) or '(any)'} not found (uldaq sees {have}); "
            f"check the cable and the udev rules libuldaq installs, or fix [daq] units in "
            f"{rig.path}"
        )
    device = ul.DaqDevice(by_serial[wanted[0]])
    device.connect()
    task = UldaqTask(ul, device, "impact")
    ctx.on_close(task.close)
    return task
