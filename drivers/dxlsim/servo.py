"""One virtual Dynamixel X-series servo: control table, instruction semantics, motion.

The device side only, no wire: the bus (:mod:`drivers.dxlsim.dispatch`) calls one method
here per servo and encodes the status packet from the returned ``(error, params)``. Every
method takes the time ``t`` (s, non-decreasing); the servo holds no clock. The error byte
is the error number (:class:`StatusError`) with bit 7 (:data:`ALERT`) set while Hardware
Error Status (addr 70) is non-zero.

The servo owns a :class:`~drivers.dxlsim.registers.RegisterFile` (the control table) and a
:class:`~drivers.dxlsim.motion.Motion` (the horn and its Present values). This module holds
the instructions, the side effects of writes, the Bus Watchdog and the injected faults.
The choices made where the e-Manual is silent, and what is not modelled:
``docs/dxlsim.md``.
"""

from __future__ import annotations

import math

import drivers.protocol2.control_table as ct
from drivers.protocol2.control_table import OperatingMode, StatusError

from . import registers as rg
from .dual_axis import share_module
from .hand import Hand, HandFn
from .models import ServoModel, get_model
from .motion import Motion, MotionState, torque_on_by_goal
from .profile import ProfileType
from .registers import ALERT as ALERT  # re-exported
from .registers import RegisterFile, Updates
from .servo_setup import apply_initial, goal_write_range
from .thermal import THERMAL_STALL_RISE_K, THERMAL_TIME_CONSTANT_S, thermal_step

CLEAR_MULTI_TURN = b"\x01\x44\x58\x4c\x22"
FACTORY_RESET_ALL, FACTORY_RESET_KEEP_ID, FACTORY_RESET_KEEP_ID_BAUD = 0xFF, 0x01, 0x02
BACKUP_STORE, BACKUP_RESTORE, BACKUP_MAGIC = 0x01, 0x02, b"CTRL"  # 43 54 52 4C
#: Limits that can put the present supply state outside: a write re-checks it.
_SUPPLY_LIMITS = frozenset(
    (rg.TEMPERATURE_LIMIT, rg.MAX_VOLTAGE_LIMIT, rg.MIN_VOLTAGE_LIMIT, rg.PWM_LIMIT)
)
_INPUT_VOLTAGE_ERROR = int(ct.HardwareError.INPUT_VOLTAGE)
_OVERHEATING_ERROR = int(ct.HardwareError.OVERHEATING)
#: the longest stretch heated at one motor current while the horn moves (s): a 100 Hz show's
#: period, so a show at 100 Hz or faster never has its packets' gaps split
THERMAL_STEP_S = 0.010


