"""One virtual Dynamixel X-series servo: control table, instruction semantics, motion.

The device side only: no bytes on a wire, no timing of the wire. The bus decodes an
instruction packet, decides addressing, calls one method here per servo and encodes the
status packet from the returned ``(error, params)``. Every method takes the current
time ``t`` (float seconds, non-decreasing); the servo holds no clock.

Error byte (Protocol 2.0): bits 0-6 the error number (:class:`StatusError`), bit 7
(:data:`ALERT`) set whenever Hardware Error Status (addr 70) is non-zero.

Motion, evaluated lazily on a fixed grid of ``step_s`` (``advance(t)`` catches up;
nothing moving means a jump)::

    Goal Position -> profile planner -> Position/Velocity Trajectory (140/136)
                  -> horn: first-order lag (tau = model.lag_time_constant_s),
                     speed-limited to the no-load speed scaled by voltage and PWM Limit
                  -> Present Position/Velocity (132/128)

The profile is planned analytically when a goal arrives (piecewise constant
acceleration, see :mod:`drivers.dxlsim.profile`) so move durations match the e-Manual
formulas; only the lag is stepped. Velocity, PWM and Current modes drive a velocity
trajectory instead and the horn velocity lags it.

Choices where the e-Manual is silent or ambiguous (all deliberate, all tested):

- Read of a span with gaps returns 0 for the undefined bytes (as a real X-series
  returns reserved data); a read reaching past the last field (addr 146) is an Access
  Error; a read may start or end inside a field (its bytes are sliced). Length 0 is a
  Data Length Error. An erroneous read returns ``(err, b"")``.
- Write: atomic; checks per field in address order: undefined/read-only/EEPROM with
  torque on -> Access Error 7, partial multi-byte field -> Data Length Error 5, own
  range -> Data Range Error 4 (also every goal register while the Bus Watchdog is
  tripped, and a non-zero Bus Watchdog value while tripped), cross-field limits ->
  Data Limit Error 6. Profile Velocity above Velocity Limit is accepted and capped at
  use. Torque Enable 1 while ``Hardware Error Status & Shutdown`` is non-zero is
  refused with Result Fail 1 (the errors that cut torque keep it off until Reboot).
- Torque on holds the present position and copies it into Goal Position, so torque-on
  never jumps and Goal Position reads what the servo holds. In Position Control Mode it
  also folds Present Position into one turn (e-Manual Present Position note), as do a
  change to Position Control Mode and Reboot.
- Torque off stops the horn where it is (no coasting); the trajectory follows it.
- Bus Watchdog trip stops at once (the e-Manual: profile applied as 0): the trajectory
  holds where the horn is.
- Action with nothing registered -> Result Fail. Action re-validates the registered
  write against the state at Action time.
- Factory Reset while torque is on -> Access Error (it writes EEPROM).
- Clear (multi-turn) while moving -> Result Fail; other Clear parameters -> Data Range
  Error, wrong length -> Data Length Error. After it Goal Position = Present Position.
- Reboot/brownout: RAM to defaults, Goal Position = Present Position (folded), Realtime
  Tick restarts at 0. Reboot's returned error still carries the pre-reboot Alert bit
  (the real servo replies before it reboots).
- Not modelled: Drive Mode (reverse, time-based profile) is stored but ignored; Moving
  Status bit3 (following error) is never set; Homing Offset's ±1024 validity rule in
  Position Control Mode is ignored; in step moves (Profile Velocity 0) only the motor's
  speed bounds the horn, not Velocity Limit. Current mode is crude: the goal current
  fraction of Current Limit sets a fraction of no-load speed (an unloaded horn).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from drivers.protocol2.control_table import ALERT_BIT, OperatingMode, StatusError

from .models import (
    EEPROM_END,
    PULSE_PER_S2_PER_ACCEL_UNIT,
    PULSE_PER_S_PER_VELOCITY_UNIT,
    PULSES_PER_REV,
    PWM_FULL_SCALE,
    Field,
    ServoModel,
    get_model,
)
from .profile import ProfileType, _segments_end, plan_profile, plan_velocity

ALERT = ALERT_BIT  # bit 7 of the ERR byte: Hardware Error Status is not 0


class MotionState(NamedTuple):
    """Unrounded motion state in Present Position's frame: pulse and pulse/s."""

    position: float
    velocity: float
    trajectory_position: float
    trajectory_velocity: float


