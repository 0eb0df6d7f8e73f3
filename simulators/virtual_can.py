"""The simulators' end of python-can's ``virtual`` bus: the same wire, a cheaper send.

A simulated amplifier sends one CAN frame per sample (the CANopen one six), 8 192 a second at
the soak's 4x time-lapse of 2 048 S/s. python-can's :meth:`VirtualBus.send
<can.interfaces.virtual.VirtualBus.send>` hands each receiver a ``copy.deepcopy`` of the message
(about 28 µs a frame, most of a simulator thread's CPU, held under the GIL the service's event
loop needs to answer). :class:`SimVirtualBus` hands each receiver its own
:class:`can.Message` built field by field instead (about 5 µs): what the drivers receive is the
same — a fresh message per receiver with the send time, the channel and ``is_rx`` set — and the
driver ends stay plain ``can.Bus(interface="virtual", ...)``.
"""

from __future__ import annotations

import queue
import time
from typing import Any

import can
from can.interfaces.virtual import VirtualBus

__all__ = ["SimVirtualBus"]


class SimVirtualBus(VirtualBus):
    """``can.Bus(interface="virtual", channel=...)`` with a send that copies a frame's fields
    (not ``deepcopy``); the rest is python-can's.

    ``accept_ids``: the identifiers this bus receives (a CAN controller's hardware acceptance
    filter: a simulated node that needs only its SDO and NMT frames is not handed the stream's
    thousands of frames a second); None: all.
    """

    def __init__(self, *args: Any, accept_ids: frozenset[int] | None = None, **kw: Any) -> None:
        super().__init__(*args, **kw)
        if accept_ids is not None:  # on the receive queue, where every sender looks
            self.queue.accept_ids = frozenset(accept_ids)  # type: ignore[attr-defined]

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        data = bytes(msg.data)
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            accept = getattr(bus_queue, "accept_ids", None)
            if accept is not None and msg.arbitration_id not in accept:
                continue
            copy = can.Message(
                timestamp=timestamp,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                channel=self.channel_id,
                dlc=msg.dlc,
                data=data,
                is_fd=msg.is_fd,
                is_rx=bus_queue is not self.queue,
                bitrate_switch=msg.bitrate_switch,
                error_state_indicator=msg.error_state_indicator,
            )
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")