_PROTOCOL_2 = 2  # Protocol Type (addr 13) value of Protocol 2.0
_ID, _BAUD_RATE, _PROTOCOL_TYPE = rg.ID, rg.BAUD_RATE, rg.PROTOCOL_TYPE
_FIRMWARE_VERSION = rg.FIRMWARE_VERSION
_BUS_WATCHDOG, _TORQUE_ENABLE = rg.BUS_WATCHDOG, rg.TORQUE_ENABLE
_TEMPERATURE_LIMIT, _HARDWARE_ERROR_STATUS = rg.TEMPERATURE_LIMIT, rg.HARDWARE_ERROR_STATUS
_WATCHDOG_UNIT_S = ct.WATCHDOG_UNIT_S
_exp = math.exp
_GOAL_POSITION, _OPERATING_MODE = rg.GOAL_POSITION, rg.OPERATING_MODE
_MIN_POSITION_LIMIT, _MAX_POSITION_LIMIT = rg.MIN_POSITION_LIMIT, rg.MAX_POSITION_LIMIT
_WATCHDOG_TRIPPED, _POSITION_MODE = ct.WATCHDOG_TRIPPED, int(OperatingMode.POSITION)


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
        self._boot_t = float(t)
        self._reg = RegisterFile(m, fw)
        self._regs = self._reg.values  # the same dict: the servo's fast path to the values
        self._mo = Motion(m, self._regs, t, step_s)
        self._temp_c = self._ambient_c = m.ambient_temperature_c
        self._stall_a = m.stall_current_a
        self._goal_addr, self._goal_lo, self._goal_hi = goal_write_range(m)  # write()'s short way
        self._wd_ref = self._mo.now
        self._wd_deadline = math.inf
        self._pending: tuple[int, bytes] | None = None
        self._hand: Hand | None = None
        self._step_s = float(step_s)
        #: the other axis in the same case (2XL430: :func:`pair_axes`), sharing one
        #: communication module
        self.partner: VirtualServo | None = None
        self._reg.dynamic.update(self._mo.present_getters())
        self._reg.dynamic[rg.REALTIME_TICK] = self._realtime_tick
        self._reg.dynamic[rg.PRESENT_TEMPERATURE] = self._present_temperature
        self._derive()
        apply_initial(self, id, m.baud_index(baud), rdt_units, overrides)

    # --- what the bus needs ----------------------------------------------------------------
    #: ID (addr 7)
    id: int
    #: the line rate at which this servo hears Protocol 2.0 packets; 0 when Protocol Type
    #: (addr 13) selects another protocol (1.0, or the X330's S.BUS/iBUS/RC-PWM), which
    #: dxlsim does not speak: the servo is then deaf to the bus, as a real one is to 2.0
    listening_baud: int
    #: Return Delay Time, s (addr 9 × 2 µs)
    return_delay_s: float
    #: Fast Sync/Bulk Read available on this firmware
    supports_fast_read: bool

    def _derive(self) -> None:
        """The four values above, asked of every servo on every packet, kept as plain
        attributes: computed again after whatever may change their registers (a Write
        other than the goal's short way, a restart, the other axis's module)."""
        regs, m = self._regs, self.model
        self.id = regs[_ID]
        protocol_2 = regs[_PROTOCOL_TYPE] == _PROTOCOL_2
        self.listening_baud = m.baud_rates[regs[_BAUD_RATE]] if protocol_2 else 0
        self.return_delay_s = regs[rg.RETURN_DELAY_TIME] * 2e-6
        self.supports_fast_read = regs[_FIRMWARE_VERSION] >= m.fast_read_min_firmware

    @property
    def secondary_id(self) -> int | None:
        """Secondary (Shadow) ID (addr 12), None when disabled (> 252)."""
        sid = self._regs[rg.SECONDARY_ID]
        return sid if sid <= 252 else None

    @property
    def baud(self) -> int:
        """Baud rate, bps (from addr 8)."""
        return self.model.baud_rates[self._regs[rg.BAUD_RATE]]

    @property
    def status_return_level(self) -> int:
        """0: reply to Ping only, 1: Ping and Read, 2: all (addr 68)."""
        return self._regs[rg.STATUS_RETURN_LEVEL]

    @property
    def firmware(self) -> int:
        return self._regs[rg.FIRMWARE_VERSION]

    @property
    def torque_enabled(self) -> bool:
        return self._regs[rg.TORQUE_ENABLE] == 1

    @property
    def alert(self) -> bool:
        """Hardware Error Status (addr 70) is non-zero: bit 7 of every error byte."""
        return self._regs[rg.HARDWARE_ERROR_STATUS] != 0

    @property
    def hardware_error_status(self) -> int:
        return self._regs[rg.HARDWARE_ERROR_STATUS]

    @property
    def operating_mode(self) -> OperatingMode:
        return OperatingMode(self._regs[rg.OPERATING_MODE])

    @property
    def now(self) -> float:
        """Latest time seen, s."""
        return self._mo.now

    @property
    def motion(self) -> MotionState:
        """Unrounded motion state at the last grid step (Present Position's frame)."""
        return self._mo.state()

    # --- time ------------------------------------------------------------------------------
    def advance(self, t: float) -> None:
        """Evolve temperature, motion and watchdog up to ``t`` (s); the motion in fixed steps
        of ``step_s``, the temperature at the motor current of each stretch of at most
        :data:`THERMAL_STEP_S` while the horn moves (its current changes as it does: a long
        gap between packets is not heated at the current of its start).

        Cost: O(1) when nothing moves; about a microsecond per step otherwise.
        """
        mo = self._mo
        while t - mo.now > THERMAL_STEP_S and (mo.v or mo.acc):
            self._advance(mo.now + THERMAL_STEP_S)
        self._advance(t)

    def _advance(self, t: float) -> None:
        mo = self._mo
        now = mo.now
        if t <= now:
            if t < now:
                if t < now - 1e-9:
                    raise ValueError(f"time went back: {t!r} < {now!r}")
                return
            if t <= self._wd_deadline:
                # The same moment again (a servo is advanced per touch, read and write):
                # no time to heat over, the watchdog is not due, and the motion has been
                # run to ``now`` already (every move of ``mo.now`` is followed by run_to).
                return
        else:
            # The first-order thermal model over t - now at the present motor current (see
            # drivers.dxlsim.thermal); latches Overheating. No current at ambient: nothing
            # to do (thermal_step would return the temperature as it is).
            amps = mo.current_a()
            celsius = self._temp_c
            if amps or celsius != self._ambient_c:
                temp = thermal_step(self.model, celsius, amps, t - now)
                if temp != celsius:
                    self._temp_c = temp
                    limit = self._regs[_TEMPERATURE_LIMIT]
                    if temp > limit - 1 and round(temp) > limit:  # (the first is implied)
                        self._latch(_OVERHEATING_ERROR)
        if t > self._wd_deadline:
            mo.run_to(self._wd_deadline)
            mo.now = self._wd_deadline
            self._trip()
        mo.now = t
        mo.run_to(t)
        if self._hand is not None and not self._regs[_TORQUE_ENABLE]:
            self._hand.move(mo)

    def touch(self, t: float) -> None:
        """A valid instruction packet for this servo arrived at ``t``: restart the Bus
        Watchdog timer."""
        mo = self._mo
        now = mo.now
        dt = t - now  # > 0 exactly when t > now
        if 0.0 < dt <= THERMAL_STEP_S and t <= self._wd_deadline and self._hand is None:
            # advance(t) for a packet of a running show, inline: one stretch, no watchdog
            # due, no hand. The thermal step is thermal_step()'s, term for term.
            amps = mo.current_a()
            celsius = self._temp_c
            if amps or celsius != self._ambient_c:
                frac = amps / self._stall_a
                target = self._ambient_c + THERMAL_STALL_RISE_K * frac * frac
                if celsius != target:
                    temp = target + (celsius - target) * _exp(-dt / THERMAL_TIME_CONSTANT_S)
                    if temp != celsius:
                        self._temp_c = temp
                        limit = self._regs[_TEMPERATURE_LIMIT]
                        if temp > limit - 1 and round(temp) > limit:
                            self._latch(_OVERHEATING_ERROR)
            mo.now = t
            mo.run_to(t)
        else:
            self.advance(t)
        self._wd_ref = t
        regs = self._regs  # _arm_watchdog(), inline: every packet to the servo comes here
        wd = regs[_BUS_WATCHDOG]
        if regs[_TORQUE_ENABLE] and wd > 0:
            self._wd_deadline = t + wd * _WATCHDOG_UNIT_S
        else:
            self._wd_deadline = math.inf

    # --- instructions --------------------------------------------------------------------
    def ping(self, t: float) -> tuple[int, bytes]:
        """Ping: ``(error, model number LE16 + firmware version)``."""
        self.advance(t)
        regs = self._regs
        params = regs[rg.MODEL_NUMBER].to_bytes(2, "little") + bytes((regs[rg.FIRMWARE_VERSION],))
        return self._reg.alert, params

    def read(self, addr: int, length: int, t: float) -> tuple[int, bytes]:
        """Read ``length`` bytes from ``addr``: ``(error, data)``; data is ``b""`` on error.

        Gaps read as 0; a span past the table end is an Access Error; length < 1 a Data
        Length Error.
        """
        if t != self._mo.now or t > self._wd_deadline:  # else advance(t) has nothing to do
            self.advance(t)
        err, data = self._reg.read(addr, length)
        return (ALERT if self._regs[_HARDWARE_ERROR_STATUS] else 0) | err, data  # + Alert

    def write(self, addr: int, data: bytes, t: float) -> int:
        """Write ``data`` at ``addr`` atomically; returns the error byte."""
        if t != self._mo.now or t > self._wd_deadline:  # else advance(t) has nothing to do
            self.advance(t)
        regs = self._regs
        if addr == self._goal_addr and len(data) == 4 and regs[_TORQUE_ENABLE]:
            # A goal position with torque on (every Sync Write of goals) that validate()
            # accepts: stored and planned as _apply() would; anything else takes the long way.
            value = int.from_bytes(data, "little", signed=True)
            if (
                self._goal_lo <= value <= self._goal_hi
                and regs[_BUS_WATCHDOG] != _WATCHDOG_TRIPPED
                and (
                    regs[_OPERATING_MODE] != _POSITION_MODE
                    or regs[_MIN_POSITION_LIMIT] <= value <= regs[_MAX_POSITION_LIMIT]
                )
                and self.partner is None
            ):
                regs[_GOAL_POSITION] = value
                self._mo.plan_goal()
                return ALERT if regs[_HARDWARE_ERROR_STATUS] else 0
        err, updates = self._reg.validate(addr, data)
        partner = self.partner
        if (
            partner is not None
            and not err
            and any(f.addr == rg.ID and value == partner.id for f, value in updates)
        ):
            err = StatusError.DATA_LIMIT  # 2xl430-w250.md: both axes one ID -> 0x06
        if not err:
            self._apply(updates)
            self._derive()
            if partner is not None:
                share_module(self)
        return err | (ALERT if self._regs[_HARDWARE_ERROR_STATUS] else 0)  # + Alert

    def reg_write(self, addr: int, data: bytes, t: float) -> int:
        """Reg Write: validate like Write, keep it pending, set Registered Instruction."""
        self.advance(t)
        err, _ = self._reg.validate(addr, data)
        if not err:
            self._pending = (addr, bytes(data))
            self._regs[rg.REGISTERED_INSTRUCTION] = 1
        return err | self._reg.alert

    def action(self, t: float) -> int:
        """Action: apply the pending Reg Write (re-validated now); Instruction Error if none
        (protocol2.md error table: "Action has been used without Reg Write")."""
        self.advance(t)
        if self._pending is None:
            return StatusError.INSTRUCTION | self._reg.alert
        addr, data = self._pending
        self._pending = None
        self._regs[rg.REGISTERED_INSTRUCTION] = 0
        return self.write(addr, data, t)

    def reboot(self, t: float) -> int:
        """Reboot: RAM to defaults, hardware error cleared, torque off; the horn stays.

        Returns the error byte of the reply sent before rebooting (Alert as it was).
        """
        self.advance(t)
        err = self._reg.alert
        self._restart(t)
        return err

    def factory_reset(self, option: int, t: float) -> int:
        """Factory Reset: 0xFF everything, 0x01 all but ID, 0x02 all but ID and baud.

        Other options: Data Range Error; torque on: Access Error. Then reboots.
        """
        self.advance(t)
        alert = self._reg.alert
        keep = {
            FACTORY_RESET_ALL: (),
            FACTORY_RESET_KEEP_ID: (rg.ID,),
            FACTORY_RESET_KEEP_ID_BAUD: (rg.ID, rg.BAUD_RATE),
        }.get(option)
        if keep is None:
            return alert | StatusError.DATA_RANGE
        if self._regs[rg.TORQUE_ENABLE]:
            return alert | StatusError.ACCESS
        self._reg.reset_eeprom(keep)
        self._restart(t)
        share_module(self)
        return alert

    def backup(self, params: bytes, t: float) -> int:
        """Control Table Backup (0x20): ``01 43 54 52 4C`` stores the backup, ``02 43 54 52
        4C`` restores its EEPROM part and reboots (the reply leaves first). Only with torque
        off (else Result Fail) and on firmware that has it (else Instruction Error)."""
        self.advance(t)
        alert = self._reg.alert
        if self.firmware < self.model.backup_min_firmware:
            return alert | StatusError.INSTRUCTION
        if len(params) != 1 + len(BACKUP_MAGIC):
            return alert | StatusError.DATA_LENGTH
        if bytes(params[1:]) != BACKUP_MAGIC or params[0] not in (BACKUP_STORE, BACKUP_RESTORE):
            return alert | StatusError.DATA_RANGE
        if self._regs[rg.TORQUE_ENABLE]:
            return alert | StatusError.RESULT_FAIL
        if params[0] == BACKUP_STORE:
            self._reg.store_backup()
        elif self._reg.restore_eeprom():
            self._restart(t)
            share_module(self)
        else:
            return alert | StatusError.RESULT_FAIL  # nothing stored to restore
        return alert

    def clear(self, params: bytes, t: float) -> int:
        """Clear (0x10). ``01 44 58 4C 22`` folds Present Position into one turn (only
        while stopped, else Result Fail)."""
        self.advance(t)
        alert = self._reg.alert
        if len(params) != len(CLEAR_MULTI_TURN):
            return alert | StatusError.DATA_LENGTH
        if bytes(params) != CLEAR_MULTI_TURN:
            return alert | StatusError.DATA_RANGE
        mo = self._mo
        if mo.moving() or mo.now < mo.profile_end:
            return alert | StatusError.RESULT_FAIL
        mo.fold_one_turn()
        self._regs[rg.GOAL_POSITION] = mo.present_position()
        return alert

    # --- faults the bus injects ----------------------------------------------------------
    def inject_hardware_error(self, bits: int, t: float) -> None:
        """Latch Hardware Error Status bits (0x01 voltage, 0x04 overheating, 0x08 encoder,
        0x10 electrical shock, 0x20 overload); bits in Shutdown (63) cut torque."""
        self.advance(t)
        self._latch(bits & 0xFF)

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
        self._mo.volts = float(volts)
        self._check_supply()

    def set_temperature(self, celsius: float, t: float | None = None) -> None:
        """Internal temperature, °C (from ``t``, s, if given). Above Temperature Limit it
        latches the overheating error."""
        if t is not None:
            self.advance(t)
        self._temp_c = float(celsius)
        self._check_supply()

    def set_load(self, torque_nm: float, t: float | None = None) -> None:
        """Steady external torque on the horn, N·m (from ``t``, s, if given); positive
        pushes towards lower positions. It slows the horn, costs holding current (which
        heats the motor) and at the stall torque stalls it: see :mod:`drivers.dxlsim.motion`."""
        if t is not None:
            self.advance(t)
        self._mo.load_nm = float(torque_nm)
        self._mo.update_speed_limit()

    def hand(self, position_fn: HandFn | None, t: float | None = None) -> None:
        """A person's hand on the horn from ``t`` (s, if given) on: while torque is off the horn
        is at ``position_fn(t)``, Present Position in pulses (float, multi-turn, Homing Offset
        included), or stays where it was left where that is None; ``None`` takes the hand
        away. No effect while torque is on. See :mod:`drivers.dxlsim.hand`."""
        if t is not None:
            self.advance(t)
        hand = self._hand = None if position_fn is None else Hand(position_fn, self._step_s)
        if not self._regs[_TORQUE_ENABLE]:  # taken away: the horn stays where it was left
            if hand is None:
                self._mo.stop_now()
            else:
                hand.move(self._mo)

    # --- side effects of writes ----------------------------------------------------------
    def _apply(self, updates: Updates) -> None:
        regs = self._regs
        mo = self._mo
        if len(updates) == 1 and updates[0][0].addr in rg.GOAL_ADDRS and regs[_TORQUE_ENABLE]:
            # The loop below for one goal with torque on (every Sync Write of goals): no
            # Torque On by Goal Update, the goal is stored and the motion replanned.
            regs[updates[0][0].addr] = updates[0][1]
            mo.plan_goal()
            return
        replan = False
        for f, value in updates:
            a = f.addr
            old = regs[a]
            if a == rg.TORQUE_ENABLE:
                if value and not old:
                    self._torque_on()
                elif old and not value:
                    self._torque_off()
                continue
            if not regs[rg.TORQUE_ENABLE] and torque_on_by_goal(regs, self.model, a):
                self._torque_on()  # Drive Mode bit 3: a goal with torque off turns it on
            regs[a] = value
            if a == rg.OPERATING_MODE and value != old:
                regs[rg.PROFILE_ACCELERATION] = regs[rg.PROFILE_VELOCITY] = 0
                if value == OperatingMode.POSITION:
                    mo.fold_one_turn()
                    regs[rg.GOAL_POSITION] = mo.present_position()
            elif a == rg.BUS_WATCHDOG:
                if value == 0:
                    self._wd_deadline = math.inf
                self._wd_ref = mo.now
                self._arm_watchdog()
            elif a in _SUPPLY_LIMITS:
                self._check_supply()  # narrower limits can put the present state outside
            elif a in rg.GOAL_ADDRS:
                replan = True
        if replan and regs[rg.TORQUE_ENABLE]:
            mo.plan_goal()

    def _torque_on(self) -> None:
        mo = self._mo
        if self._regs[rg.OPERATING_MODE] == OperatingMode.POSITION:
            mo.fold_one_turn()
        mo.stop_now()
        self._regs[rg.TORQUE_ENABLE] = 1
        self._regs[rg.GOAL_POSITION] = mo.present_position()
        self._wd_ref = mo.now
        self._arm_watchdog()

    def _torque_off(self) -> None:
        self._regs[rg.TORQUE_ENABLE] = 0
        self._mo.stop_now()
        self._wd_deadline = math.inf

    def _trip(self) -> None:
        self._regs[rg.BUS_WATCHDOG] = ct.WATCHDOG_TRIPPED
        self._wd_deadline = math.inf
        self._mo.stop_now()

    def _arm_watchdog(self) -> None:
        regs = self._regs
        wd = regs[_BUS_WATCHDOG]
        if regs[_TORQUE_ENABLE] and wd > 0:
            self._wd_deadline = self._wd_ref + wd * _WATCHDOG_UNIT_S
        else:
            self._wd_deadline = math.inf

    def _check_supply(self) -> None:
        """Latch the voltage/temperature errors the present state deserves; rescale speed."""
        regs = self._regs
        if (
            not regs[rg.MIN_VOLTAGE_LIMIT]
            <= round(self._mo.volts * 10.0)
            <= regs[rg.MAX_VOLTAGE_LIMIT]
        ):
            self._latch(_INPUT_VOLTAGE_ERROR)
        if round(self._temp_c) > regs[rg.TEMPERATURE_LIMIT]:
            self._latch(_OVERHEATING_ERROR)
        self._mo.update_speed_limit()

    def _latch(self, bits: int) -> None:
        self._regs[rg.HARDWARE_ERROR_STATUS] |= bits
        if bits & self._regs[rg.SHUTDOWN]:
            self._torque_off()

    def _restart(self, t: float) -> None:
        mo = self._mo
        self._reg.reset_ram()
        startup_torque = self._reg.boot_ram()  # Startup Configuration (60), if the model has it
        self._pending = None
        self._torque_off()
        mo.fold_one_turn()
        self._regs[rg.GOAL_POSITION] = mo.present_position()
        mo.profile_type = ProfileType.STEP
        self._boot_t = t
        mo.update_speed_limit()
        self._derive()
        if startup_torque:
            self._torque_on()

    # --- registers computed on read the motion does not own ------------------------------
    def _realtime_tick(self) -> int:
        return int((self._mo.now - self._boot_t) * 1000.0 + 1e-6) % 32768

    def _present_temperature(self) -> int:
        return round(self._temp_c)

    def __repr__(self) -> str:
        return (
            f"VirtualServo({self.model.name!r}, id={self.id}, t={self._mo.now:.6f}, "
            f"position={self._mo.present_position()}, torque={self._regs[rg.TORQUE_ENABLE]})"
        )
