"""A simulated CiA 402 drive: first-order motor behind a CiA 301 / 402 protocol stack.

:class:`SimDrive` is one motor: boot-up, heartbeat producer and consumer, the SDO server of
:mod:`sim.cia402_od` (expedited and segmented), configurable RPDO / TPDO mapping
(event-timer and SYNC; synchronous RPDOs act at the next SYNC), the power state machine
with its statusword bits (optionally vendor bits such as the Maxon EPOS bit 8), EMCY on
faults, quick stop on NMT stop. Modes: profile velocity and position, homing (home switch
or current position, :data:`drivers.cia402.HOMING_METHODS`), and the cyclic synchronous
modes CSP / CSV: the set-point received before a SYNC is taken at that SYNC and (CSP)
interpolated linearly over the interpolation period. A drive in CSP / CSV that sees no
SYNC for three communication cycles (0x1006) sends EMCY 0x8700 and quick-stops.
It is driven by frames and time only, so the same object runs in real time
(:class:`sim.cia402_bank.SimDriveBank`) or in lockstep.
"""
from __future__ import annotations

import math

from drivers import cia402 as p
from sim.cia402_motion import CspSegment, approach_velocity
from sim.cia402_od import DriveFaults, SdoServer, object_dictionary

Frame = tuple[int, bytes]

CYCLIC = (p.MODE_CSP, p.MODE_CSV)
SYNC_LOSS_CYCLES = 3.5          # stop when the 3rd SYNC after the last one is half a period overdue
HOMING_TRAVEL = 250_000         # counts searched for the home switch before a homing error


