"""CANopen master for CiA 402 drives (the ``canopen`` package on any python-can bus).

:class:`Cia402Master` brings each drive up (NMT reset communication, boot-up, device
type check, heartbeat producer / consumer, PDO mapping by SDO, mode, ramps, NMT start),
then runs the power state machine cyclically over RPDO1 (controlword + target) from
TPDO1 (statusword, mode display) and TPDO2 (position, velocity). Wheels run in profile
velocity (or CSV), steering in profile position (or CSP). With ``sync_hz`` > 0 the cyclic
step is the SYNC producer: it sends every RPDO, then SYNC, so in the cyclic synchronous
modes every drive takes its set-point at the same instant; there the master slews the
set-points itself (steer rate, wheel acceleration), as a drive's profile would. Steer
drives can home first (``homing_method``, CiA 402 mode 6) before their operating mode.

Safety: the master quick-stops **every** drive when commands go stale (watchdog), a
heartbeat is lost, a drive reboots, an EMCY arrives or a drive faults in service; those
latch until :meth:`Cia402Master.reset`. Faults already present at start are reset (rising
edge of controlword bit 7) a bounded number of times. The master also produces its own
heartbeat *from the cyclic step*, and each drive is told to consume it, so a stalled or
killed master makes the drives fault and stop by themselves.

Time comes from ``clock`` (seconds; ``time.monotonic`` by default, the node's clock in a
pipeline), so the master also runs in virtual time. Bring-up runs in a background thread
(:meth:`Cia402Master.start`), or inside :meth:`Cia402Master.step` on a synchronous bus.
"""
from __future__ import annotations

import logging
import math
import struct
import threading
import time
from typing import Callable

import can
import canopen

from drivers import cia402 as p
from drivers.cia402_bringup import Drive, EmcyRecord, bring_up, finish_homing, sdo_read
from drivers.cia402_config import Config, check_config, check_object_dictionary, feedback_bound_s
from tether import DriverError

log = logging.getLogger("drivers.canopen402")      # one logger for the whole driver


