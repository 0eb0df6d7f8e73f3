"""The simulators' end of python-can's ``virtual`` bus: the same wire, a cheaper send.

A simulated amplifier sends one CAN frame per sample (the CANopen one six), 8 192 a second at
the soak's 4x time-lapse of 2 048 S/s. python-can's :meth:`VirtualBus.send
<can.interfaces.virtual.VirtualBus.send>` hands each receiver a ``copy.deepcopy`` of the message
(about 28 µs a frame, most of a simulator thread's CPU, held under the GIL the service's event
loop needs to answer). :class:`SimVirtualBus` hands each receiver its own
:class:`can.Message` built field by field instead (about 5 µs): what the drivers receive is the
same — a fresh message per receiver with the send time, the channel and ``is_rx`` set — and the
driver ends stay plain ``can.Bus(interface="virtual", ...)``.

At a time-lapse the frames come in bursts (an amplifier sends the pulses of the last few ms at
once, :data:`~dimacq.simulators.loadcell.pulses.BURST_S`): :meth:`SimVirtualBus.send_frames`
hands a whole burst to each receiver under one lock of its queue (``queue.Queue``'s own
``mutex``, one wake-up of the reader), in order, each frame still its own message with the
burst's send time. Per frame that is the message built and a deque append, about 1 µs, against
about 15 µs through :meth:`send` (a lock, a notify and often a thread switch per frame): at 40x
real time one amplifier sends 82 000 frames a second.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Iterable, Sequence
from typing import Any

import can
from can.interfaces.virtual import VirtualBus

__all__ = ["RX_BACKLOG_FRAMES", "SimVirtualBus"]

#: frames waiting in a receiver's queue past which a simulator sends nothing more (its
#: clock slips, an adaptive DAQ clock waits for it): on a host whose receive thread got too
#: little CPU, the reply to the host's next request would otherwise wait behind seconds of
#: frames (an SDO answer behind 50 000 TPDOs on a loaded machine). Tens of ms of a receive
#: thread's work; an idle host keeps its queue under a few hundred frames.
RX_BACKLOG_FRAMES = 2048

_new = object.__new__
#: the fields of a python-can message this module sets (all of them, checked at import)
_FIELDS = {
    "timestamp",
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "channel",
    "dlc",
    "data",
    "is_fd",
    "is_rx",
    "bitrate_switch",
    "error_state_indicator",
}
_SLOTS_KNOWN = set(getattr(can.Message, "__slots__", ())) - {"__weakref__"} == _FIELDS


def _message(
    timestamp: float, aid: int, channel: Any, data: bytes | bytearray, fd: bool, is_rx: bool
) -> can.Message:
    """A received data frame (11-bit id), as ``can.Message(...)`` makes it but with its fields
    set directly (0.5 µs, not 1.4 µs: the keyword handling of ``__init__`` is most of a
    frame's cost at a time-lapse); through ``__init__`` if python-can's fields differ."""
    if not _SLOTS_KNOWN:  # pragma: no cover - another python-can release
        return can.Message(
            timestamp=timestamp,
            arbitration_id=aid,
            is_extended_id=False,
            channel=channel,
            data=bytearray(data),
            is_fd=fd,
            is_rx=is_rx,
        )
    m: can.Message = _new(can.Message)
    m.timestamp = timestamp
    m.arbitration_id = aid
    m.is_extended_id = False
    m.is_remote_frame = False
    m.is_error_frame = False
    m.channel = channel
    m.data = bytearray(data)
    m.dlc = len(m.data)
    m.is_fd = fd
    m.is_rx = is_rx
    m.bitrate_switch = False
    m.error_state_indicator = False
    return m


class SimVirtualBus(VirtualBus):
    """``can.Bus(interface="virtual", channel=...)`` with a send that copies a frame's fields
    (not ``deepcopy``); the rest is python-can's.

    ``accept_ids``: the simulated node's hardware acceptance filter (a CAN controller's mask
    registers): frames sent by simulators through this class reach its receive queue only with
    one of these identifiers (None: every frame). Without it, each of the X-38's three
    amplifier simulators had to take and drop the other two's data frames one by one (12 000 a
    second at 2x real time) before it saw a command: a STOP waited behind seconds of them.
    """

    def __init__(self, *args: Any, accept_ids: Iterable[int] | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if accept_ids is not None:
            # on the queue, where the senders of the channel see it
            self.queue.dimacq_accept = frozenset(accept_ids)  # type: ignore[attr-defined]

    def receivers_backlog(self, arbitration_id: int | None = None) -> int:
        """Frames waiting in the fullest receive queue among the other buses of the channel (those
        whose acceptance filter lets ``arbitration_id`` through; None: all of them).

        A simulator at a time-lapse sends faster than any real bus carries frames; when the
        host's receive thread falls that far behind, a reply it sends next waits behind the
        whole backlog. The simulators look here and wait (their clocks slip) rather than pile
        more frames in front of the host's next answer."""
        most = 0
        for bus_queue in self.channel:
            if bus_queue is self.queue:
                continue
            accept = getattr(bus_queue, "dimacq_accept", None)
            if accept is not None and arbitration_id is not None and arbitration_id not in accept:
                continue
            most = max(most, bus_queue.qsize())
        return most

    def receivers_behind(self, arbitration_id: int | None = None) -> bool:
        """More than :data:`RX_BACKLOG_FRAMES` frames wait in a receiver's queue
        (:meth:`receivers_backlog`): a simulator sends nothing more until it has taken them."""
        return self.receivers_backlog(arbitration_id) > RX_BACKLOG_FRAMES

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        data = bytes(msg.data)
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            accept = getattr(bus_queue, "dimacq_accept", None)
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

    def send_frames(self, frames: Sequence[tuple[int, bytes | bytearray, bool]]) -> None:
        """Send ``(arbitration_id, data, is_fd)`` frames in order, as one burst (11-bit ids).

        Each receiver gets its own :class:`can.Message` per frame (send time, channel,
        ``is_rx``), as :meth:`send` gives it, appended to its queue under the queue's lock with
        one notify. A receiver with a bounded queue (``rx_queue_size``) too full for the burst
        gets the frames one by one through :meth:`send`'s path (and the same error when full).
        """
        self._check_if_open()
        if not frames:
            return
        timestamp = time.time()
        channel = self.channel_id
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            is_rx = bus_queue is not self.queue
            accept = getattr(bus_queue, "dimacq_accept", None)
            msgs = [
                _message(timestamp, aid, channel, data, fd, is_rx)
                for aid, data, fd in frames
                if accept is None or aid in accept
            ]
            if not msgs:
                continue
            with bus_queue.mutex:
                room = bus_queue.maxsize <= 0 or bus_queue.maxsize - len(bus_queue.queue) >= len(
                    msgs
                )
                if room:
                    bus_queue.queue.extend(msgs)
                    bus_queue.unfinished_tasks += len(msgs)
                    bus_queue.not_empty.notify()
            if not room:
                for m in msgs:
                    try:
                        bus_queue.put(m, block=False)
                    except queue.Full as err:
                        raise can.CanOperationError(
                            "Could not send message to one or more recipients"
                        ) from err
