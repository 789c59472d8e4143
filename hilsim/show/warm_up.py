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

import copy
import time
from typing import TypeVar

from hilsim._types import FloatArray
from hilsim.dynamics.integrators import TargetLike
from hilsim.rig.joint_map import JointMap
from hilsim.safety import SafetyEvent
from hilsim.show.stepper import Sampled, Samples, Stepper
from hilsim.targets import TargetSet
from hilsim.telemetry.format import TickRecord

__all__ = ["BUDGET_S", "WARM_UP_TICKS", "warm_up"]

#: how many times: CPython (3.11) quickens a function after a few calls, then specialises
#: its instructions as they run
WARM_UP_TICKS = 16
#: the most the runs may take: the servos' Bus Watchdog counts the silence
BUDGET_S = 0.010

T = TypeVar("T")


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
        scratch = _scratch(stepper)
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


def _scratch(stepper: Stepper) -> Stepper:
    """A stepper on copies of ``stepper``'s parts and buffers: nothing the show keeps is
    touched. A part deepcopy refuses is left out (the filter lets every command through, the
    springs stand still); the targets are a new set over the same pure tracks (copying them
    would take as long as the animation is), or a target held still for a show's live ones."""
    buffers = stepper.buffers.copy()
    targets = stepper.targets
    scratch_targets: Samples
    if stepper.live_targets or type(targets) is not TargetSet:
        scratch_targets = _Held(buffers.u)
    else:
        scratch_targets = TargetSet(targets.tracks, targets.names)
    return Stepper(
        _copy(stepper.safety) or _NoFilter(),
        scratch_targets,
        _copy(stepper.integrator) or _NoSprings(),
        stepper.h,
        stepper.substeps,
        buffers,
    )


def _copy(part: T) -> T | None:
    """A deep copy of ``part``, or None where deepcopy refuses it."""
    try:
        return copy.deepcopy(part)
    except Exception:  # whatever deepcopy refuses: that part is not warmed
        return None


class _NoFilter:
    def filter(self, desired_rad: FloatArray, out: FloatArray, /) -> SafetyEvent | None:
        return None


class _NoSprings:
    def step(self, x: FloatArray, v: FloatArray, h: float, t: float, target: TargetLike, /) -> None:
        return None


class _Held:
    """The target where it is, still."""

    def __init__(self, u: FloatArray) -> None:
        self._held: Sampled = (tuple(u.tolist()), (0.0,) * len(u))

    def sample(self, t: float, out_pos: FloatArray, out_vel: FloatArray | None = None, /) -> None:
        out_pos[:] = self._held[0]
        if out_vel is not None:
            out_vel[:] = 0.0

    def sample_into(self, t: float, out_pos: FloatArray, /) -> Sampled:
        return self._held
