"""What the simulated USB devices share: a pyusb backend (``usb.backend.IBackend``) for a device
with one configuration, one vendor-specific interface and one bulk IN endpoint — the shape of the
project's DAQ (:mod:`dimacq.simulators.daq.backend`) and of the USB-1808X
(:mod:`dimacq.simulators.mcc.backend`). Each device adds its enumeration, handles, control
requests and bulk reads; the descriptors and the no-op configuration calls are here once.
"""

from __future__ import annotations

import array
import errno
import logging
from typing import Any

import usb.backend
import usb.core

__all__ = ["Desc", "OneBulkInBackend"]

log = logging.getLogger(__name__)


class Desc:
    """A USB descriptor as pyusb reads it: an object with the descriptor's fields."""

    def __init__(self, **fields: Any) -> None:
        self.__dict__.update(fields)


class OneBulkInBackend(usb.backend.IBackend):
    """Descriptors (configuration 1, interface 0 of class 0xFF, bulk IN ``data_endpoint`` of
    512-byte packets) and the configuration calls a pyusb device makes, for a subclass to
    complete with ``enumerate_devices``, ``open_device``, ``close_device``, ``ctrl_transfer`` and
    ``bulk_read``."""

    #: the bulk IN endpoint's address (bit 7 set)
    data_endpoint: int
    #: how the device is named in the log
    device_name = "simulated USB device"

    def get_parent(self, dev: Any) -> None:
        return None

    def get_device_descriptor(self, dev: Any) -> Any:
        return dev

    def get_configuration_descriptor(self, dev: Any, config: int) -> Any:
        return Desc(
            bLength=9,
            bDescriptorType=2,
            wTotalLength=25,
            bNumInterfaces=1,
            bConfigurationValue=1,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=250,
            extra_descriptors=[],
        )

    def get_interface_descriptor(self, dev: Any, intf: int, alt: int, config: int) -> Any:
        return Desc(
            bLength=9,
            bDescriptorType=4,
            bInterfaceNumber=0,
            bAlternateSetting=0,
            bNumEndpoints=1,
            bInterfaceClass=0xFF,
            bInterfaceSubClass=0,
            bInterfaceProtocol=0,
            iInterface=0,
            extra_descriptors=[],
        )

    def get_endpoint_descriptor(self, dev: Any, ep: int, intf: int, alt: int, config: int) -> Any:
        return Desc(
            bLength=7,
            bDescriptorType=5,
            bEndpointAddress=self.data_endpoint,
            bmAttributes=2,
            wMaxPacketSize=512,
            bInterval=0,
            bRefresh=0,
            bSynchAddress=0,
            extra_descriptors=[],
        )

    def set_configuration(self, dev_handle: Any, config_value: int) -> None:
        return None

    def get_configuration(self, dev_handle: Any) -> int:
        return 1

    def claim_interface(self, dev_handle: Any, intf: int) -> None:
        return None

    def release_interface(self, dev_handle: Any, intf: int) -> None:
        return None

    def clear_halt(self, dev_handle: Any, ep: int) -> None:
        return None

    def _stall(self, why: str) -> usb.core.USBError:
        """A control request the device refuses: the endpoint stalls (EPIPE), as on the bus."""
        log.info("%s stalls a control request: %s", self.device_name, why)
        return usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)

    @staticmethod
    def _answer(buf: array.array[int], payload: bytes) -> int:
        """An IN control transfer's data stage: ``payload`` into ``buf``; bytes written."""
        n = min(len(buf), len(payload))
        buf[:n] = array.array("B", payload[:n])
        return n
