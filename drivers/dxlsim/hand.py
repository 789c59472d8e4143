"""A person's hand on a torque-off servo's horn: how a test teaches a figure by hand.

On a real Dynamixel with Torque Enable 0 the motor is free: a person turns the horn and the
encoder reports where it is (Present Position, Present Velocity). :meth:`VirtualServo.hand
<drivers.dxlsim.servo.VirtualServo.hand>` gives the emulated servo that hand: a function of
the emulator's time ``t`` (s) that says where the horn is held, in the units and frame of
Present Position(132):

* **raw pulses**, a float (4096 per turn), Homing Offset(20) included: exactly the number the
  servo would report, rounded as the servo rounds its own horn;
* **multi-turn**: the hand may turn the horn past a full turn; the servo counts the turns
  while torque is off (Present Position 4100 is one turn and 4 pulses), and torque on in
  Position Control Mode folds it back into one turn, as it does for any motion
  (``docs/dxlsim.md``, torque); the value is kept in the register's signed 32-bit range;
* ``None``: the hand is off the horn at that time; the horn stays where it was left (no
  coasting, Present Velocity 0) until the hand holds it again.

Present Velocity(128) is the hand's speed, the backward difference over one motion step
(``step_s``). Present Current and PWM stay 0: the motor is not driven.

With torque **on** the hand does nothing: in this model a person cannot back-drive a holding
servo (an external torque is :meth:`~drivers.dxlsim.servo.VirtualServo.set_load`, which
only slows or stalls it). When torque goes off again, the hand (still attached) takes the
horn from where the motor left it at the next instant the servo sees.

Reaching a servo in a test: build the :class:`~drivers.dxlsim.bus.DxlBus` yourself and
register it (``register_bus("teach", dx)``, then ``DynamixelBus.open("dxlsim://teach", ...)``)
and call ``dx.servo(1).hand(fn)``; or from a bus opened on any ``dxlsim://`` URL, its port's
emulated bus: ``bus.link.port.ser.bus.servo(1).hand(fn)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from .motion import Motion

#: where a hand holds the horn at time t (Present Position, pulses), or None: let go
HandFn = Callable[[float], "float | None"]
_LO, _HI = -(2**31), 2**31 - 1  # Present Position is a signed 32-bit register


class Hand:
    """``position_fn(t)`` -> Present Position (pulses, float) or None; see the module
    docstring. ``step_s``: the servo's motion step (the velocity's difference interval)."""

    def __init__(self, position_fn: HandFn, step_s: float) -> None:
        if not callable(position_fn):
            raise ValueError(f"a hand is a function of time, got {position_fn!r}")
        self.fn = position_fn
        self.step_s = float(step_s)

    def _at(self, t: float) -> float | None:
        p = self.fn(t)
        if p is None:
            return None
        p = float(p)
        if not math.isfinite(p):
            raise ValueError(f"the hand put the horn at {p!r} at t={t!r}: not a position")
        return min(max(p, _LO), _HI)

    def move(self, mo: Motion) -> None:
        """Put the horn where the hand holds it at ``mo.now`` (the caller checks that torque
        is off). Let go: the horn stops where it is."""
        t = mo.now
        p = self._at(t)
        if p is None:
            if mo.v:
                mo.stop_now()
            return
        before = self._at(t - self.step_s)
        x = p - mo.offset()  # the actual frame (Present Position = actual + Homing Offset)
        mo.x = x
        mo.hold(x)  # no trajectory: the motor is free
        mo.v = 0.0 if before is None else (p - before) / self.step_s
        mo.acc = 0.0
