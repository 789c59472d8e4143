"""Before a real-time show's tick 0: the tick's own code run a few times on copies of its
parts, so that the first ticks cost what later ones do.

A 1 kHz show's first ticks ran cold: CPython specialises a function's bytecode only after
it has run a few times, and the CPU's caches held the start-up's work. scale16 (16 joints at
1 kHz, 2026-11-27, runs of 8 taken in turns): tick 0 overran in 16 of 16 cold and 3 of 16
warm in one hour, 15 of 16 cold and 9 of 16 warm in a slower one; its stages' medians sim
113-186 µs cold, 71-110 warm, safety 69-116 and 30-50, telemetry 79-127 and 46-78 (21-34,
13-22 and 10-16 in later ticks). It takes ~1-1.5 ms before the show.

Nothing the show keeps is touched: the safety filter, the springs and the telemetry's
books are deep copies (a part that cannot be copied is left out), their methods called as
their classes define them (an instance's own override, such as a test's spy, is not
called), the targets are a new set over the show's tracks sampled at t = 0 (a show's live
targets are not sampled), the arrays are copies, and no byte goes to the bus (the bus stage
stays as cold as the start-up's reads leave it). It runs after the start-up's last packet,
so it is short: the copies scale with the joints, not the animation, and the runs stop at
:data:`BUDGET_S`. A virtual-time run has no deadline to miss and is not warmed.
"""

from __future__ import annotations

import copy
import time
from typing import TYPE_CHECKING

from hilsim.targets import TargetSet

if TYPE_CHECKING:
    from hilsim.loop import HilLoop

#: how many times: CPython (3.11) quickens a function after a few calls, then specialises
#: its instructions as they run
WARM_UP_TICKS = 16
#: the most the stages' runs may take (they run after the start-up's last packet: the
#: servos' Bus Watchdog, 100 ms in the shipped rigs, counts the silence)
BUDGET_S = 0.010


def _copy(part):
    """A deep copy of ``part``, or None where it cannot be copied: that part is then not
    warmed."""
    try:
        return copy.deepcopy(part)
    except Exception:  # whatever deepcopy refuses: not warmed, nothing else changes
        return None


def _targets(loop: HilLoop) -> TargetSet | None:
    """A new set over the show's own tracks (their ``sample`` is a pure function of t, and
    copying them would take as long as the animation is: 0.1-1 s for ten minutes of CSV
    curves, a silence the servos' Bus Watchdog would end), or None for a show, whose
    director's live inputs are not to be sampled before tick 0."""
    targets = loop.targets
    if loop.director is not None or type(targets) is not TargetSet:
        return None
    return TargetSet(targets.tracks, targets.names)


def warm_up(loop: HilLoop, n: int = WARM_UP_TICKS) -> str | None:
    """Run the tick's stages but the bus ``n`` times on copies of ``loop``'s parts, within
    :data:`BUDGET_S` (a part that cannot be copied is left out: without targets the springs
    follow a target held still). Returns None, or what failed, having done nothing the show
    keeps: the show then starts cold, as it did before."""
    try:
        end = time.perf_counter() + BUDGET_S
        safety, integ = _copy(loop.safety), _copy(loop.integrator)
        targets = _targets(loop)
        x, v, cmd, u = (a.copy() for a in (loop.x, loop.v, loop.cmd, loop.u))
        jmap, h = loop.map, loop.rig.loop.h_s
        held = (tuple(u.tolist()), (0.0,) * len(u))
        for _ in range(n):
            if safety is not None:
                type(safety).filter(safety, x, cmd)
            jmap.to_joint_list(jmap.to_servo_list(cmd.tolist()))
            target = held if targets is None else targets.sample_into(0.0, u)
            if integ is not None:
                type(integ).step(integ, x, v, h, 0.0, target)
            if time.perf_counter() > end:
                break
        scratch = getattr(loop.telemetry, "warm_up", None)
        if scratch is not None:
            scratch(loop.rec, n)
    except Exception as exc:  # a warm-up must never keep a show from starting
        return f"{type(exc).__name__}: {exc}"
    return None
