"""python-can <-> tether bridge: open any python-can interface with echo filtering, and
convert frames between ``can.Message`` and :class:`msgs.can.CanFrame`.

``udp_multicast`` (the bus tests and the demo use here: this machine has no SocketCAN)
delivers every frame to every socket of the group, **including the sender's own**. A
CANopen master that read its own SDO requests back would take them for responses, so
:class:`EchoFilterBus` tags each frame it sends with a per-bus token in the ``channel``
field (which ``udp_multicast`` carries across) and drops received frames carrying its own
token. On interfaces that do not carry the channel, it drops a received frame equal to
one this bus sent in the last ``echo_window_s`` (a counted multiset, so a peer sending
the same bytes later is not swallowed).
"""
from __future__ import annotations

import collections
import logging
import os
import threading
import time
import uuid
from typing import Any, Callable

import can

from msgs.can import CanFrame

log = logging.getLogger(__name__)

#: Interfaces whose receive path returns our own frames.
ECHOING_INTERFACES = frozenset({"udp_multicast"})


class EchoFilterBus(can.BusABC):
    """Wrap a python-can bus: drop echoes of our own frames, tap sent frames.

    ``tx_listeners`` are called with every ``can.Message`` sent successfully (so a node
    can publish transmitted frames as well as received ones).
    """

    def __init__(self, inner: can.BusABC, *, tag_channel: bool, echo_window_s: float = 0.5) -> None:
        self._inner = inner
        self._tag = f"tether-{os.getpid()}-{uuid.uuid4().hex[:8]}" if tag_channel else None
        self._window_s = echo_window_s
        self._sent: dict[tuple[int, bytes], collections.deque[float]] = {}   # frame -> send times
        self._sends = 0
        self._lock = threading.Lock()
        self.tx_listeners: list[Callable[[can.Message], None]] = []
        self.echoes_dropped = 0
        self.recv_errors = 0
        self._closed = False
        super().__init__(channel=getattr(inner, "channel_info", "?"))
        self.channel_info = f"echo-filtered {getattr(inner, 'channel_info', inner)}"

    @property
    def inner(self) -> can.BusABC:
        return self._inner

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._tag is not None:
            msg = can.Message(timestamp=msg.timestamp or time.time(), arbitration_id=msg.arbitration_id,
                              is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                              is_error_frame=msg.is_error_frame, dlc=msg.dlc, data=msg.data,
                              is_fd=msg.is_fd, channel=self._tag, is_rx=False)
        else:
            key = (msg.arbitration_id, bytes(msg.data))
            now = time.monotonic()
            with self._lock:
                self._sent.setdefault(key, collections.deque()).append(now)
                self._sends += 1
                if self._sends % 1024 == 0:        # forget frames whose echo never came
                    for k in [k for k, q in self._sent.items() if now - q[-1] > self._window_s]:
                        del self._sent[k]
        self._inner.send(msg, timeout)
        for listener in self.tx_listeners:
            try:
                listener(msg)
            except Exception:  # noqa: BLE001 - a tap must never break the bus
                log.exception("CAN tx listener failed")

    def _is_echo(self, msg: can.Message) -> bool:
        if self._tag is not None:
            return msg.channel == self._tag
        key = (msg.arbitration_id, bytes(msg.data))
        now = time.monotonic()
        with self._lock:
            times = self._sent.get(key)
            while times and now - times[0] > self._window_s:
                times.popleft()
            if times:
                times.popleft()
                return True
        return False

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                msg = self._inner.recv(remaining)
            except can.CanOperationError as exc:
                # A malformed datagram on the multicast group: count it, keep the bus alive.
                self.recv_errors += 1
                log.warning("dropped an undecodable CAN frame (%s); %d so far", exc, self.recv_errors)
                msg = None
                if self._closed:
                    return None, False
            if msg is None:
                if deadline is not None and time.monotonic() >= deadline:
                    return None, False
                continue
            if self._is_echo(msg):
                self.echoes_dropped += 1
                continue
            if self._tag is not None:
                msg.channel = None
            return msg, False

    def fileno(self) -> int:
        return self._inner.fileno()

    def shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        super().shutdown()
        self._inner.shutdown()


def open_bus(interface: str, channel: str, bitrate: int = 0, **kwargs: Any) -> EchoFilterBus:
    """Open a python-can bus by interface name (``socketcan``, ``pcan``, ``kvaser``,
    ``slcan``, ``virtual``, ``udp_multicast``, ...), wrapped in :class:`EchoFilterBus`.

    ``bitrate`` 0 leaves the interface's own setting (socketcan takes it from ``ip link``).
    Raises ``can.CanError`` (with python-can's message) when the interface cannot open.
    """
    if interface == "udp_multicast":
        kwargs.setdefault("fd", False)
    elif bitrate and interface not in ("virtual",):
        kwargs["bitrate"] = bitrate
    inner = can.Bus(interface=interface, channel=channel, **kwargs)
    return EchoFilterBus(inner, tag_channel=interface in ECHOING_INTERFACES)


def frame_from_message(msg: can.Message, *, stamp_ns: int = 0, channel: str = "", is_rx: bool = True) -> CanFrame:
    """``can.Message`` -> :class:`CanFrame` (``stamp_ns`` defaults to the message timestamp)."""
    if not stamp_ns and msg.timestamp:
        stamp_ns = int(round(msg.timestamp * 1e9))
    return CanFrame(stamp_ns=stamp_ns, arbitration_id=msg.arbitration_id, data=bytes(msg.data or b""),
                    is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                    is_error_frame=msg.is_error_frame, is_rx=is_rx,
                    channel=channel or (str(msg.channel) if msg.channel is not None else ""),
                    is_fd=bool(msg.is_fd), dlc=int(msg.dlc))


def message_from_frame(frame: CanFrame) -> can.Message:
    """:class:`CanFrame` -> ``can.Message`` (timestamp in seconds from ``stamp_ns``)."""
    dlc = frame.dlc if frame.is_remote_frame else len(frame.data)
    return can.Message(timestamp=frame.stamp_ns * 1e-9, arbitration_id=frame.arbitration_id,
                       is_extended_id=frame.is_extended_id, is_remote_frame=frame.is_remote_frame,
                       is_error_frame=frame.is_error_frame, data=None if frame.is_remote_frame else frame.data,
                       dlc=dlc, is_fd=frame.is_fd, is_rx=frame.is_rx, channel=frame.channel or None)
