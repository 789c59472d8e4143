"""Cues, live joint values and releases from the program that runs the show (``Show.cue``,
``Show.set_joint``, ``Show.release``): the same hand-over as the network inputs, without a
network.

Any thread may call :meth:`Controls.cue`, :meth:`Controls.set_joint` and
:meth:`Controls.release`; the director takes what is there once per tick
(:meth:`Controls.poll`), never waiting. A value reaches the servo only through its joint's
spring and the safety filter, like every input; a release hands the joint back to the show's
layers through the director's :class:`~hilsim.live.live_layer.LiveLayer`, the one place that
takes and releases joints (a panel or another input uses the same).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field

from hilsim.live.inbox import MAX_LIVE_DEG
from hilsim.live.show_spec import API_CUE

__all__ = ["Controls", "ControlsPoll"]


@dataclass
class ControlsPoll:
    """What arrived since the last tick: joint values (deg), cue triggers and releases (a
    joint, or None for all). Releases come before the values: a value set after a release
    takes the joint again; one set before it is dropped with it."""

    values: dict[str, float] = field(default_factory=dict)
    triggers: list[str] = field(default_factory=list)
    releases: list[str | None] = field(default_factory=list)


_NOTHING = ControlsPoll()  # shared, never changed: what a tick with nothing new polls


class Controls:
    """The show's controls for the program running it.

    Args:
        joints: the joints a value may be set for.
        cues: the show file's cue names (none: :meth:`cue` refuses every name).
    """

    def __init__(self, joints: Iterable[str], cues: Iterable[str] = ()) -> None:
        self.joints = frozenset(joints)
        self.cues = frozenset(cues)
        self._lock = threading.Lock()
        self._values: dict[str, float] = {}
        self._cues: list[str] = []
        self._releases: list[str | None] = []

    def cue(self, name: str) -> None:
        """Fire cue ``name`` at the next tick. KeyError for a cue the show does not have."""
        if name not in self.cues:
            have = ", ".join(sorted(self.cues)) or "none"
            raise KeyError(f"no cue {name!r} in this show (cues: {have})")
        with self._lock:
            self._cues.append(name)

    def set_joint(self, joint: str, deg: float) -> None:
        """Drive ``joint`` at ``deg`` degrees from the next tick on. KeyError for an unknown
        joint; ValueError for a value that is not a finite number within the live range."""
        if joint not in self.joints:
            raise KeyError(f"no joint {joint!r} (joints: {', '.join(sorted(self.joints))})")
        value = float(deg)
        if not (math.isfinite(value) and -MAX_LIVE_DEG <= value <= MAX_LIVE_DEG):
            raise ValueError(f"{joint}: {deg!r} is not a joint angle in degrees")
        with self._lock:
            self._values[joint] = value

    def release(self, joint: str | None = None) -> None:
        """Hand ``joint`` (None: every joint) back from its live value to the show's cues,
        clips and idle at the next tick, through its spring. KeyError for an unknown joint."""
        if joint is not None and joint not in self.joints:
            raise KeyError(f"no joint {joint!r} (joints: {', '.join(sorted(self.joints))})")
        with self._lock:
            if joint is None:
                self._values.clear()
            else:
                self._values.pop(joint, None)
            if joint not in self._releases:  # once each: bounded by the joints + 1
                self._releases.append(joint)

    def poll(self, t: float) -> ControlsPoll:
        """Everything set since the last poll (the latest value per joint); ``t`` is the show
        time (the inputs' common signature)."""
        if not (self._values or self._cues or self._releases):  # the usual tick: no lock
            return _NOTHING
        with self._lock:
            values, cues, releases = self._values, self._cues, self._releases
            self._values, self._cues, self._releases = {}, [], []
        return ControlsPoll(values, [f"{API_CUE}{c}" for c in cues], releases)
