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

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hilsim._types import FloatArray
from hilsim.dynamics.integrators import TargetLike
from hilsim.safety import SafetyEvent
from hilsim.show.parts import Parts

__all__ = ["Stepper", "TickBuffers"]

#: u(t) and u'(t) as tuples of floats, as the tick hands them to the springs
Sampled = tuple[tuple[float, ...], tuple[float, ...]]


class Filters(Protocol):
    """What the stepper needs of the safety filter."""

    def filter(self, desired_rad: FloatArray, out: FloatArray, /) -> SafetyEvent | None: ...


class Samples(Protocol):
    """What the stepper needs of the targets."""

    def sample(
        self, t: float, out_pos: FloatArray, out_vel: FloatArray | None = None, /
    ) -> None: ...

    def sample_into(self, t: float, out_pos: FloatArray, /) -> Sampled: ...


class Steps(Protocol):
    """What the stepper needs of the springs."""

    def step(
        self, x: FloatArray, v: FloatArray, h: float, t: float, target: TargetLike, /
    ) -> None: ...


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
        out = TickBuffers.zeros(len(self.du))
        out.block[:] = self.block
        out.du[:] = self.du
        return out


class Stepper:
    """Steps one show's safety filter, targets and springs on one set of buffers.

    Args:
        safety: the filter every command passes.
        targets: one track per joint.
        integrator: the springs.
        h: the integration step (s); ``substeps`` steps make one tick.
        buffers: the arrays the tick works in.
        live_targets: the targets are a show's live inputs (never sampled outside the show).
    """

    def __init__(
        self,
        safety: Filters,
        targets: Samples,
        integrator: Steps,
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
        return self.safety.filter(b.x, b.cmd)

    def sample(self, t: float) -> Sampled:
        """u(t) into ``u`` (recorded), and u, u' as the springs take them."""
        return self.targets.sample_into(t, self.buffers.u)

    def advance(self, t: float, first: Sampled | None = None) -> None:
        """The springs from ``t`` to the next tick, the target held over each substep.
        ``first``: u(t), u'(t) when :meth:`sample` gave them this tick."""
        b, h = self.buffers, self.h
        if first is None:  # (a catch-up tick: nothing recorded, the arrays as they are)
            self.targets.sample(t, b.u, b.du)
            self.integrator.step(b.x, b.v, h, t, (b.u, b.du))
        else:
            self.integrator.step(b.x, b.v, h, t, first)
        if self.substeps > 1:
            self._substeps(t)

    def _substeps(self, t: float) -> None:
        b, h, targets, integ = self.buffers, self.h, self.targets, self.integrator
        for j in range(1, self.substeps):
            ts = t + j * h
            targets.sample(ts, b.u, b.du)
            integ.step(b.x, b.v, h, ts, (b.u, b.du))
