"""Before a real-time show's tick 0: the tick's own code run a few times on copies of its
parts, so that the first ticks cost what later ones do.

A 1 kHz show's first ticks ran cold: CPython specialises a function's bytecode only after
it has run a few times, and the CPU's caches held the start-up's work. scale16 (16 joints at
1 kHz, 2026-11-27, 16 runs each way): tick 0 overran in 16 of 16 before, its stages sim
113-122 µs, safety 69-83, telemetry 79-85 (medians of two rounds) against 21-24, 13-15 and
10-11 later; 3 of 16 after (sim 71-80, safety 30-31, telemetry 46-54). It costs ~1.5 ms
before the show.

Nothing the show keeps is touched: the safety filter, the targets, the springs and the
telemetry's books are deep copies (a part that cannot be copied, such as a show's live
targets, is left out), their methods called as their classes define them (an instance's
own override, such as a test's spy, is not called), the arrays are copies, and no byte goes
to the bus (the bus stage stays as cold as the start-up's reads leave it). A virtual-time
run has no deadline to miss and is not warmed.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hilsim.loop import HilLoop

#: how many times: CPython 3.11 quickens a function after 8 calls, then specialises its
#: instructions as they run
WARM_UP_TICKS = 16


def _copy(part):
    """A deep copy of ``part``, or None where it cannot be copied (a show's live targets
    hold locks and sockets): that part is then not warmed."""
    try:
        return copy.deepcopy(part)
    except Exception:  # whatever deepcopy refuses: not warmed, nothing else changes
        return None


def warm_up(loop: HilLoop, n: int = WARM_UP_TICKS) -> str | None:
    """Run the tick's stages but the bus ``n`` times on copies of ``loop``'s parts (those
    that cannot be copied are left out: targets that cannot be are held at their value at
    tick 0). Returns None, or what failed, having done nothing the show keeps: the show then
    starts cold, as it did before."""
    try:
        safety, targets, integ = (_copy(p) for p in (loop.safety, loop.targets, loop.integrator))
        x, v, cmd, u = (a.copy() for a in (loop.x, loop.v, loop.cmd, loop.u))
        jmap, h = loop.map, loop.rig.loop.h_s
        held = (tuple(u.tolist()), (0.0,) * len(u))  # a target for the springs if needed
        for _ in range(n):
            if safety is not None:
                type(safety).filter(safety, x, cmd)
            jmap.to_joint_list(jmap.to_servo_list(cmd.tolist()))
            target = held if targets is None else type(targets).sample_into(targets, 0.0, u)
            if integ is not None:
                type(integ).step(integ, x, v, h, 0.0, target)
        scratch = getattr(loop.telemetry, "warm_up", None)
        if scratch is not None:
            scratch(loop.rec, n)
    except Exception as exc:  # a warm-up must never keep a show from starting
        return f"{type(exc).__name__}: {exc}"
    return None
