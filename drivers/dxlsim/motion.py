"""The motion of one virtual servo's horn, evaluated lazily on a fixed time grid.

Evaluated on a grid of ``step_s`` (:meth:`Motion.run_to` catches up; nothing moving
means a jump)::

    Goal Position -> profile planner -> Position/Velocity Trajectory (140/136)
                  -> horn: first-order lag (tau = model.lag_time_constant_s),
                     speed-limited to the no-load speed scaled by voltage and PWM Limit
                  -> Present Position/Velocity (132/128)

The profile is planned analytically when a goal arrives (:mod:`drivers.dxlsim.profile`);
only the lag is stepped. Positions are kept in the actual frame (Present Position = actual +
Homing Offset). The :class:`Motion` reads the servo's registers (``regs``, shared with its
:class:`~drivers.dxlsim.registers.RegisterFile`) and never writes them; the servo owns it and
decides when to plan, hold or stop.

The e-Manual rules modelled here (time-based profile, Following Error, Homing Offset, a steady
load): ``docs/dxlsim.md`` (the horn's motion). What is not modelled: the same page.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

from drivers.protocol2.control_table import DRIVE_MODE, POSITION_MODES, OperatingMode

from .models import (
    PULSE_PER_S2_PER_ACCEL_UNIT,
    PULSE_PER_S_PER_VELOCITY_UNIT,
    PULSES_PER_REV,
    PWM_FULL_SCALE,
    ServoModel,
)
from .profile import (
    ProfileType,
    Segment,
    _segments_end,
    plan_profile,
    plan_time_profile,
    plan_velocity,
)
from .registers import (
    CURRENT_LIMIT,
    DRIVE_MODE_TIME_PROFILE,
    DRIVE_MODE_TORQUE_ON_BY_GOAL,
    FIRMWARE_VERSION,
    GOAL_CURRENT,
    GOAL_POSITION,
    GOAL_PWM,
    GOAL_VELOCITY,
    HARDWARE_ERROR_STATUS,
    HOMING_OFFSET,
    MOVING,
    MOVING_STATUS,
    MOVING_THRESHOLD,
    OPERATING_MODE,
    POSITION_TRAJECTORY,
    PRESENT_CURRENT,
    PRESENT_INPUT_VOLTAGE,
    PRESENT_POSITION,
    PRESENT_PWM,
    PRESENT_VELOCITY,
    PROFILE_ACCELERATION,
    PROFILE_VELOCITY,
    PWM_LIMIT,
    SHUTDOWN,
    TIME_PROFILE_MIN_FIRMWARE,
    TORQUE_ENABLE,
    VELOCITY_LIMIT,
    VELOCITY_TRAJECTORY,
)

_RAD_PER_PULSE = 2.0 * math.pi / PULSES_PER_REV
_POSITION_MODE, _STEP = OperatingMode.POSITION, ProfileType.STEP  # one lookup (~0.15 µs each)
_copysign = math.copysign
_SETTLE_PULSES = 1e-3  # horn this close to a finished trajectory: snap and go idle
_GRID_EPS = 1e-7  # grid steps are counted with this slack against float round-off
_DRIVE_MODE = DRIVE_MODE.addr
HOMING_OFFSET_POSITION_MODE_LIMIT = 1024  # e-Manual control_table_homingoffset.md NOTE
#: Moving Status bit 3 threshold, pulses between Position Trajectory(140) and the horn.
#: The e-Manual gives no number. 128 pulses = 1/32 turn = 11.25°: about five times the
#: largest lag a healthy horn shows in this model (``v_nl·tau`` at full no-load speed:
#: 25 pulses for an XM430-W350 at 12 V, 56 for an XL330-M288 at 5 V), so a profile the
#: motor can follow never sets it; and of the order of hilsim's own host-side tracking
#: tolerance (``tracking_tolerance_deg`` default 10°, docs/rig.md).
FOLLOWING_ERROR_PULSES = 128
#: The goal register that commands each Operating Mode (the "given command" of Drive Mode
#: bit 3; Goal Current in Current-based Position mode is a limit, not the command).
COMMAND_GOAL: dict[int, int] = {
    OperatingMode.CURRENT: GOAL_CURRENT,
    OperatingMode.VELOCITY: GOAL_VELOCITY,
    OperatingMode.POSITION: GOAL_POSITION,
    OperatingMode.EXTENDED_POSITION: GOAL_POSITION,
    OperatingMode.CURRENT_BASED_POSITION: GOAL_POSITION,
    OperatingMode.PWM: GOAL_PWM,
}


def torque_on_by_goal(regs: dict[int, int], model: ServoModel, addr: int) -> bool:
    """Drive Mode bit 3, Torque On by Goal Update (e-Manual ``control_table_drivemode.md``):
    with Torque Enable 0, a write of the goal that commands the present Operating Mode turns
    torque on and is performed. Not with a Shutdown error latched: Torque Enable would be
    refused (Result Fail) there too, so the goal is stored and nothing moves."""
    if not regs[_DRIVE_MODE] & DRIVE_MODE_TORQUE_ON_BY_GOAL:
        return False
    # "available from firmware V45" (V46 on XL330/XC330): the model's backup_min_firmware,
    # the same gate the register file applies to writing the bit
    min_fw = model.backup_min_firmware
    return (
        regs[FIRMWARE_VERSION] >= min_fw
        and COMMAND_GOAL.get(regs[OPERATING_MODE]) == addr
        and not regs[HARDWARE_ERROR_STATUS] & regs[SHUTDOWN]
    )


class MotionState(NamedTuple):
    """Unrounded motion state in Present Position's frame: pulse and pulse/s."""

    position: float
    velocity: float
    trajectory_position: float
    trajectory_velocity: float


