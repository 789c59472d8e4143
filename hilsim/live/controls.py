"""Cues and live joint values from the program that runs the show (``Show.cue``,
``Show.set_joint``): the same hand-over as the network inputs, without a network.

Any thread may call :meth:`Controls.cue` and :meth:`Controls.set_joint`; the director takes
what is there once per tick (:meth:`Controls.poll`), never waiting. A value reaches the servo
only through its joint's spring and the safety filter, like every input.
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
    """What arrived since the last tick: joint values (deg) and cue triggers."""

    values: dict[str, float] = field(default_factory=dict)
    triggers: list[str] = field(default_factory=list)
    #: joints handed back to the show (their live value dropped), in the order asked
    released: list[str] = field(default_factory=list)


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
        self._released: list[str] = []

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
            if joint in self._released:
                self._released.remove(joint)

    def release(self, joint: str | None = None) -> None:
        """Hand ``joint`` (None: every joint) back to the show from the next tick on: its
        live value is dropped and it follows its cues, clips or idle again, through its
        spring. KeyError for an unknown joint."""
        if joint is not None and joint not in self.joints:
            raise KeyError(f"no joint {joint!r} (joints: {', '.join(sorted(self.joints))})")
        names = sorted(self.joints) if joint is None else [joint]
        with self._lock:
            for name in names:
                self._values.pop(name, None)
                if name not in self._released:
                    self._released.append(name)

    def poll(self, t: float) -> ControlsPoll:
        """Everything set since the last poll (the latest value per joint); ``t`` is the show
        time (the inputs' common signature)."""
        if not (self._values or self._cues or self._released):  # the usual tick: no lock
            return _NOTHING
        with self._lock:
            values, cues, released = self._values, self._cues, self._released
            self._values, self._cues, self._released = {}, [], []
        return ControlsPoll(values, [f"{API_CUE}{c}" for c in cues], released)