CLEAR_MULTI_TURN = b"\x01\x44\x58\x4c\x22"
FACTORY_RESET_ALL, FACTORY_RESET_KEEP_ID, FACTORY_RESET_KEEP_ID_BAUD = 0xFF, 0x01, 0x02
_WATCHDOG_UNIT_S = 0.020
_TRIPPED = -1
_GOAL_ADDRS = frozenset((100, 102, 104, 116))
_POSITION_MODES = frozenset((3, 4, 5))
_SETTLE_PULSES = 1e-3  # horn this close to a finished trajectory: snap and go idle
_GRID_EPS = 1e-7  # grid steps are counted with this slack against float round-off
_MASKS = {1: 0xFF, 2: 0xFFFF, 4: 0xFFFFFFFF}
# Physical quantities a constructor override may set although the field is read-only.
_INITIAL_STATE_FIELDS = ("present_position", "present_input_voltage", "present_temperature")


class VirtualServo:
    """A Dynamixel X-series servo without the wire.

    Args:
        model: model name or number (see :func:`drivers.dxlsim.models.get_model`).
        id: ID (addr 7), 0-252.
        baud: bits per second, stored as the Baud Rate index (addr 8).
        return_delay_us: Return Delay Time in µs, a multiple of 2 in 0-508 (addr 9 × 2 µs).
        firmware: Firmware Version (addr 6); default: the model's.
        t: time of power-up, s.
        step_s: fixed motion step, s.
        **overrides: initial control-table values by field name (``goal_position=...``,
            ``torque_enable=1``, ``operating_mode=4``...), validated like a Write; also the
            physical start state ``present_position`` (pulse), ``present_input_voltage``
            (0.1 V) and ``present_temperature`` (°C). EEPROM overrides survive Reboot, RAM
            ones do not. Raises ValueError on anything invalid.
    """

    def __init__(
        self,
        model: str | int | ServoModel = "XM430-W350",
        id: int = 1,
        *,
        baud: int = 57600,
        return_delay_us: float = 500,
        firmware: int | None = None,
        t: float = 0.0,
        step_s: float = 0.001,
        **overrides: int,
    ) -> None:
        self.model = m = get_model(model)
        if not step_s > 0.0:
            raise ValueError(f"step_s must be > 0, got {step_s!r}")
        fw = m.firmware if firmware is None else firmware
        if not 0 <= fw <= 255:
            raise ValueError(f"firmware must be 0..255, got {fw!r}")
        rdt_units = round(return_delay_us / 2.0)
        if abs(rdt_units * 2.0 - return_delay_us) > 1e-6 or not 0 <= rdt_units <= 254:
            raise ValueError(
                f"return_delay_us must be a multiple of 2 in 0..508, got {return_delay_us!r}"
            )
        for key in ("id", "baud_rate", "return_delay_time"):
            if key in overrides:
                raise ValueError(f"give {key} through the id=/baud=/return_delay_us= arguments")
        self._dt = float(step_s)
        self._inv_dt = 1.0 / self._dt
        self._t0 = float(t)  # origin of the motion grid
        self._k = 0  # last grid step done
        self._now = float(t)
        self._boot_t = float(t)
        self._regs: dict[int, int] = {}
        self._reset_eeprom(keep=())
        self._regs[6] = fw
        self._reset_ram()
        # physical state (actual frame: Present Position = actual + Homing Offset)
        self._x = 2048.0
        self._v = 0.0
        self._acc = 0.0
        self._volts = m.nominal_voltage_v
        self._temp_c = m.ambient_temperature_c
        self._velocity_loop = False  # True in modes 0/1/16: the horn tracks a velocity
        self._hold(self._x)
        self._profile_type = ProfileType.STEP
        self._wd_ref = self._now
        self._wd_deadline = math.inf
        self._pending: tuple[int, bytes] | None = None
        self._alpha = 1.0 - math.exp(-self._dt / m.lag_time_constant_s)
        self._update_speed_limit()
        self._dynamic = {
            120: self._realtime_tick,
            122: self._moving,
            123: self._moving_status,
            124: self._present_pwm,
            126: self._present_current,
            128: self._present_velocity,
            132: self._present_position,
            136: self._velocity_trajectory,
            140: self._position_trajectory,
            144: self._present_input_voltage,
            146: self._present_temperature,
        }
        self._apply_initial(id, m.baud_index(baud), rdt_units, overrides)

    # --- construction helpers ------------------------------------------------------------
    def _apply_initial(self, id_: int, baud_index: int, rdt: int, overrides: dict) -> None:
        eeprom = {"id": id_, "baud_rate": baud_index, "return_delay_time": rdt}
        ram: dict[str, int] = {}
        state: dict[str, int] = {}
        for name, value in overrides.items():
            try:
                f = self.model.field(name)
            except KeyError as exc:
                raise ValueError(str(exc).strip("'\"")) from None
            if f.name in _INITIAL_STATE_FIELDS:
                state[f.name] = value
            elif not f.writable:
                raise ValueError(f"{f.name} is read-only")
            else:
                (eeprom if f.eeprom else ram)[f.name] = value
        # EEPROM first (torque is off), then the physical state, then torque, then RAM.
        for name, value in sorted(eeprom.items(), key=lambda kv: self.model.field(kv[0]).addr):
            self._initial_write(name, value)
        if "present_position" in state:
            self._x = float(state["present_position"] - self._regs[20])
            self._hold(self._x)
        if "present_input_voltage" in state:
            self.set_input_voltage(state["present_input_voltage"] / 10.0)
        if "present_temperature" in state:
            self.set_temperature(float(state["present_temperature"]))
        self._regs[116] = self._present_position()
        if "torque_enable" in ram:
            self._initial_write("torque_enable", ram.pop("torque_enable"))
        for name, value in sorted(ram.items(), key=lambda kv: self.model.field(kv[0]).addr):
            self._initial_write(name, value)

    def _initial_write(self, name: str, value: int) -> None:
        f = self.model.field(name)
        try:
            data = (value & _MASKS[f.size]).to_bytes(f.size, "little")
        except (TypeError, AttributeError):
            raise ValueError(f"{name} must be an int, got {value!r}") from None
        if not f.accepts(value):
            raise ValueError(f"{name}={value} is outside {f.lo}..{f.hi} {f.choices or ''}")
        err = self.write(f.addr, data, self._now) & 0x7F
        if err:
            raise ValueError(f"{name}={value} refused: {StatusError(err).name}")

    # --- properties the bus needs --------------------------------------------------------
    @property
    def id(self) -> int:
        """ID (addr 7)."""
        return self._regs[7]

    @property
    def secondary_id(self) -> int | None:
        """Secondary (Shadow) ID (addr 12), None when disabled (> 252)."""
        sid = self._regs[12]
        return sid if sid <= 252 else None

    @property
    def baud(self) -> int:
        """Baud rate, bps (from addr 8)."""
        return self.model.baud_rates[self._regs[8]]

    @property
    def return_delay_s(self) -> float:
        """Return Delay Time, s (addr 9 × 2 µs)."""
        return self._regs[9] * 2e-6

    @property
    def status_return_level(self) -> int:
        """0: reply to Ping only, 1: Ping and Read, 2: all (addr 68)."""
        return self._regs[68]

    @property
    def firmware(self) -> int:
        return self._regs[6]

    @property
    def torque_enabled(self) -> bool:
        return self._regs[64] == 1

    @property
    def supports_fast_read(self) -> bool:
        """Fast Sync/Bulk Read available on this firmware."""
        return self.model.supports_fast_read(self._regs[6])

    @property
    def alert(self) -> bool:
        """Hardware Error Status (addr 70) is non-zero: bit 7 of every error byte."""
        return self._regs[70] != 0

    @property
    def hardware_error_status(self) -> int:
        return self._regs[70]

    @property
    def operating_mode(self) -> OperatingMode:
        return OperatingMode(self._regs[11])

    @property
    def now(self) -> float:
        """Latest time seen, s."""
        return self._now

    @property
    def motion(self) -> MotionState:
        """Unrounded motion state at the last grid step (Present Position's frame)."""
        off = self._regs[20]
        return MotionState(self._x + off, self._v, self._r + off, self._rv)

    # --- time ------------------------------------------------------------------------------
    def advance(self, t: float) -> None:
        """Evolve motion and watchdog up to ``t`` (s) in fixed steps of ``step_s``.

        Cost: O(1) when nothing moves; about a microsecond per step otherwise.
        """
        if t < self._now:
            if t < self._now - 1e-9:
                raise ValueError(f"time went back: {t!r} < {self._now!r}")
            return
        if t > self._wd_deadline:
            self._run_to(self._wd_deadline)
            self._now = self._wd_deadline
            self._trip()
        self._now = t
        self._run_to(t)

    def _run_to(self, t: float) -> None:
        k_end = int((t - self._t0) * self._inv_dt + _GRID_EPS)
        k = self._k
        if k_end <= k:
            return
        if self._idle:
            self._k = k_end
            return
        dt, inv_dt, t0, alpha = self._dt, self._inv_dt, self._t0, self._alpha
        vmax = self._vmax
        lim = vmax * dt
        x, v, acc = self._x, self._v, self._acc
        segs, i = self._segs, self._seg_i
        n = len(segs)
        end_p = self._end_p
        velocity_loop = self._velocity_loop
        r, rv = self._r, self._rv
        idle = False
        while k < k_end:
            k += 1
            tk = t0 + k * dt
            while i < n and tk >= segs[i][1]:
                i += 1
            if i < n:
                ts, te, p0, v0, a = segs[i]
                tau = tk - ts
                rv = v0 + a * tau
                r = p0 + (v0 + 0.5 * a * tau) * tau
            else:
                r, rv = end_p, 0.0
            if velocity_loop:
                vn = v + (rv - v) * alpha
                if vn > vmax:
                    vn = vmax
                elif vn < -vmax:
                    vn = -vmax
                if i < n and vn == v and a == 0.0 and te == math.inf:
                    # the horn has converged on an endless cruise: jump to the end
                    tau = (k_end - k + 1) * dt
                    x += v * tau
                    r += v0 * (tau - dt)
                    acc = 0.0
                    k = k_end
                    break
                x += vn * dt
                acc = (vn - v) * inv_dt
                v = vn
                if i >= n and -_SETTLE_PULSES < v < _SETTLE_PULSES:
                    idle = True
                    break
            else:
                dx = (r - x) * alpha
                if dx > lim:
                    dx = lim
                elif dx < -lim:
                    dx = -lim
                x += dx
                vn = dx * inv_dt
                acc = (vn - v) * inv_dt
                v = vn
                if i >= n and -_SETTLE_PULSES < r - x < _SETTLE_PULSES:
                    x = r
                    idle = True
                    break
        if idle:
            self._k = k_end
            self._x = x
            self._v = self._acc = 0.0
            self._hold(x)
            return
        self._k = k
        self._x, self._v, self._acc = x, v, acc
        self._seg_i = i
        self._r, self._rv = r, rv

    def touch(self, t: float) -> None:
        """A valid instruction packet for this servo arrived at ``t``: restart the Bus
        Watchdog timer."""
        self.advance(t)
        self._wd_ref = t
        self._arm_watchdog()

    # --- instructions --------------------------------------------------------------------
    def ping(self, t: float) -> tuple[int, bytes]:
        """Ping: ``(error, model number LE16 + firmware version)``."""
        self.advance(t)
        params = self._regs[0].to_bytes(2, "little") + bytes((self._regs[6],))
        return (ALERT if self._regs[70] else 0), params

    def read(self, addr: int, length: int, t: float) -> tuple[int, bytes]:
        """Read ``length`` bytes from ``addr``: ``(error, data)``; data is ``b""`` on error.

        Gaps read as 0; a span past the table end is an Access Error; length < 1 a Data
        Length Error.
        """
        self.advance(t)
        alert = ALERT if self._regs[70] else 0
        m = self.model
        f = m.by_addr.get(addr)
        if f is not None and f.size == length:  # the common case: one whole field
            getter = self._dynamic.get(addr)
            value = getter() if getter is not None else self._regs[addr]
            return alert, (value & _MASKS[length]).to_bytes(length, "little")
        if length < 1:
            return alert | StatusError.DATA_LENGTH, b""
        end = addr + length
        if addr < 0 or end > m.table_end:
            return alert | StatusError.ACCESS, b""
        out = bytearray(length)
        owner = m.byte_owner
        a = addr
        while a < end:
            f = owner[a]
            if f is None:
                a += 1
                continue
            getter = self._dynamic.get(f.addr)
            value = getter() if getter is not None else self._regs[f.addr]
            raw = (value & _MASKS[f.size]).to_bytes(f.size, "little")
            lo, hi = a - f.addr, min(f.end, end) - f.addr
            out[a - addr : a - addr + hi - lo] = raw[lo:hi]
            a = f.addr + hi
        return alert, bytes(out)

    def write(self, addr: int, data: bytes, t: float) -> int:
        """Write ``data`` at ``addr`` atomically; returns the error byte."""
        self.advance(t)
        err, updates = self._validate(addr, data)
        if not err:
            self._apply(updates)
        return err | (ALERT if self._regs[70] else 0)

    def reg_write(self, addr: int, data: bytes, t: float) -> int:
        """Reg Write: validate like Write, keep it pending, set Registered Instruction."""
        self.advance(t)
        err, _ = self._validate(addr, data)
        if not err:
            self._pending = (addr, bytes(data))
            self._regs[69] = 1
        return err | (ALERT if self._regs[70] else 0)

    def action(self, t: float) -> int:
        """Action: apply the pending Reg Write (re-validated now); Result Fail if none."""
        self.advance(t)
        if self._pending is None:
            return StatusError.RESULT_FAIL | (ALERT if self._regs[70] else 0)
        addr, data = self._pending
        self._pending = None
        self._regs[69] = 0
        return self.write(addr, data, t)

    def reboot(self, t: float) -> int:
        """Reboot: RAM to defaults, hardware error cleared, torque off; the horn stays.

        Returns the error byte of the reply sent before rebooting (Alert as it was).
        """
        self.advance(t)
        err = ALERT if self._regs[70] else 0
        self._restart(t)
        return err

    def factory_reset(self, option: int, t: float) -> int:
        """Factory Reset: 0xFF everything, 0x01 all but ID, 0x02 all but ID and baud.

        Other options: Data Range Error; torque on: Access Error. Then reboots.
        """
        self.advance(t)
        alert = ALERT if self._regs[70] else 0
        keep = {
            FACTORY_RESET_ALL: (),
            FACTORY_RESET_KEEP_ID: (7,),
            FACTORY_RESET_KEEP_ID_BAUD: (7, 8),
        }.get(option)
        if keep is None:
            return alert | StatusError.DATA_RANGE
        if self._regs[64]:
            return alert | StatusError.ACCESS
        self._reset_eeprom(keep)
        self._restart(t)
        return alert

    def clear(self, params: bytes, t: float) -> int:
        """Clear (0x10). ``01 44 58 4C 22`` folds Present Position into one turn (only
        while stopped, else Result Fail)."""
        self.advance(t)
        alert = ALERT if self._regs[70] else 0
        if len(params) != len(CLEAR_MULTI_TURN):
            return alert | StatusError.DATA_LENGTH
        if bytes(params) != CLEAR_MULTI_TURN:
            return alert | StatusError.DATA_RANGE
        if self._moving() or self._now < self._profile_end:
            return alert | StatusError.RESULT_FAIL
        self._fold_one_turn()
        self._regs[116] = self._present_position()
        return alert

    # --- faults the bus injects ----------------------------------------------------------
    def inject_hardware_error(self, bits: int, t: float) -> None:
        """Latch Hardware Error Status bits (0x01 voltage, 0x04 overheating, 0x08 encoder,
        0x10 electrical shock, 0x20 overload); bits in Shutdown (63) cut torque."""
        self.advance(t)
        self._regs[70] |= bits & 0xFF
        if bits & self._regs[63]:
            self._torque_off()

    def cut_torque(self, t: float) -> None:
        """Silent shutdown: Torque Enable reads 0, no hardware error."""
        self.advance(t)
        self._torque_off()

    def trip_watchdog(self, t: float) -> None:
        """Trip the Bus Watchdog now (reads -1) whether it was armed or not."""
        self.advance(t)
        self._trip()

    def brownout(self, t: float) -> None:
        """Supply dip: the same restart as Reboot (the bus models the silence)."""
        self.advance(t)
        self._restart(t)

    def set_input_voltage(self, volts: float, t: float | None = None) -> None:
        """Supply voltage, V (from ``t``, s, if given). Outside Min/Max Voltage Limit it
        latches the input voltage error; the top speed scales with it."""
        if t is not None:
            self.advance(t)
        self._volts = float(volts)
        self._check_supply()

    def set_temperature(self, celsius: float, t: float | None = None) -> None:
        """Internal temperature, °C (from ``t``, s, if given). Above Temperature Limit it
        latches the overheating error."""
        if t is not None:
            self.advance(t)
        self._temp_c = float(celsius)
        self._check_supply()

    # --- write validation and side effects -----------------------------------------------
    def _validate(self, addr: int, data: bytes) -> tuple[int, list[tuple[Field, int]]]:
        m = self.model
        regs = self._regs
        n = len(data)
        f = m.by_addr.get(addr)
        if f is not None and f.size == n:  # one whole field: the Sync Write case
            if not f.writable or (addr < EEPROM_END and regs[64]):
                return StatusError.ACCESS, []
            updates = [(f, int.from_bytes(data, "little", signed=f.signed))]
        else:
            if n == 0:
                return StatusError.DATA_LENGTH, []
            end = addr + n
            if addr < 0 or end > m.table_end:
                return StatusError.ACCESS, []
            updates = []
            owner = m.byte_owner
            a = addr
            while a < end:
                f = owner[a]
                if f is None or not f.writable or (f.addr < EEPROM_END and regs[64]):
                    return StatusError.ACCESS, []
                if f.addr != a or f.end > end:
                    return StatusError.DATA_LENGTH, []
                value = int.from_bytes(data[a - addr : f.end - addr], "little", signed=f.signed)
                updates.append((f, value))
                a = f.end
        tripped = regs[98] == _TRIPPED
        for f, value in updates:
            if not f.accepts(value):
                return StatusError.DATA_RANGE, []
            if tripped and (f.addr in _GOAL_ADDRS or (f.addr == 98 and value != 0)):
                return StatusError.DATA_RANGE, []
        for f, value in updates:
            if f.addr in _GOAL_ADDRS and not self._within_limits(f.addr, value, updates):
                return StatusError.DATA_LIMIT, []
            if f.addr == 64 and value and not regs[64] and regs[70] & regs[63]:
                return StatusError.RESULT_FAIL, []
        return StatusError.NONE, updates

    def _within_limits(self, addr: int, value: int, updates: list[tuple[Field, int]]) -> bool:
        """Goal registers against the limit registers as they will be after this write."""

        def reg(a: int) -> int:
            for f, v in updates:
                if f.addr == a:
                    return v
            return self._regs[a]

        if addr == 116:
            return reg(11) != OperatingMode.POSITION or reg(52) <= value <= reg(48)
        if addr == 104:
            return abs(value) <= reg(44)
        if addr == 102:
            return abs(value) <= reg(38)
        return abs(value) <= reg(36)  # 100, Goal PWM

    def _apply(self, updates: list[tuple[Field, int]]) -> None:
        regs = self._regs
        replan = False
        for f, value in updates:
            a = f.addr
            old = regs[a]
            if a == 64:
                if value and not old:
                    self._torque_on()
                elif old and not value:
                    self._torque_off()
                continue
            regs[a] = value
            if a == 11 and value != old:
                regs[108] = regs[112] = 0
                if value == OperatingMode.POSITION:
                    self._fold_one_turn()
                    regs[116] = self._present_position()
            elif a == 98:
                if value == 0:
                    self._wd_deadline = math.inf
                self._wd_ref = self._now
                self._arm_watchdog()
            elif a in (31, 32, 34, 36):
                self._check_supply()  # narrower limits can put the present state outside
            elif a in _GOAL_ADDRS:
                replan = True
        if replan and regs[64]:
            self._plan_goal()

    def _plan_goal(self) -> None:
        """Start a new trajectory for the present goal registers at ``now``."""
        regs = self._regs
        mode = regs[11]
        t = self._now
        p0, v0 = self._trajectory_at(t)
        accel = regs[108] * PULSE_PER_S2_PER_ACCEL_UNIT or math.inf
        if mode in _POSITION_MODES:
            self._velocity_loop = False
            goal = float(regs[116] - regs[20])
            vel = regs[112]
            if regs[44] > 0:
                vel = min(vel, regs[44])  # Velocity Limit caps the profile
            if vel == 0:
                segs, kind = [], ProfileType.STEP
            else:
                v_max = vel * PULSE_PER_S_PER_VELOCITY_UNIT
                segs, kind = plan_profile(t, p0, v0, goal, v_max, accel)
            end_p = goal
        else:
            self._velocity_loop = True
            if mode == OperatingMode.VELOCITY:
                target = regs[104] * PULSE_PER_S_PER_VELOCITY_UNIT
                kind = ProfileType.TRAPEZOIDAL if regs[108] else ProfileType.STEP
            else:  # duty (or, unloaded, current) as a fraction of the no-load speed
                if mode == OperatingMode.PWM:
                    frac = regs[100] / PWM_FULL_SCALE
                else:
                    frac = regs[102] / max(1, self.model.field("current_limit").hi)
                m = self.model
                target = frac * m.no_load_speed_pulse_s * self._volts / m.nominal_voltage_v
                accel, kind = math.inf, ProfileType.STEP
            segs = plan_velocity(t, p0, v0, target, accel)
            end_p = _segments_end(segs, p0)
        self._segs, self._seg_i, self._end_p = segs, 0, end_p
        # the profile is over when the last finite piece ends (velocity modes end endless)
        ends = [te for _, te, _, _, _ in segs[-2:] if te != math.inf]
        self._profile_end = ends[-1] if ends else t
        self._profile_type = kind
        self._idle = False

    def _trajectory_at(self, t: float) -> tuple[float, float]:
        """Trajectory (position, velocity) at time ``t`` from the current plan."""
        if self._idle:
            return self._r, 0.0
        for ts, te, p0, v0, a in self._segs[self._seg_i :]:
            if t < te:
                tau = max(0.0, t - ts)
                return p0 + (v0 + 0.5 * a * tau) * tau, v0 + a * tau
        return self._end_p, 0.0

    def _hold(self, x: float) -> None:
        """No plan: the trajectory rests at ``x`` and nothing needs stepping."""
        self._segs = []
        self._seg_i = 0
        self._end_p = self._r = x
        self._rv = 0.0
        self._profile_end = self._now
        self._idle = True

    def _stop_now(self) -> None:
        self._v = self._acc = 0.0
        self._velocity_loop = False
        self._hold(self._x)

    def _torque_on(self) -> None:
        if self._regs[11] == OperatingMode.POSITION:
            self._fold_one_turn()
        self._stop_now()
        self._regs[64] = 1
        self._regs[116] = self._present_position()
        self._wd_ref = self._now
        self._arm_watchdog()

    def _torque_off(self) -> None:
        self._regs[64] = 0
        self._stop_now()
        self._wd_deadline = math.inf

    def _trip(self) -> None:
        self._regs[98] = _TRIPPED
        self._wd_deadline = math.inf
        self._stop_now()

    def _arm_watchdog(self) -> None:
        wd = self._regs[98]
        if self._regs[64] and wd > 0:
            self._wd_deadline = self._wd_ref + wd * _WATCHDOG_UNIT_S
        else:
            self._wd_deadline = math.inf

    def _fold_one_turn(self) -> None:
        self._x = float(math.floor(self._x + 0.5) % PULSES_PER_REV)
        self._stop_now()

    def _check_supply(self) -> None:
        """Latch the voltage/temperature errors the present state deserves; rescale speed."""
        if not self._regs[34] <= round(self._volts * 10.0) <= self._regs[32]:
            self._latch(0x01)
        if round(self._temp_c) > self._regs[31]:
            self._latch(0x04)
        self._update_speed_limit()

    def _latch(self, bits: int) -> None:
        self._regs[70] |= bits
        if bits & self._regs[63]:
            self._torque_off()

    def _update_speed_limit(self) -> None:
        m = self.model
        scale = max(0.0, self._volts / m.nominal_voltage_v) * self._regs[36] / PWM_FULL_SCALE
        self._vmax = m.no_load_speed_pulse_s * scale

    def _reset_eeprom(self, keep: tuple[int, ...]) -> None:
        for f in self.model.fields:
            if f.addr < EEPROM_END and f.addr not in keep and f.addr != 6:
                self._regs[f.addr] = f.default

    def _reset_ram(self) -> None:
        for f in self.model.fields:
            if f.addr >= EEPROM_END:
                self._regs[f.addr] = f.default

    def _restart(self, t: float) -> None:
        self._reset_ram()
        self._pending = None
        self._torque_off()
        self._fold_one_turn()
        self._regs[116] = self._present_position()
        self._profile_type = ProfileType.STEP
        self._boot_t = t
        self._update_speed_limit()

    # --- dynamic registers (computed on read) ---------------------------------------------
    def _realtime_tick(self) -> int:
        return int((self._now - self._boot_t) * 1000.0 + 1e-6) % 32768

    def _moving(self) -> int:
        return 1 if abs(self._present_velocity()) > self._regs[24] else 0

    def _moving_status(self) -> int:
        status = self._profile_type << 4
        if self._now < self._profile_end:
            status |= 0x02
        if (
            self._regs[11] in _POSITION_MODES
            and self._regs[64]
            and abs(self._regs[116] - self._present_position()) <= self.model.in_position_pulses
        ):
            status |= 0x01
        return status

    def _current_a(self) -> float:
        if not self._regs[64] or (self._v == 0.0 and self._acc == 0.0):
            return 0.0
        m = self.model
        rad_per_pulse = 2.0 * math.pi / PULSES_PER_REV
        kt = m.stall_torque_nm / m.stall_current_a
        amps = m.reflected_inertia_kgm2 * self._acc * rad_per_pulse / kt
        if self._v:
            amps += math.copysign(m.running_current_a, self._v)
        return max(-m.stall_current_a, min(m.stall_current_a, amps))

    def _present_current(self) -> int:
        m = self.model
        amps = self._current_a()
        if m.current_unit_ma is None:  # Present Load, 0.1 % of stall
            return round(1000.0 * amps / m.stall_current_a)
        units = round(amps * 1000.0 / m.current_unit_ma)
        limit = self._regs.get(38, units)
        return max(-limit, min(limit, units))

    def _present_pwm(self) -> int:
        if not self._regs[64]:
            return 0
        m = self.model
        v_full = m.no_load_speed_pulse_s * self._volts / m.nominal_voltage_v
        duty = self._v / v_full + self._current_a() / m.stall_current_a * 0.1
        pwm = round(duty * PWM_FULL_SCALE)
        limit = self._regs[36]
        return max(-limit, min(limit, pwm))

    def _present_velocity(self) -> int:
        return round(self._v / PULSE_PER_S_PER_VELOCITY_UNIT)

    def _present_position(self) -> int:
        return math.floor(self._x + 0.5) + self._regs[20]

    def _velocity_trajectory(self) -> int:
        return round(self._rv / PULSE_PER_S_PER_VELOCITY_UNIT)

    def _position_trajectory(self) -> int:
        return math.floor(self._r + 0.5) + self._regs[20]

    def _present_input_voltage(self) -> int:
        return round(self._volts * 10.0)

    def _present_temperature(self) -> int:
        return round(self._temp_c)

    def __repr__(self) -> str:
        return (
            f"VirtualServo({self.model.name!r}, id={self.id}, t={self._now:.6f}, "
            f"position={self._present_position()}, torque={self._regs[64]})"
        )
