"""The bus-free half of a tick: the safety filter, the targets, the springs.

One tick k at show time t = k·period::

    stepper.command()            x -> cmd through the safety filter (the only way to the wire)
    ... the bus: cmd out, present back ...
    first = stepper.sample(t)    u(t), u'(t) into the buffers
    stepper.advance(t, first)    x, v -> tick k+1 (substeps; the target held over each)

The loop, its warm-up and the offline preview (``hilsim tracks``) all step a show through
this one class, so the preview runs the show's parts exactly as the loop does.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from hilsim._types import FloatArray
from hilsim.dynamics.integrators import Integrator
from hilsim.safety import SafetyEvent, SafetyFilter
from hilsim.show.parts import Parts
from hilsim.targets import TargetSet

__all__ = ["Stepper", "TickBuffers"]

#: u(t) and u'(t) as the integrator takes them: tuples of floats, or the buffers themselves
Sampled = tuple[tuple[float, ...] | FloatArray, tuple[float, ...] | FloatArray]

_Part = TypeVar("_Part")


@dataclass
class TickBuffers:
    """The tick's joint-frame arrays, each shaped (n,), in rad and rad/s.

    ``u`` target, ``x`` spring position, ``v`` spring velocity, ``cmd`` the command after the
    safety filter, ``present`` the servos' positions read back, ``du`` the target's rate.
    The first five are consecutive views of ``block``, in a telemetry row's order.
    """

    block: FloatArray
    u: FloatArray
    x: FloatArray
    v: FloatArray
    cmd: FloatArray
    present: FloatArray
    du: FloatArray

    @classmethod
    def zeros(cls, n: int) -> TickBuffers:
        block = np.zeros(5 * n)
        u, x, v, cmd, present = (block[k * n : (k + 1) * n] for k in range(5))
        return cls(block, u, x, v, cmd, present, np.zeros(n))

    def copy(self) -> TickBuffers:
        n = len(self.du)
        out = TickBuffers.zeros(n)
        out.block[:] = self.block
        out.du[:] = self.du
        return out


class Stepper:
    """Steps one show's safety filter, targets and springs on one set of buffers.

    Args:
        safety: the filter every command passes; None (a warm-up copy that failed): skipped.
        targets: one track per joint; None: the springs follow the target held in ``u``.
        integrator: the springs; None: not stepped.
        h: the integration step (s); ``substeps`` steps make one tick.
        buffers: the arrays the tick works in.
        live_targets: the targets are a show's live inputs (never sampled outside the show).
    """

    def __init__(
        self,
        safety: SafetyFilter | None,
        targets: TargetSet | None,
        integrator: Integrator | None,
        h: float,
        substeps: int,
        buffers: TickBuffers,
        *,
        live_targets: bool = False,
    ) -> None:
        self.safety, self.targets, self.integrator = safety, targets, integrator
        self.h, self.substeps, self.buffers = h, substeps, buffers
        self.live_targets = live_targets

    @classmethod
    def of(cls, parts: Parts, buffers: TickBuffers) -> Stepper:
        """The stepper of a show's parts."""
        loop = parts.rig.loop
        return cls(
            parts.safety,
            parts.targets,
            parts.integrator,
            loop.h_s,
            loop.substeps,
            buffers,
            live_targets=parts.director is not None,
        )

    def command(self) -> SafetyEvent | None:
        """``cmd`` from ``x`` through the safety filter; its event, if any."""
        b = self.buffers
        return None if self.safety is None else self.safety.filter(b.x, b.cmd)

    def sample(self, t: float) -> Sampled:
        """u(t) into ``u`` (recorded) and both as the springs take them."""
        targets, b = self.targets, self.buffers
        if targets is None:
            return (tuple(b.u.tolist()), (0.0,) * len(b.u))
        return targets.sample_into(t, b.u)

    def advance(self, t: float, first: Sampled | None = None) -> None:
        """The springs from ``t`` to the next tick, the target held over each substep.
        ``first``: u(t), u'(t) when :meth:`sample` gave them this tick."""
        integ, b, h = self.integrator, self.buffers, self.h
        if integ is None:
            return
        targets = self.targets
        if first is None:  # (a catch-up tick: nothing recorded, the arrays as they are)
            if targets is None:
                first = self.sample(t)
            else:
                targets.sample(t, b.u, b.du)
                first = (b.u, b.du)
        integ.step(b.x, b.v, h, t, first)
        for j in range(1, self.substeps):
            ts = t + j * h
            if targets is not None:
                targets.sample(ts, b.u, b.du)
            integ.step(b.x, b.v, h, ts, (b.u, b.du))

    def scratch_copy(self) -> Stepper:
        """A stepper on copies of these parts and buffers, for a warm-up: nothing the show
        keeps is touched. A part that cannot be copied is None; a show's live targets and
        the targets' tracks are not copied (a new set over the same pure tracks)."""
        targets = self.targets
        fresh = None
        if targets is not None and not self.live_targets and type(targets) is TargetSet:
            fresh = TargetSet(targets.tracks, targets.names)
        return Stepper(
            _copy(self.safety),
            fresh,
            _copy(self.integrator),
            self.h,
            self.substeps,
            self.buffers.copy(),
        )


def _copy(part: _Part) -> _Part | None:
    """A deep copy of ``part``, or None where deepcopy refuses it."""
    try:
        return copy.deepcopy(part)
    except Exception:  # whatever deepcopy refuses: that part is not warmed
        return None
