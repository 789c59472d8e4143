"""The motor's temperature: a first-order thermal model driven by the motor current.

Estimates, not e-Manual figures: the manual gives only Temperature Limit(31), Present
Temperature(146) and the Overheating bit of Hardware Error Status(70) / Shutdown(63)
(``_includes/en/dxl/control_table_alarm_shutdown.md``), no thermal constants. The servo
(:mod:`drivers.dxlsim.servo`) steps it whenever time advances, at the current
:meth:`drivers.dxlsim.motion.Motion.current_a` of that moment, starting at the model's
ambient 30 °C.
"""

from __future__ import annotations

import math

from .models import ServoModel

# First order:
#   dT/dt = (T_ambient + THERMAL_STALL_RISE_K·(I/I_stall)² - T) / THERMAL_TIME_CONSTANT_S
# i.e. copper loss I²R against one thermal resistance to the ambient. A held stall would
# settle 100 K above ambient (130 °C from 30 °C), so it crosses the default 80 °C limit
# (XM/XH430) after τ·ln 2 ≈ 83 s and 72 °C (XL430) after ≈ 65 s; only more than 71 % of the
# stall current, held, ever trips 80 °C; the running current of a moving horn (5 % of stall)
# settles 0.3 K above ambient: an idle or lightly loaded servo never overheats.
THERMAL_STALL_RISE_K = 100.0
THERMAL_TIME_CONSTANT_S = 300.0


def thermal_step(model: ServoModel, celsius: float, amps: float, dt: float) -> float:
    """Temperature after ``dt`` s at a steady motor current ``amps`` (exact for a constant
    current; see THERMAL_STALL_RISE_K)."""
    frac = amps / model.stall_current_a
    target = model.ambient_temperature_c + THERMAL_STALL_RISE_K * frac * frac
    if celsius == target:
        return celsius
    return target + (celsius - target) * math.exp(-dt / THERMAL_TIME_CONSTANT_S)