class Cia402Master:
    """CANopen master for a set of CiA 402 drives on one bus (no tether dependency)."""

    def __init__(self, bus: can.BusABC, cfg: Config, *, on_trip: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        check_config(cfg)
        self.cfg = cfg
        self._clock = clock
        self.bus = bus
        self.network = canopen.Network(bus)
        self.drives: dict[str, Drive] = {}
        self.latched = ""                # why every drive is held in quick stop ('' = not)
        self.errors = 0
        self._on_trip = on_trip
        self._stop = threading.Event()
        self._next_master_hb = 0.0
        self._next_sync: float | None = None
        self._last_sync_s: float | None = None
        self.syncs_sent = 0
        self._sync_failures = 0
        self._thread: threading.Thread | None = None
        self._inline = False             # bring-up inside step() (synchronous bus, virtual time)
        self._skip: dict[str, set[int]] = {}
        for spec in cfg.drives:
            od = canopen.ObjectDictionary()
            if spec.eds or cfg.eds:
                od = canopen.import_od(spec.eds or cfg.eds, node_id=spec.node_id)
                problems, self._skip[spec.name] = check_object_dictionary(od, spec.role)
                if problems:
                    raise ValueError(f"drive {spec.name!r}: {spec.eds or cfg.eds} cannot serve as a {spec.role} "
                                     f"drive: {'; '.join(problems)}")
            node = canopen.RemoteNode(spec.node_id, od)
            node.sdo.RESPONSE_TIMEOUT = cfg.sdo_timeout_s
            self.network.add_node(node)
            d = Drive(spec, node)
            self.drives[spec.name] = d
            n = spec.node_id
            self.network.unsubscribe(p.EMCY + n)                      # ours decodes short frames too
            self.network.subscribe(p.EMCY + n, self._emcy_cb(d))
            self.network.subscribe(p.TPDO_BASE[0] + n, self._tpdo1_cb(d))
            self.network.subscribe(p.TPDO_BASE[1] + n, self._tpdo2_cb(d))
            node.nmt.add_heartbeat_callback(self._hb_cb(d))

    # -- bus callbacks (notifier thread) ---------------------------------------------
    def _hb_cb(self, d: Drive) -> Callable[[int], None]:
        def cb(state: int) -> None:
            d.last_hb = self._clock()
            d.nmt_state = p.NMT_STATES.get(state, f"0x{state:02X}")
            if state == 0:
                d.booted.set()
                if d.configured:       # rebooted in service: it lost its configuration
                    d.configured = False
                    d.last_feedback = None
                    self.trip(f"{d.name} rebooted")
        return cb

    def _emcy_cb(self, d: Drive) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, ts: float) -> None:
            try:
                e = p.parse_emcy(data)
            except ValueError as exc:
                self.errors += 1
                log.error("%s: %s", d.name, exc)
                return
            d.emcy_history.append(EmcyRecord(self._clock(), e.code, e.register, e.text))
            if e.is_reset:
                d.emcy_code, d.fault = 0, ""
                return
            d.emcy_code, d.fault = e.code, f"EMCY 0x{e.code:04X} {e.text}"
            log.warning("%s: %s (register 0x%02X)", d.name, d.fault, e.register)
            if d.configured and d.was_enabled:
                self.trip(f"{d.name}: {d.fault}")
        return cb

    def _tpdo1_cb(self, d: Drive) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, ts: float) -> None:
            if len(data) < 2:
                self.errors += 1
                return
            was_enabled, was_faulted = d.was_enabled, d.state in (p.FAULT, p.FAULT_REACTION_ACTIVE)
            d.set_statusword(struct.unpack_from("<H", data)[0])
            d.mode = struct.unpack_from("<b", data, 2)[0] if len(data) >= 3 else d.mode
            d.last_feedback = self._clock()
            if d.state in (p.FAULT, p.FAULT_REACTION_ACTIVE) and was_enabled and d.configured:
                if not was_faulted:
                    d.read_error_code = True          # 0x603F says why; read it outside the callback
                self.trip(f"{d.name} faulted in service (statusword 0x{d.statusword:04X})")
        return cb

    def _tpdo2_cb(self, d: Drive) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, ts: float) -> None:
            if len(data) < 8:
                self.errors += 1
                return
            raw_pos, d.velocity = struct.unpack_from("<ii", data)
            d.position = p.unwrap_int32(d.position, raw_pos)
            d.last_feedback = self._clock()
        return cb

    # -- bring-up ----------------------------------------------------------------------
    def start(self) -> None:
        """Connect and start bringing drives up in a background thread.

        On a synchronous bus (``bus.synchronous``: frames answered inside ``send``, as on
        :class:`sim.cia402_bank.SyncCanBus`) frames are dispatched as they arrive, with no
        notifier thread, and bring-up runs inside :meth:`step`: everything in the caller's thread.
        """
        if getattr(self.bus, "synchronous", False):
            self.bus.receivers.append(self._dispatch)
            self._inline = True
            return
        self.network.connect()
        self._thread = threading.Thread(target=self._bring_up_loop, name="cia402-bring-up", daemon=True)
        self._thread.start()

    def _dispatch(self, msg: can.Message) -> None:
        for listener in list(self.network.listeners):
            listener.on_message_received(msg)

    def _bring_up_loop(self) -> None:
        while not self._stop.is_set():
            self.bring_up_pending()
            self._stop.wait(0.02)

    def bring_up_pending(self) -> None:
        """Try to bring up every drive that is not configured and not waiting for its retry time."""
        for d in self.drives.values():
            if d.configured and d.read_error_code and not self._stop.is_set():
                self._read_error_code(d)
            if d.configured and d.homing == "switch" and not self._stop.is_set():
                try:
                    finish_homing(d)
                except (DriverError, can.CanError) as exc:
                    d.fault = f"after homing: {exc}"
                    self.trip(f"{d.name}: {d.fault}")
            if d.configured or self._clock() < d.next_try or self._stop.is_set():
                continue
            try:
                self.bring_up(d)
            except (DriverError, canopen.SdoAbortedError, canopen.SdoCommunicationError, can.CanError) as exc:
                d.next_try = self._clock() + self.cfg.retry_s
                log.error("%s (node %d): bring-up failed: %s; retrying in %.1f s",
                          d.name, d.spec.node_id, exc, self.cfg.retry_s)
            except Exception:  # noqa: BLE001 - the bring-up thread must outlive any surprise
                d.next_try = self._clock() + self.cfg.retry_s
                log.exception("%s (node %d): bring-up failed unexpectedly", d.name, d.spec.node_id)

    def _read_error_code(self, d: Drive) -> None:
        """Upload 0x603F (the drive's own error code) after an in-service fault, once."""
        d.read_error_code = False
        try:
            d.error_code = sdo_read(d, p.ERROR_CODE, 0, 2)
        except (DriverError, can.CanError) as exc:
            log.error("%s (node %d): reading error code 0x603F failed: %s", d.name, d.spec.node_id, exc)
            return
        text = p.EMCY_CODES.get(d.error_code, p.EMCY_CODES.get(d.error_code & 0xFF00, "unknown"))
        log.error("%s (node %d): error code 0x603F = 0x%04X (%s)", d.name, d.spec.node_id, d.error_code, text)

    def bring_up(self, d: Drive) -> None:
        """Configure one drive and start it (raises DriverError with the step that failed)."""
        bring_up(self.network, d, self.cfg, skip=self._skip.get(d.name, set()), now_s=self._clock())

    # -- cyclic ------------------------------------------------------------------------
    def trip(self, reason: str) -> None:
        """Hold every drive in quick stop until :meth:`reset`."""
        if not self.latched:
            self.latched = reason
            log.error("quick stop of all drives: %s", reason)
            if self._on_trip is not None:
                self._on_trip(reason)

    def reset(self) -> None:
        """Clear the latch; faulted drives get fault resets again."""
        if self.latched:
            log.warning("reset after: %s", self.latched)
        self.latched = ""
        for d in self.drives.values():
            d.fault_resets = 0
            d.was_enabled = False
            if d.homing == "running":
                d.homing = "pending"            # a homing run that tripped starts over
            if d.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE):
                d.fault, d.emcy_code = "", 0

    def ready(self) -> bool:
        """Every drive is configured and homed (it may still be disabled)."""
        return all(d.configured and not d.homing for d in self.drives.values())

    def enabled(self) -> bool:
        """Every drive is configured, OPERATION ENABLED with a live heartbeat, and nothing is latched:
        the vehicle is under command (what a trajectory may wait for before it starts)."""
        return not self.latched and all(d.configured and not d.homing and d.state == p.OPERATION_ENABLED
                                        and d.nmt_state != "LOST" for d in self.drives.values())

    def step(self, now_s: float, setpoints: dict[str, int] | None) -> None:
        """One cycle: master heartbeat, heartbeat check, controlword + target per drive.

        ``setpoints`` (counts/s for wheels, counts for steering) is None when commands
        are stale or absent; the drives are then quick-stopped.
        """
        cfg = self.cfg
        if self._inline:
            self.bring_up_pending()
        if cfg.master_node_id and now_s >= self._next_master_hb:
            self._next_master_hb = now_s + cfg.master_heartbeat_ms / 1000.0
            self._send(p.HEARTBEAT + cfg.master_node_id, b"\x05")
        lost_after = cfg.heartbeat_ms * cfg.heartbeat_loss_factor / 1000.0
        feedback_bound = feedback_bound_s(cfg)
        clock = self._clock()
        for d in self.drives.values():
            if d.configured and d.last_hb is not None and clock - d.last_hb > lost_after:
                d.nmt_state = "LOST"
                self.trip(f"heartbeat of {d.name} lost")
            if not d.configured or cfg.feedback_timeout_ms == 0:
                continue
            if d.last_feedback is None:
                d.last_feedback = clock               # started: its PDOs must come from now on
            elif clock - d.last_feedback > feedback_bound:
                # The heartbeat may still come: a drive whose PDOs stop cannot be steered or watched.
                self.trip(f"feedback PDOs of {d.name} (node {d.spec.node_id}) silent for "
                          f"{(clock - d.last_feedback) * 1e3:.0f} ms (bound {feedback_bound * 1e3:.0f} ms)")
        faulted = any(d.state in (p.FAULT, p.FAULT_REACTION_ACTIVE) for d in self.drives.values())
        run = setpoints is not None and not self.latched and self.ready() and not faulted
        for d in self.drives.values():
            if d.configured and d.homing and not self.latched and d.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE):
                self._home(d)
            elif d.configured:
                self._command(d, setpoints if run else None)
        self._produce_sync(now_s)

    def _produce_sync(self, now_s: float) -> None:
        """SYNC after this cycle's RPDOs, on a fixed grid of 1/sync_hz. A step up to half a step period
        early still serves its slot; a late step sends its SYNC and the grid moves on to the first slot
        not yet due, and no two SYNCs go out less than half a SYNC period apart: the catch-up steps after
        a stall skip the slots they missed instead of bursting SYNCs a millisecond or two apart, which is
        not the cycle (0x1006) the drives interpolate their set-points over."""
        hz = self.cfg.sync_hz
        if hz <= 0:
            return
        early, period = 0.5 / self.cfg.rate_hz, 1.0 / hz
        if self._next_sync is None:
            self._next_sync = now_s
        if now_s < self._next_sync - early:
            return
        if self._last_sync_s is not None and self._clock() - self._last_sync_s < 0.5 * period:
            return                           # a late SYNC went out just now: this slot is served
        self._next_sync += period * (math.floor((now_s + early - self._next_sync) / period) + 1)
        if self._send(p.SYNC, b""):
            self._last_sync_s = self._clock()     # when it went out (``now_s`` may be a stale reading)
            self.syncs_sent += 1
            self._sync_failures = 0
        else:
            self._sync_failures += 1
            if self._sync_failures >= 3:     # the drives stop by themselves; say why here too
                self.trip(f"SYNC producer failing: {self._sync_failures} SYNC frames in a row not sent")

    def _home(self, d: Drive) -> None:
        """Homing (mode 6, set at bring-up): enable, raise controlword bit 4, wait for bits 12 + 10."""
        clock, sw = self._clock(), d.statusword
        if d.homing == "pending":
            cw = p.next_controlword(d.state, p.OPERATION_ENABLED, d.cw_prev)
            if d.state == p.OPERATION_ENABLED and d.mode == p.MODE_HOMING:
                cw |= p.CW_HOMING_START
                d.homing, d.homing_since = "running", clock
                log.info("%s: homing, method %d", d.name, self.cfg.homing_method)
        elif d.homing == "running":
            cw = p.CW_ENABLE_OPERATION | p.CW_HOMING_START
            if sw & p.SW_HOMING_ERROR:
                d.fault = f"homing error (method {self.cfg.homing_method}, statusword 0x{sw:04X})"
                self.trip(f"{d.name}: {d.fault}")
            elif sw & p.SW_HOMING_ATTAINED and sw & p.SW_TARGET_REACHED and d.cw_prev & p.CW_HOMING_START:
                d.homing, cw = "switch", p.CW_SHUTDOWN       # motor off while the mode changes by SDO
            elif clock - d.homing_since > self.cfg.homing_timeout_s:
                d.fault = f"homing not attained within {self.cfg.homing_timeout_s:g} s"
                self.trip(f"{d.name}: {d.fault}")
        else:                                                # 'switch': wait for the bring-up thread
            cw = p.CW_SHUTDOWN
        self._rpdo(d, cw, d.target)

    def _command(self, d: Drive, setpoints: dict[str, int] | None) -> None:
        wheel = d.spec.role == "wheel"
        cfg = self.cfg
        if setpoints is not None:
            target_state = p.OPERATION_ENABLED
        elif d.state == p.FAULT and not d.was_enabled and d.fault_resets < cfg.max_fault_resets:
            # Reset a fault we inherited (never powers up), paced: a drive needs time to clear it.
            paced = self._clock() - d.last_fault_reset >= cfg.fault_reset_interval_s
            target_state = p.SWITCH_ON_DISABLED if paced or d.cw_prev & p.CW_FAULT_RESET else p.QUICK_STOP_ACTIVE
        else:
            target_state = p.QUICK_STOP_ACTIVE
        cw = p.next_controlword(d.state, target_state, d.cw_prev)
        if cw == p.CW_FAULT_RESET and not d.cw_prev & p.CW_FAULT_RESET:
            d.fault_resets += 1
            d.last_fault_reset = self._clock()
            if d.fault_resets == cfg.max_fault_resets:
                log.error("%s: fault persists after %d resets", d.name, d.fault_resets)
        enabled = d.state == p.OPERATION_ENABLED and setpoints is not None
        if d.cyclic:
            self._cyclic(d, cw, setpoints[d.name] if enabled and setpoints is not None else None)
            return
        if wheel:
            d.target = setpoints[d.name] if enabled and setpoints is not None else 0
            self._rpdo(d, cw, d.target)
            return
        if setpoints is not None:
            # The steering rate is bounded by the drive itself: profile velocity 0x6081 =
            # steer_speed_radps, written at bring-up (streaming slewed set-points instead would
            # race the profile-position handshake); the angle by the fold to steer_limit_rad.
            d.target = setpoints[d.name]
        if not enabled:
            d.latched_target = None
            self._rpdo(d, cw, d.target)
        elif d.latched_target != d.target:
            # Profile position: a rising edge of bit 4 latches 0x607A; bit 5 replaces the running move.
            self._rpdo(d, cw | p.CW_NEW_SET_POINT | p.CW_CHANGE_IMMEDIATELY, d.target)
            self._rpdo(d, cw | p.CW_CHANGE_IMMEDIATELY, d.target)
            d.latched_target = d.target
        else:
            self._rpdo(d, cw | p.CW_CHANGE_IMMEDIATELY, d.target)

    def _cyclic(self, d: Drive, cw: int, goal: int | None) -> None:
        """CSP / CSV: the set-point of this SYNC, slewed toward ``goal`` at the steer rate / wheel
        acceleration (a cyclic drive follows its set-points as they come; a jump would be a step).
        No goal: wheels ramp to 0, steering holds where it is (and the drive is quick-stopped)."""
        k = abs(d.spec.counts_per_unit)
        period = 1.0 / self.cfg.sync_hz
        if d.spec.role == "wheel":
            goal, limit = goal or 0, self.cfg.wheel_accel_mps2 * k * period
            if d.state != p.OPERATION_ENABLED:
                d.target = 0
        else:
            limit = self.cfg.steer_speed_radps * k * period
            if goal is None or d.state != p.OPERATION_ENABLED:
                goal = d.target = int(d.position if d.position is not None else d.target)
        d.target += int(max(-limit, min(limit, goal - d.target)))
        self._rpdo(d, cw, d.target)

    def _rpdo(self, d: Drive, cw: int, target: int) -> None:
        d.cw_prev = cw
        target = max(-2**31, min(2**31 - 1, int(target)))
        self._send(p.RPDO_BASE[0] + d.spec.node_id, struct.pack("<Hi", cw, target))

    def _send(self, can_id: int, data: bytes) -> bool:
        try:
            self.network.send_message(can_id, data)
        except can.CanError as exc:
            self.errors += 1
            log.error("CAN send 0x%03X failed: %s", can_id, exc)
            return False
        return True

    def close(self) -> None:
        """Quick-stop enabled drives, stop threads, release the bus (safe to call twice)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self.network.bus is None:
            return
        stopping = False
        for d in self.drives.values():
            if d.configured and d.state in (p.OPERATION_ENABLED, p.QUICK_STOP_ACTIVE):
                self._rpdo(d, p.CW_QUICK_STOP, 0 if d.spec.role == "wheel" else d.target)
                stopping = True
        if stopping and self.cfg.sync_hz > 0:
            self._send(p.SYNC, b"")          # synchronous RPDOs act at SYNC: this one delivers the quick stop
        self.network.disconnect()
