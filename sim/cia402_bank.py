"""Simulated drives on a bus: in real time on any python-can bus, or in lockstep on a
synchronous in-process bus driven by a virtual clock.

:class:`SimDriveBank` serves several :class:`sim.cia402_device.SimDrive` on a python-can
bus from a thread (``virtual``, ``udp_multicast``, ...). :class:`SyncCanHub` is a CAN bus
in one process whose :class:`SyncCanBus` endpoints deliver every frame *inside*
``send`` at the hub's virtual time, so a CANopen master, the drives and everything around
them run deterministically and faster than real time; :class:`LockstepDriveBank` serves
drives on such an endpoint, advanced by :meth:`SyncCanHub.advance`.
"""
from __future__ import annotations

import threading
import time
from typing import Callable

import can

from sim.cia402_device import Frame, SimDrive


class SimDriveBank:
    """Several :class:`SimDrive` on one python-can bus, served by a thread (or by :meth:`poll`).

    Hold :attr:`lock` while touching a drive from another thread (fault injection).
    """

    def __init__(self, bus: can.BusABC, drives: dict[str, SimDrive], *, step_s: float = 0.001) -> None:
        self.bus, self.drives, self.step_s = bus, drives, step_s
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_step = 0.0
        self.send_errors = 0

    def _send(self, frames: list[Frame]) -> None:
        for arb, data in frames:
            try:
                self.bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
            except can.CanError:
                self.send_errors += 1

    def poll(self, duration_s: float) -> None:
        """Serve the bus for ``duration_s`` seconds (frames answered as they come).

        Frames already waiting are handled before the motors are advanced: after this thread
        was held up, the SYNC frames that did arrive count before any SYNC watchdog looks.
        """
        end = time.monotonic() + duration_s
        while True:
            now = time.monotonic()
            wait = 0.0 if now >= self._next_step or now >= end else min(self._next_step, end) - now
            msg = self.bus.recv(wait)
            if msg is not None:
                if not msg.is_error_frame and not msg.is_remote_frame:
                    now = time.monotonic()
                    with self.lock:
                        for drive in self.drives.values():
                            self._send(drive.receive(msg.arbitration_id, bytes(msg.data), now))
                continue
            now = time.monotonic()
            if now >= self._next_step:
                self._next_step = now + self.step_s
                with self.lock:
                    for drive in self.drives.values():
                        self._send(drive.advance(now))
            if now >= end:
                return

    def start(self) -> "SimDriveBank":
        self._thread = threading.Thread(target=self._run, name="sim-cia402", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            self.poll(0.05)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def actuals(self) -> dict[str, float]:
        """Velocity (counts/s) of wheel drives and position (counts) of steer drives."""
        with self.lock:
            return {name: d.velocity if d.role == "wheel" else d.position for name, d in self.drives.items()}


class SyncCanHub:
    """An in-process CAN bus with a virtual clock: frames are delivered synchronously.

    Every frame sent on one endpoint reaches the receivers of every other endpoint before
    ``send`` returns (a CAN bus of zero latency and infinite bit rate), stamped with
    :attr:`now_s`. :meth:`advance` moves the clock and runs the tickers (simulated devices
    integrating up to the new time and emitting their cyclic frames).
    """

    def __init__(self, now_s: float = 0.0) -> None:
        self.now_s = now_s
        self.frames = 0
        self._buses: list[SyncCanBus] = []
        self._tickers: list[Callable[[float], None]] = []

    def bus(self, name: str = "lockstep") -> "SyncCanBus":
        """A new endpoint on this hub."""
        bus = SyncCanBus(self, name)
        self._buses.append(bus)
        return bus

    def add_ticker(self, fn: Callable[[float], None]) -> None:
        self._tickers.append(fn)

    def advance(self, now_s: float) -> None:
        """Move the clock to ``now_s`` (never back) and let every device catch up."""
        self.now_s = max(self.now_s, now_s)
        for fn in list(self._tickers):
            fn(self.now_s)

    def _deliver(self, sender: "SyncCanBus", msg: can.Message) -> None:
        self.frames += 1
        for bus in list(self._buses):
            if bus is not sender:
                bus.receive(msg)

    def _detach(self, bus: "SyncCanBus") -> None:
        if bus in self._buses:
            self._buses.remove(bus)


class SyncCanBus(can.BusABC):
    """One endpoint of a :class:`SyncCanHub` (``synchronous = True``: replies arrive inside ``send``).

    Frames received are passed to ``receivers`` (callables taking a ``can.Message``);
    :meth:`recv` never returns one, so a python-can Notifier on this bus just idles.
    Carries ``tx_listeners`` and ``recv_errors`` like :class:`drivers.can_bus.EchoFilterBus`.
    """

    synchronous = True

    def __init__(self, hub: SyncCanHub, name: str) -> None:
        self.hub = hub
        self.receivers: list[Callable[[can.Message], None]] = []
        self.tx_listeners: list[Callable[[can.Message], None]] = []
        self.recv_errors = 0
        self._closed = threading.Event()
        super().__init__(channel=name)
        self.channel_info = f"lockstep hub {name}"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._closed.is_set():
            raise can.CanOperationError("lockstep bus is shut down")
        msg = can.Message(timestamp=self.hub.now_s, arbitration_id=msg.arbitration_id,
                          is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                          is_error_frame=msg.is_error_frame, dlc=msg.dlc, data=msg.data, is_rx=False)
        for listener in self.tx_listeners:
            listener(msg)
        self.hub._deliver(self, msg)

    def receive(self, msg: can.Message) -> None:
        """Called by the hub with a frame another endpoint sent."""
        if self._closed.is_set():
            return
        rx = can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                         is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame, dlc=msg.dlc,
                         data=msg.data, is_rx=True)
        for receiver in list(self.receivers):
            receiver(rx)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._closed.wait(0.05 if timeout is None else min(timeout, 0.05))
        return None, False

    def shutdown(self) -> None:
        if self._closed.is_set():
            return
        self._closed.set()
        self.hub._detach(self)
        super().shutdown()


class LockstepDriveBank:
    """Drives on a :class:`SyncCanBus`: frames answered as they arrive, motors advanced by the hub."""

    def __init__(self, bus: SyncCanBus, drives: dict[str, SimDrive]) -> None:
        self.bus, self.drives = bus, drives
        self.lock = threading.Lock()          # API parity with SimDriveBank; everything runs in one thread
        self.send_errors = 0
        bus.receivers.append(self._on_frame)
        bus.hub.add_ticker(self._advance)

    def _send(self, frames: list[Frame]) -> None:
        for arb, data in frames:
            self.bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))

    def _on_frame(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            return
        for drive in self.drives.values():
            self._send(drive.receive(msg.arbitration_id, bytes(msg.data), self.bus.hub.now_s))

    def _advance(self, now_s: float) -> None:
        for drive in self.drives.values():
            self._send(drive.advance(now_s))

    def start(self) -> "LockstepDriveBank":
        return self

    def stop(self) -> None:
        pass

    def actuals(self) -> dict[str, float]:
        """Velocity (counts/s) of wheel drives and position (counts) of steer drives."""
        return {name: d.velocity if d.role == "wheel" else d.position for name, d in self.drives.items()}