class Motion:
    """Horn and trajectory of one servo of ``model`` from time ``t`` (s), on a grid of
    ``step_s``. ``regs`` is the servo's register dict (read only here)."""

    # the trajectory (set by hold() and by a goal): pieces, next due, end, reference, at rest
    segs: list[Segment]
    seg_i: int
    end_p: float
    r: float
    rv: float
    idle: bool

    def __init__(self, model: ServoModel, regs: dict[int, int], t: float, step_s: float) -> None:
        self.model = m = model
        self._regs = regs
        self._dt = float(step_s)
        self._inv_dt = 1.0 / self._dt
        self._t0 = float(t)  # origin of the motion grid
        self.k = 0  # last grid step done
        self.now = float(t)  # latest time seen (the servo moves it)
        self.x = 2048.0  # horn position, actual frame (pulse)
        self.v = 0.0
        self.acc = 0.0
        self.volts = m.nominal_voltage_v
        self.load_nm = 0.0  # steady external torque on the horn (see the module docstring)
        self.velocity_loop = False  # True in modes 0/1/16: the horn tracks a velocity
        self.hold(self.x)
        self.profile_type = ProfileType.STEP
        self._alpha = 1.0 - math.exp(-self._dt / m.lag_time_constant_s)
        self._kt = m.stall_torque_nm / m.stall_current_a  # torque constant, N·m/A
        # the model's figures current_a() uses, one attribute away
        self._inertia, self._running_a = m.reflected_inertia_kgm2, m.running_current_a
        self._stall_a = m.stall_current_a
        self.update_speed_limit()

    def present_getters(self) -> dict[int, Callable[[], int]]:
        """The registers computed from the motion on read: address -> getter."""
        return {
            MOVING: self.moving,
            MOVING_STATUS: self.moving_status,
            PRESENT_PWM: self.present_pwm,
            PRESENT_CURRENT: self.present_current,
            PRESENT_VELOCITY: self.present_velocity,
            PRESENT_POSITION: self.present_position,
            VELOCITY_TRAJECTORY: self.velocity_trajectory,
            POSITION_TRAJECTORY: self.position_trajectory,
            PRESENT_INPUT_VOLTAGE: self.present_input_voltage,
        }

    def state(self) -> MotionState:
        """Unrounded motion state at the last grid step (Present Position's frame)."""
        off = self.offset()
        return MotionState(self.x + off, self.v, self.r + off, self.rv)

    # long on purpose: one pass of the motion profile, in the e-Manual's order
    def run_to(self, t: float) -> None:  # noqa: PLR0912, PLR0915
        k_end = int((t - self._t0) * self._inv_dt + _GRID_EPS)
        k = self.k
        if k_end <= k:
            return
        if self.idle:
            self.k = k_end
            return
        if not self.velocity_loop and self.seg_i >= len(self.segs):
            # No trajectory left (a step, or a profile over), Position modes: the loop below with
            # r = end_p every step and only the last two dx kept (v, acc computed as it does).
            inv_dt = self._inv_dt
            alpha = self._alpha
            settle = _SETTLE_PULSES
            neg_settle = -settle
            lim = self._step_lim
            neg_lim = -lim
            x = self.x
            r = self.end_p
            steps = k_end - k
            dx = prev = 0.0
            e = r - x  # the error, computed once a step and used twice
            for _ in range(steps):
                prev, dx = dx, e * alpha
                if dx > lim:
                    dx = lim
                elif dx < neg_lim:
                    dx = neg_lim
                x += dx
                e = r - x
                if neg_settle < e < settle:
                    self.k, self.x, self.v, self.acc = k_end, r, 0.0, 0.0
                    self.hold(r)
                    return
            self.acc = (dx * inv_dt - (prev * inv_dt if steps > 1 else self.v)) * inv_dt
            self.k = k_end
            self.x = x
            self.v = dx * inv_dt
            self.r = r
            self.rv = 0.0
            return
        dt, inv_dt, t0, alpha = self._dt, self._inv_dt, self._t0, self._alpha
        vmax = self._vmax
        lim = vmax * dt
        x, v, acc = self.x, self.v, self.acc
        segs, i = self.segs, self.seg_i
        n = len(segs)
        end_p = self.end_p
        velocity_loop = self.velocity_loop
        r, rv = self.r, self.rv
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
            self.k = k_end
            self.x = x
            self.v = self.acc = 0.0
            self.hold(x)
            return
        self.k = k
        self.x, self.v, self.acc = x, v, acc
        self.seg_i = i
        self.r, self.rv = r, rv

    def plan_goal(self) -> None:
        """Start a new trajectory for the present goal registers at ``now``."""
        regs = self._regs
        mode = regs[OPERATING_MODE]
        t = self.now
        if mode in POSITION_MODES:
            self.velocity_loop = False
            goal = float(regs[GOAL_POSITION] - self.offset())
            vel = regs[PROFILE_VELOCITY]
            if vel == 0:  # a step (a cap cannot raise 0): nothing to plan, nowhere to start
                self.segs = []
                self.seg_i = 0
                self.end_p = goal
                self.profile_end = t
                self.profile_type = _STEP
                self.idle = False
                return
            accel = regs[PROFILE_ACCELERATION] * PULSE_PER_S2_PER_ACCEL_UNIT or math.inf
            time_based = self.time_based()
            if not time_based and regs[VELOCITY_LIMIT] > 0:
                vel = min(vel, regs[VELOCITY_LIMIT])  # Velocity Limit caps the profile (> 0)
            p0, v0 = self.trajectory_at(t)
            if time_based:  # Profile Velocity = span, Profile Acceleration = t1, in ms
                span, acc = vel / 1000.0, regs[PROFILE_ACCELERATION] / 1000.0
                segs, kind = plan_time_profile(t, p0, v0, goal, span, acc)
            else:
                v_max = vel * PULSE_PER_S_PER_VELOCITY_UNIT
                segs, kind = plan_profile(t, p0, v0, goal, v_max, accel)
            end_p = goal
        else:
            self.velocity_loop = True
            accel = regs[PROFILE_ACCELERATION] * PULSE_PER_S2_PER_ACCEL_UNIT or math.inf
            p0, v0 = self.trajectory_at(t)
            if mode == OperatingMode.VELOCITY:
                target = regs[GOAL_VELOCITY] * PULSE_PER_S_PER_VELOCITY_UNIT
                kind = ProfileType.TRAPEZOIDAL if regs[PROFILE_ACCELERATION] else ProfileType.STEP
                if self.time_based() and regs[PROFILE_ACCELERATION] and target != v0:
                    # time-based: t1 = Profile Acceleration(108) ms whatever the step
                    accel = abs(target - v0) * 1000.0 / regs[PROFILE_ACCELERATION]
            else:  # duty (or, unloaded, current) as a fraction of the no-load speed
                if mode == OperatingMode.PWM:
                    frac = regs[GOAL_PWM] / PWM_FULL_SCALE
                else:
                    frac = regs[GOAL_CURRENT] / max(1, self.model.field("current_limit").hi)
                m = self.model
                target = frac * m.no_load_speed_pulse_s * self.volts / m.nominal_voltage_v
                accel, kind = math.inf, ProfileType.STEP
            segs = plan_velocity(t, p0, v0, target, accel)
            end_p = _segments_end(segs, p0)
        self.segs, self.seg_i, self.end_p = segs, 0, end_p
        # the profile is over when the last finite piece ends (velocity modes end endless)
        ends = [te for _, te, _, _, _ in segs[-2:] if te != math.inf]
        self.profile_end = ends[-1] if ends else t
        self.profile_type = kind
        self.idle = False

    def time_based(self) -> bool:
        """Drive Mode bit 2 selects the time-based profile (firmware 42 and later)."""
        regs = self._regs
        return bool(
            regs[_DRIVE_MODE] & DRIVE_MODE_TIME_PROFILE
            and regs[FIRMWARE_VERSION] >= TIME_PROFILE_MIN_FIRMWARE
        )

    def offset(self) -> int:
        """Homing Offset(20) in effect: ignored in Position Control Mode outside ±1024."""
        regs = self._regs
        off = regs[HOMING_OFFSET]
        if not off:  # the usual case: 0 whatever the mode
            return 0
        if (
            regs[OPERATING_MODE] == _POSITION_MODE
            and not -HOMING_OFFSET_POSITION_MODE_LIMIT <= off <= HOMING_OFFSET_POSITION_MODE_LIMIT
        ):
            return 0
        return off

    def trajectory_at(self, t: float) -> tuple[float, float]:
        """Trajectory (position, velocity) at time ``t`` from the current plan."""
        if self.idle:
            return self.r, 0.0
        for ts, te, p0, v0, a in self.segs[self.seg_i :]:
            if t < te:
                tau = max(0.0, t - ts)
                return p0 + (v0 + 0.5 * a * tau) * tau, v0 + a * tau
        return self.end_p, 0.0

    def hold(self, x: float) -> None:
        """No plan: the trajectory rests at ``x`` and nothing needs stepping."""
        self.segs = []
        self.seg_i = 0
        self.end_p = self.r = x
        self.rv = 0.0
        self.profile_end = self.now
        self.idle = True

    def stop_now(self) -> None:
        self.v = self.acc = 0.0
        self.velocity_loop = False
        self.hold(self.x)

    def fold_one_turn(self) -> None:
        self.x = float(math.floor(self.x + 0.5) % PULSES_PER_REV)
        self.stop_now()

    def update_speed_limit(self) -> None:
        m = self.model
        scale = max(0.0, self.volts / m.nominal_voltage_v) * self._regs[PWM_LIMIT] / PWM_FULL_SCALE
        self._vmax = m.no_load_speed_pulse_s * scale
        if self.load_nm:  # the motor's speed-torque line at this voltage and duty
            stall = m.stall_torque_nm * scale
            self._vmax *= max(0.0, 1.0 - abs(self.load_nm) / stall) if stall > 0.0 else 0.0
        self._step_lim = self._vmax * self._dt  # the most the horn moves in one step

    def moving(self) -> int:
        return 1 if abs(self.present_velocity()) > self._regs[MOVING_THRESHOLD] else 0

    def moving_status(self) -> int:
        status = self.profile_type << 4
        if self.now < self.profile_end:
            status |= 0x02
        regs = self._regs
        if regs[OPERATING_MODE] in POSITION_MODES and regs[TORQUE_ENABLE]:
            if abs(regs[GOAL_POSITION] - self.present_position()) <= self.model.in_position_pulses:
                status |= 0x01
            if self.following_error():
                status |= 0x08
        return status

    def following_error(self) -> bool:
        """Moving Status bit 3: the horn is more than :data:`FOLLOWING_ERROR_PULSES` off
        its position trajectory during a profiled move or while the horn is still catching
        up with its end (Position modes only, see :meth:`moving_status`). A step (Profile
        Velocity 0) has no trajectory to follow: never set."""
        if self.profile_type == _STEP or self.idle:
            return False
        return abs(self.r - self.x) > FOLLOWING_ERROR_PULSES

    def current_a(self) -> float:
        load = self.load_nm
        v = self.v
        if not self._regs[TORQUE_ENABLE] or (v == 0.0 and self.acc == 0.0 and not load):
            return 0.0
        kt = self._kt
        amps = self._inertia * self.acc * _RAD_PER_PULSE / kt
        if v:
            amps += _copysign(self._running_a, v)
        if load:
            amps += load / kt  # holding the external torque
        stall = self._stall_a  # max(-stall, min(stall, amps)) without the two calls
        return stall if amps > stall else -stall if amps < -stall else amps

    def present_current(self) -> int:
        m = self.model
        amps = self.current_a()
        if m.current_unit_ma is None:  # Present Load, 0.1 % of stall
            return round(1000.0 * amps / m.stall_current_a)
        units = round(amps * 1000.0 / m.current_unit_ma)
        limit = self._regs.get(CURRENT_LIMIT, units)
        return max(-limit, min(limit, units))

    def present_pwm(self) -> int:
        if not self._regs[TORQUE_ENABLE]:
            return 0
        m = self.model
        v_full = m.no_load_speed_pulse_s * self.volts / m.nominal_voltage_v
        duty = self.v / v_full + self.current_a() / m.stall_current_a * 0.1
        pwm = round(duty * PWM_FULL_SCALE)
        limit = self._regs[PWM_LIMIT]
        return max(-limit, min(limit, pwm))

    def present_velocity(self) -> int:
        return round(self.v / PULSE_PER_S_PER_VELOCITY_UNIT)

    def present_position(self) -> int:
        return math.floor(self.x + 0.5) + self.offset()

    def velocity_trajectory(self) -> int:
        return round(self.rv / PULSE_PER_S_PER_VELOCITY_UNIT)

    def position_trajectory(self) -> int:
        return math.floor(self.r + 0.5) + self.offset()

    def present_input_voltage(self) -> int:
        return round(self.volts * 10.0)
