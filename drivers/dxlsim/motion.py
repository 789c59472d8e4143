"""The motion of one virtual servo's horn, evaluated lazily on a fixed time grid.

Evaluated on a grid of ``step_s`` (:meth:`Motion.run_to` catches up; nothing moving
means a jump)::

    Goal Position -> profile planner -> Position/Velocity Trajectory (140/136)
                  -> horn: first-order lag (tau = model.lag_time_constant_s),
                     speed-limited to the no-load speed scaled by voltage and PWM Limit
                  -> Present Position/Velocity (132/128)

The profile is planned analytically when a goal arrives (piecewise constant
acceleration, see :mod:`drivers.dxlsim.profile`) so move durations match the e-Manual
formulas; only the lag is stepped. Velocity, PWM and Current modes drive a velocity
trajectory instead and the horn velocity lags it. Positions are kept in the actual frame
(Present Position = actual + Homing Offset). The :class:`Motion` reads the servo's
registers (``regs``, shared with its :class:`~drivers.dxlsim.registers.RegisterFile`)
and never writes them; the servo owns it and decides when to plan, hold or stop.

Not modelled: Drive Mode (reverse, time-based profile) is stored but ignored; Moving
Status bit3 (following error) is never set; Homing Offset's ±1024 validity rule in
Position Control Mode is ignored; in step moves (Profile Velocity 0) only the motor's
speed bounds the horn, not Velocity Limit. Current mode is crude: the goal current
fraction of Current Limit sets a fraction of no-load speed (an unloaded horn).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

from drivers.protocol2.control_table import POSITION_MODES, OperatingMode

from .models import (
    PULSE_PER_S2_PER_ACCEL_UNIT,
    PULSE_PER_S_PER_VELOCITY_UNIT,
    PULSES_PER_REV,
    PWM_FULL_SCALE,
    ServoModel,
)
from .profile import ProfileType, _segments_end, plan_profile, plan_velocity
from .registers import (
    CURRENT_LIMIT,
    GOAL_CURRENT,
    GOAL_POSITION,
    GOAL_PWM,
    GOAL_VELOCITY,
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
    TORQUE_ENABLE,
    VELOCITY_LIMIT,
    VELOCITY_TRAJECTORY,
)

_SETTLE_PULSES = 1e-3  # horn this close to a finished trajectory: snap and go idle
_GRID_EPS = 1e-7  # grid steps are counted with this slack against float round-off


class MotionState(NamedTuple):
    """Unrounded motion state in Present Position's frame: pulse and pulse/s."""

    position: float
    velocity: float
    trajectory_position: float
    trajectory_velocity: float


class Motion:
    """Horn and trajectory of one servo of ``model`` from time ``t`` (s), on a grid of
    ``step_s``. ``regs`` is the servo's register dict (read only here)."""

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
        self.velocity_loop = False  # True in modes 0/1/16: the horn tracks a velocity
        self.hold(self.x)
        self.profile_type = ProfileType.STEP
        self._alpha = 1.0 - math.exp(-self._dt / m.lag_time_constant_s)
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
        off = self._regs[HOMING_OFFSET]
        return MotionState(self.x + off, self.v, self.r + off, self.rv)

    def run_to(self, t: float) -> None:
        k_end = int((t - self._t0) * self._inv_dt + _GRID_EPS)
        k = self.k
        if k_end <= k:
            return
        if self.idle:
            self.k = k_end
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
        p0, v0 = self.trajectory_at(t)
        accel = regs[PROFILE_ACCELERATION] * PULSE_PER_S2_PER_ACCEL_UNIT or math.inf
        if mode in POSITION_MODES:
            self.velocity_loop = False
            goal = float(regs[GOAL_POSITION] - regs[HOMING_OFFSET])
            vel = regs[PROFILE_VELOCITY]
            if regs[VELOCITY_LIMIT] > 0:
                vel = min(vel, regs[VELOCITY_LIMIT])  # Velocity Limit caps the profile
            if vel == 0:
                segs, kind = [], ProfileType.STEP
            else:
                v_max = vel * PULSE_PER_S_PER_VELOCITY_UNIT
                segs, kind = plan_profile(t, p0, v0, goal, v_max, accel)
            end_p = goal
        else:
            self.velocity_loop = True
            if mode == OperatingMode.VELOCITY:
                target = regs[GOAL_VELOCITY] * PULSE_PER_S_PER_VELOCITY_UNIT
                kind = ProfileType.TRAPEZOIDAL if regs[PROFILE_ACCELERATION] else ProfileType.STEP
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

    def moving(self) -> int:
        return 1 if abs(self.present_velocity()) > self._regs[MOVING_THRESHOLD] else 0

    def moving_status(self) -> int:
        status = self.profile_type << 4
        if self.now < self.profile_end:
            status |= 0x02
        if (
            self._regs[OPERATING_MODE] in POSITION_MODES
            and self._regs[TORQUE_ENABLE]
            and abs(self._regs[GOAL_POSITION] - self.present_position())
            <= self.model.in_position_pulses
        ):
            status |= 0x01
        return status

    def current_a(self) -> float:
        if not self._regs[TORQUE_ENABLE] or (self.v == 0.0 and self.acc == 0.0):
            return 0.0
        m = self.model
        rad_per_pulse = 2.0 * math.pi / PULSES_PER_REV
        kt = m.stall_torque_nm / m.stall_current_a
        amps = m.reflected_inertia_kgm2 * self.acc * rad_per_pulse / kt
        if self.v:
            amps += math.copysign(m.running_current_a, self.v)
        return max(-m.stall_current_a, min(m.stall_current_a, amps))

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
        return math.floor(self.x + 0.5) + self._regs[HOMING_OFFSET]

    def velocity_trajectory(self) -> int:
        return round(self.rv / PULSE_PER_S_PER_VELOCITY_UNIT)

    def position_trajectory(self) -> int:
        return math.floor(self.r + 0.5) + self._regs[HOMING_OFFSET]

    def present_input_voltage(self) -> int:
        return round(self.volts * 10.0)
