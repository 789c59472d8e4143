"""Before a real-time show's tick 0: the tick's own code run a few times on copies of its
parts, so that the first ticks cost what later ones do.

CPython specialises a function's bytecode only after it has run a few times, and the CPU's
caches hold the start-up's work: a 1 kHz show's first ticks overran without this
(``docs/performance.md`` has the figures).

Nothing the show keeps is touched. The stepper's parts are copies
(:meth:`~hilsim.show.stepper.Stepper.scratch_copy`): a part that cannot be copied is left
out, a show's live targets are not sampled, and no byte goes to the bus. It runs after the
start-up's last packet, so it stops at :data:`BUDGET_S`. A virtual-time run has no deadline
to miss and is not warmed.
"""

from __future__ import annotations

import time

from hilsim.rig.joint_map import JointMap
from hilsim.show.stepper import Stepper
from hilsim.telemetry.format import TickRecord

__all__ = ["BUDGET_S", "WARM_UP_TICKS", "warm_up"]

#: how many times: CPython (3.11) quickens a function after a few calls, then specialises
#: its instructions as they run
WARM_UP_TICKS = 16
#: the most the runs may take: the servos' Bus Watchdog counts the silence
BUDGET_S = 0.010


def warm_up(
    stepper: Stepper,
    joint_map: JointMap,
    telemetry: object,
    rec: TickRecord,
    n: int = WARM_UP_TICKS,
) -> str | None:
    """Run the tick's stages but the bus ``n`` times on a scratch copy of ``stepper``, within
    :data:`BUDGET_S`; the telemetry's books are warmed on ``rec`` if it offers ``warm_up``.
    Returns None, or what failed: the show then starts cold."""
    try:
        end = time.perf_counter() + BUDGET_S
        scratch = stepper.scratch_copy()
        cmd = scratch.buffers.cmd
        for _ in range(n):
            scratch.command()
            joint_map.to_joint_list(joint_map.to_servo_list(cmd.tolist()))
            scratch.advance(0.0, scratch.sample(0.0))
            if time.perf_counter() > end:
                break
        warm_books = getattr(telemetry, "warm_up", None)
        if warm_books is not None:
            warm_books(rec, n)
    except Exception as exc:  # a warm-up must never keep a show from starting
        return f"{type(exc).__name__}: {exc}"
    return None