class SimDrive:
    """One simulated CiA 402 drive, driven by frames and time (seconds, any origin).

    ``receive`` and ``advance`` return the frames the drive transmits in response.
    Units: counts, counts/s, counts/s^2 (``max_velocity`` clips the set-point).
    """

    def __init__(self, node_id: int, *, role: str = "wheel", time_constant_s: float = 0.02,
                 max_velocity: float = 2_000_000.0, faults: DriveFaults | None = None, now_s: float = 0.0,
                 target_window: int = 50) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"CANopen node id must be 1..127, got {node_id}")
        if time_constant_s <= 0:
            raise ValueError("time_constant_s must be > 0 (first-order motor lag)")
        self.node_id, self.role, self.tau, self.vmax = node_id, role, time_constant_s, max_velocity
        self.faults = faults or DriveFaults()
        self.window = target_window
        self._t = now_s
        self.velocity = 0.0                # counts/s, actual
        self.position = float(self.faults.position_offset)    # physical (the steering angle, the wheel travel)
        self._enc = float(self.faults.encoder_offset)          # position actual - physical (homing moves it)
        self._demand_v = 0.0               # ramped velocity demand
        self.emcy_sent: list[int] = []
        self.syncs = 0
        self.max_sync_gap_s = 0.0          # longest time the SYNC watchdog saw without a SYNC (s, diagnostic)
        self.max_sync_gap_at_s = 0.0       # and when it saw it (the end of that gap, s)
        self._boot(now_s)

    # -- state -----------------------------------------------------------------------
    def _boot(self, now_s: float) -> None:
        self.od = object_dictionary(self.node_id, self.role)
        self.sdo = SdoServer(self.od, self.faults, on_write=self._on_sdo_write, read_hook=self._live_value)
        self.nmt = "PRE-OPERATIONAL"
        self.state = p.SWITCH_ON_DISABLED
        self._cw = 0
        self._setpoint_ack = False
        self._pp_target: float | None = None
        self._hb_next = now_s
        self._master_hb: float | None = None
        self._tpdo_next = [now_s] * 4
        self._last_sw: list[int | None] = [None] * 4
        self._sync_count = [0] * 4
        self._rpdo_pending: dict[int, bytes] = {}     # synchronous RPDOs: acted on at the next SYNC
        self._sync_last: float | None = None
        self._cyclic_since: float | None = None       # entered OPERATION ENABLED in CSP / CSV
        self._csp = CspSegment(self.position, self.position, now_s, 0.0)      # physical counts
        self._csv_target = 0.0
        self._homing = "idle"                         # idle | running | attained | error
        self._homing_start = 0.0
        self._out: list[Frame] = [(p.HEARTBEAT + self.node_id, b"\x00")]
        if self.faults.start_in_fault:
            self._enter_fault(self.faults.start_in_fault)
            self.state = p.FAULT

    def _get(self, index: int, sub: int = 0) -> int:
        return int(self.od[(index, sub)].value)  # type: ignore[arg-type]

    def _set(self, index: int, value: int, sub: int = 0) -> None:
        self.od[(index, sub)].value = value

    def statusword(self) -> int:
        sw = p.STATE_BITS[self.state] | 0x0200 | self.faults.vendor_bits          # bit 9 remote
        mode = self.mode
        if mode == p.MODE_HOMING:
            sw |= p.SW_HOMING_ATTAINED if self._homing == "attained" else 0
            sw |= p.SW_HOMING_ERROR if self._homing == "error" else 0
        elif mode in CYCLIC and self.state == p.OPERATION_ENABLED:
            sw |= 0x1000                                                          # follows the command value
        if self.state in (p.OPERATION_ENABLED, p.QUICK_STOP_ACTIVE, p.FAULT, p.FAULT_REACTION_ACTIVE):
            sw |= 0x0010                                                          # voltage enabled
        if self.state in (p.READY_TO_SWITCH_ON, p.SWITCHED_ON, p.OPERATION_ENABLED):
            sw |= 0x0020                                                          # quick stop (active low)
        if self.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE) and self._target_reached():
            sw |= 0x0400
        if mode == p.MODE_PP and self._setpoint_ack:
            sw |= 0x1000
        return sw

    @property
    def position_actual(self) -> int:
        """0x6064 as the drive reports it (encoder counts: physical + offset), wrapped to int32."""
        return (int(round(self.position + self._enc)) + 2**31) % 2**32 - 2**31

    @property
    def mode(self) -> int:
        return self._get(p.MODES_OF_OPERATION)

    def _target_reached(self) -> bool:
        if self.state != p.OPERATION_ENABLED:
            return abs(self.velocity) < self.window
        if self.mode == p.MODE_HOMING:
            return self._homing != "running"
        if self.mode in CYCLIC:
            return True
        if self.mode == p.MODE_PP:
            return self._pp_target is None or (abs(self.position - self._pp_target) < self.window
                                               and abs(self.velocity) < 10 * self.window)
        return abs(self.velocity - self._target_velocity()) < 10 * self.window

    def _target_velocity(self) -> float:
        return max(-self.vmax, min(self.vmax, float(self._get(p.TARGET_VELOCITY))))

    def _emcy(self, code: int, register: int) -> None:
        self.emcy_sent.append(code)
        self._out.append((p.EMCY + self.node_id, p.emcy_frame(code, register)))

    def _enter_fault(self, code: int) -> None:
        self._set(p.ERROR_CODE, code)
        self._set(0x1001, 0x01)
        self.state = p.FAULT_REACTION_ACTIVE
        self._emcy(code, 0x01)

    def reboot(self, now_s: float) -> None:
        """A power glitch: the drive restarts (boot-up, default configuration, motor unpowered, not homed)."""
        self._enc = float(self.faults.encoder_offset)
        self._boot(now_s)

    def inject_fault(self, code: int = 0x2310) -> None:
        """A fault from the power stage: fault reaction (quick-stop ramp), EMCY, then FAULT."""
        if self.state not in (p.FAULT, p.FAULT_REACTION_ACTIVE):
            self._enter_fault(code)

    # -- controlword -----------------------------------------------------------------
    def _apply_controlword(self, cw: int) -> None:
        prev, self._cw = self._cw, cw
        s = self.state
        if s == p.FAULT:
            if cw & 0x80 and not prev & 0x80 and not self.faults.sticky_fault:
                self._set(p.ERROR_CODE, 0)
                self._set(0x1001, 0)
                self._emcy(0x0000, 0)
                self.state = p.SWITCH_ON_DISABLED
            return
        if s in (p.FAULT_REACTION_ACTIVE, p.NOT_READY):
            return
        disable_voltage = not cw & 0x02
        quick_stop = cw & 0x06 == 0x02
        if s == p.SWITCH_ON_DISABLED:
            if cw & 0x87 == 0x06:
                self.state = p.READY_TO_SWITCH_ON
        elif s == p.QUICK_STOP_ACTIVE:
            if disable_voltage:
                self.state = p.SWITCH_ON_DISABLED
            elif cw & 0x8F == 0x0F:
                self.state = p.OPERATION_ENABLED          # transition 16
        elif disable_voltage or (quick_stop and s != p.OPERATION_ENABLED):
            self.state = p.SWITCH_ON_DISABLED
        elif quick_stop:
            self.state = p.QUICK_STOP_ACTIVE
        elif cw & 0x87 == 0x06:
            self.state = p.READY_TO_SWITCH_ON
        elif cw & 0x8F == 0x07:
            self.state = p.SWITCHED_ON
        elif cw & 0x8F == 0x0F and s in (p.SWITCHED_ON, p.OPERATION_ENABLED):
            if s == p.SWITCHED_ON:
                self._pp_target = None                    # no stale move on enable
                self._csp = CspSegment(self.position, self.position, self._t, 0.0)   # CSP holds until a SYNC
                self._csv_target = 0.0
            self.state = p.OPERATION_ENABLED
        if self.state == p.OPERATION_ENABLED and self.mode == p.MODE_HOMING:
            self._homing_control(cw, prev)
        if self.state == p.OPERATION_ENABLED and self.mode == p.MODE_PP:
            if cw & p.CW_NEW_SET_POINT and not prev & p.CW_NEW_SET_POINT:
                self._pp_target = float(self._get(p.TARGET_POSITION)) - self._enc
                self._setpoint_ack = True
            elif not cw & p.CW_NEW_SET_POINT:
                self._setpoint_ack = False

    def _homing_control(self, cw: int, prev: int) -> None:
        """Bit 4 rising starts homing with method 0x6098; bit 4 low (or halt) interrupts a run."""
        if cw & p.CW_HOMING_START and not prev & p.CW_HOMING_START:
            if self._get(p.HOMING_METHOD) in (35, 37):        # here is home
                self._enc = self._get(p.HOME_OFFSET) - self.position
                self._homing = "attained"
            else:
                self._homing, self._homing_start = "running", self.position
        elif (not cw & p.CW_HOMING_START or cw & p.CW_HALT) and self._homing == "running":
            self._homing = "idle"

    def _on_sdo_write(self, key: tuple[int, int], value: int | bytes) -> None:
        if key == (p.CONTROLWORD, 0):
            self._apply_controlword(int(value))  # type: ignore[arg-type]
        elif key == (0x1023, 1):                 # OS command: executed at once, the reply says what was run
            self._set(0x1023, b"ok: " + bytes(value), 3)  # type: ignore[arg-type]
            self._set(0x1023, 1, 2)                       # completed, no error, reply available

    def _live_value(self, key: tuple[int, int]) -> int | None:
        return self.statusword() if key == (p.STATUSWORD, 0) else None

    # -- frames in -------------------------------------------------------------------
    def receive(self, arbitration_id: int, data: bytes, now_s: float) -> list[Frame]:
        """Handle one frame seen on the bus; return the frames sent in reply."""
        if self.faults.deaf:
            return []
        self._update(now_s)
        data = bytes(data)
        fn = arbitration_id & 0x780
        if arbitration_id == p.NMT and len(data) >= 2 and data[1] in (0, self.node_id):
            self._nmt(data[0], now_s)
        elif arbitration_id == self._get(p.COB_ID_SYNC) & 0x7FF:
            if not self.faults.sync_deaf:
                self._on_sync(now_s)
        elif arbitration_id == p.SDO_RX + self.node_id and self.nmt != "STOPPED":
            self._out.extend((p.SDO_TX + self.node_id, r) for r in self.sdo.handle(data))
        elif fn == p.HEARTBEAT and self._get(0x1016, 1) >> 16 & 0x7F == arbitration_id & 0x7F:
            self._master_hb = now_s
        elif self.nmt == "OPERATIONAL":
            for i in range(4):
                cob = self._get(0x1400 + i, 1)
                if not cob & 0x80000000 and arbitration_id == cob & 0x7FF:
                    if self._get(0x1400 + i, 2) <= 240:
                        self._rpdo_pending[i] = data          # synchronous: acted on at the next SYNC
                    else:
                        self._write_mapped(0x1600 + i, data)
        return self._flush()

    def _nmt(self, cs: int, now_s: float) -> None:
        if cs in (p.NMT_RESET_NODE, p.NMT_RESET_COMM):
            keep = {k: e.value for k, e in self.od.items() if k[0] >= 0x2000} if cs == p.NMT_RESET_COMM else {}
            state, fault = self.state, self._get(p.ERROR_CODE)
            self._boot(now_s)
            for k, v in keep.items():
                self.od[k].value = v
            if cs == p.NMT_RESET_COMM:
                self.state = state if state != p.FAULT_REACTION_ACTIVE else p.FAULT
                self._set(p.ERROR_CODE, fault)
            return
        new = {p.NMT_START: "OPERATIONAL", p.NMT_STOP: "STOPPED", p.NMT_PRE_OPERATIONAL: "PRE-OPERATIONAL"}.get(cs)
        if new is None:
            return
        if self.nmt == "OPERATIONAL" and new != "OPERATIONAL" and self.state == p.OPERATION_ENABLED:
            self.state = p.QUICK_STOP_ACTIVE          # 0x6007 abort connection: quick stop
        self.nmt = new

    def _write_mapped(self, map_index: int, data: bytes) -> None:
        offset = 0
        for sub in range(1, self._get(map_index, 0) + 1):
            entry = self._get(map_index, sub)
            index, subindex, nbytes = entry >> 16, entry >> 8 & 0xFF, (entry & 0xFF) // 8
            if offset + nbytes > len(data):
                return                                 # short RPDO: ignore (a real drive sends EMCY 0x8210)
            obj = self.od.get((index, subindex))
            if obj is not None:
                obj.value = int.from_bytes(data[offset:offset + nbytes], "little", signed=obj.signed)
                if index == p.CONTROLWORD:
                    self._apply_controlword(int(obj.value))
            offset += nbytes

    # -- time ------------------------------------------------------------------------
    def advance(self, now_s: float) -> list[Frame]:
        """Integrate the motor up to ``now_s``, emit due heartbeats / TPDOs, watch the SYNC.

        The SYNC watchdog runs here, in the drive's own cycle, not on frame arrival: frames
        handled late (a real-time bank catching up) must not look like a missed SYNC.
        """
        self._update(now_s)
        self._sync_watchdog(now_s)
        return self._flush()

    def _update(self, now_s: float) -> None:
        dt = now_s - self._t
        if dt > 0:
            self._t = now_s
            self._integrate(dt)
        self._set(p.MODES_DISPLAY, self.mode)
        self._set(p.STATUSWORD, self.statusword())
        self._set(p.POSITION_ACTUAL, self.position_actual)
        self._set(p.VELOCITY_ACTUAL, int(round(self.velocity)))
        period = self._get(0x1017) / 1000.0
        if period > 0 and now_s >= self._hb_next:
            self._hb_next = now_s + period
            self._out.append((p.HEARTBEAT + self.node_id, bytes([{"OPERATIONAL": 5, "STOPPED": 4}.get(self.nmt, 0x7F)])))
        consumer = self._get(0x1016, 1)
        if consumer & 0xFFFF and self._master_hb is not None and now_s - self._master_hb > (consumer & 0xFFFF) / 1000:
            self._master_hb = None
            if self.state in (p.OPERATION_ENABLED, p.QUICK_STOP_ACTIVE):
                self._enter_fault(0x8130)             # master lost: stop on the fault ramp
        if self.nmt == "OPERATIONAL":
            for i in range(4):
                if self._get(0x1800 + i, 2) >= 0xFE and not self._get(0x1800 + i, 1) & 0x80000000:
                    timer = self._get(0x1800 + i, 5) / 1000.0
                    sw_changed = self._last_sw[i] != self._get(p.STATUSWORD)
                    if (timer > 0 and now_s >= self._tpdo_next[i]) or sw_changed:
                        self._tpdo_next[i] = now_s + timer
                        self._send_tpdo(i)

    def _sync_watchdog(self, now_s: float) -> None:
        """CSP / CSV: no SYNC for three communication cycles -> EMCY 0x8700 and quick stop."""
        if self.state != p.OPERATION_ENABLED or self.mode not in CYCLIC:
            self._cyclic_since = None
            return
        if self._cyclic_since is None:
            self._cyclic_since = now_s
        period = self._get(p.COMM_CYCLE_PERIOD) * 1e-6
        last = max(self._cyclic_since, self._sync_last if self._sync_last is not None else -math.inf)
        if now_s - last > self.max_sync_gap_s:
            self.max_sync_gap_s, self.max_sync_gap_at_s = now_s - last, now_s
        if period > 0 and now_s - last > SYNC_LOSS_CYCLES * period:
            self._set(0x1001, self._get(0x1001) | 0x10)      # error register: communication
            self._emcy(0x8700, self._get(0x1001))
            self.state = p.QUICK_STOP_ACTIVE

    def _interpolation_period(self) -> float:
        """Seconds between cyclic set-points: 0x60C2, else 0x1006, else the last SYNC interval."""
        value, exponent = self._get(p.INTERPOLATION_PERIOD, 1), self._get(p.INTERPOLATION_PERIOD, 2)
        if value:
            return value * 10.0 ** ((exponent + 128) % 256 - 128)
        return self._get(p.COMM_CYCLE_PERIOD) * 1e-6

    def _on_sync(self, now_s: float) -> None:
        if self.nmt != "OPERATIONAL":
            return
        self.syncs += 1
        self._sync_last = now_s
        for i, data in sorted(self._rpdo_pending.items()):
            self._write_mapped(0x1600 + i, data)
        self._rpdo_pending.clear()
        self._set(p.STATUSWORD, self.statusword())    # the TPDOs of this SYNC show the controlword it applied
        if self.state == p.OPERATION_ENABLED and self.mode == p.MODE_CSP:
            start = self._csp.demand(now_s)[0]
            self._csp = CspSegment(start, self._get(p.TARGET_POSITION) - self._enc, now_s, self._interpolation_period())
        elif self.state == p.OPERATION_ENABLED and self.mode == p.MODE_CSV:
            self._csv_target = self._target_velocity()
        for i in range(4):
            n = self._get(0x1800 + i, 2)
            if 1 <= n <= 240 and not self._get(0x1800 + i, 1) & 0x80000000:
                self._sync_count[i] += 1
                if self._sync_count[i] % n == 0:
                    self._send_tpdo(i)

    def _send_tpdo(self, i: int) -> None:
        if self.faults.pdo_mute:
            return
        data = b""
        for sub in range(1, self._get(0x1A00 + i, 0) + 1):
            entry = self._get(0x1A00 + i, sub)
            obj = self.od.get((entry >> 16, entry >> 8 & 0xFF))
            nbytes = (entry & 0xFF) // 8
            value = int(obj.value) if obj is not None else 0  # type: ignore[arg-type]
            data += (value & (1 << 8 * nbytes) - 1).to_bytes(nbytes, "little")
        self._last_sw[i] = self._get(p.STATUSWORD)
        self._out.append((self._get(0x1800 + i, 1) & 0x7FF, data[:8]))

    def _homing_goal(self) -> float:
        """Velocity toward the home switch edge (fast speed 0x6099:1, accel 0x609A); ends the run there."""
        edge, method = self.faults.home_switch, self._get(p.HOMING_METHOD)
        fast = float(self._get(p.HOMING_SPEEDS, 1))
        if edge is None:                                  # no switch: search the method's way, then give up
            if abs(self.position - self._homing_start) > HOMING_TRAVEL:
                self._homing = "error"
                return 0.0
            return fast if method in (19, 20) else -fast
        error = edge - self.position
        if abs(error) < self.window and abs(self.velocity) < 10 * self.window:
            self._enc = self._get(p.HOME_OFFSET) - edge
            self._homing = "attained"
            return 0.0
        return approach_velocity(error, fast, float(self._get(p.HOMING_ACCEL)), self.tau)

    def _integrate(self, dt: float) -> None:
        s, mode = self.state, self.mode
        if s == p.OPERATION_ENABLED and mode in CYCLIC:
            # The drive's own loops: velocity demand at once (CSV), or the interpolated position's
            # rate plus a critically damped position loop around the first-order motor (CSP).
            if mode == p.MODE_CSV:
                goal = self._csv_target
            else:
                demand, rate = self._csp.demand(self._t - 0.5 * dt)      # mid-step: the rate of this interval
                goal = rate + (demand - self.position) / (4.0 * self.tau)
            self._demand_v = max(-self.vmax, min(self.vmax, goal))
            self._lag(dt)
            return
        if s == p.OPERATION_ENABLED and mode == p.MODE_HOMING and self._homing == "running":
            goal, accel = self._homing_goal(), float(self._get(p.HOMING_ACCEL))
        elif s == p.OPERATION_ENABLED and mode == p.MODE_PV and not self._cw & p.CW_HALT:
            goal, accel = self._target_velocity(), float(self._get(p.PROFILE_ACCEL))
            if abs(goal) < abs(self._demand_v) or goal * self._demand_v < 0:
                accel = float(self._get(p.PROFILE_DECEL))
        elif s == p.OPERATION_ENABLED and mode == p.MODE_PP and self._pp_target is not None:
            error = self._pp_target - self.position
            vprof, accel = float(self._get(p.PROFILE_VELOCITY)), float(self._get(p.PROFILE_ACCEL))
            goal = approach_velocity(error, vprof, accel, self.tau)
        else:                                         # quick stop, fault reaction, disabled, halt
            goal, accel = 0.0, float(self._get(p.QUICK_STOP_DECEL))
        step = accel * dt
        self._demand_v += max(-step, min(step, goal - self._demand_v))
        self._lag(dt)
        if s != p.OPERATION_ENABLED and self._demand_v == 0.0 and abs(self.velocity) < 0.5:
            self.velocity = 0.0                       # at rest (below half a count per second)
            if s == p.FAULT_REACTION_ACTIVE:
                self.state = p.FAULT

    def _lag(self, dt: float) -> None:
        """First-order motor: the velocity follows the demand with time constant tau."""
        alpha = 1.0 - math.exp(-dt / self.tau)
        self.velocity += alpha * (self._demand_v - self.velocity)
        self.position += self.velocity * dt

    def _flush(self) -> list[Frame]:
        out, self._out = self._out, []
        return [] if self.faults.mute else out
