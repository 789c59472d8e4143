"""Named clips played on a show's timeline: one joint's target as the clips that
drive it, one after another.

A *clip* is a set of tracks, one per joint it drives, each with its own time from 0 (a
Bottango animation, a lip-sync line, keyframes). A *cue* starts a clip at a show time,
once or looped; the next cue cuts to its clip. :class:`ClipSequence` is one joint's target
through the cues: the track of the clip playing, at the clip's own time; where the clip
playing does not drive this joint (or before the first cue), the joint's ``base`` track.

A cut is a step in the *target*; it never reaches the servo as one. The joint's spring
follows the new target from where it is, and the safety filter limits the command to the
joint's speed and acceleration, so going from one clip to another - or from the pose the
figure stands in - is always within the joint's limits (Bottango's own playback jumps).
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field

from hilsim.targets.tracks import Track


@dataclass(frozen=True)
class Cue:
    """Start ``clip`` at show time ``at_s``; ``loop``: play it again from its start at its
    end (a clip with no end plays on either way)."""

    at_s: float
    clip: str
    loop: bool = False

    def __post_init__(self) -> None:
        if not (isinstance(self.at_s, int | float) and math.isfinite(self.at_s) and self.at_s >= 0):
            raise ValueError(f"a cue's at_s must be a finite time >= 0 s, got {self.at_s!r}")


@dataclass(frozen=True, eq=False)
class ClipSequence(Track):
    """One joint's target through the show's cues (module docstring).

    ``entries``: per cue, in time order, ``(at_s, track or None, loop)`` - None where the
    cue's clip does not drive this joint (then ``base``). Times must strictly increase.
    """

    base: Track
    entries: tuple[tuple[float, Track | None, bool], ...]
    _times: list[float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        entries = tuple(self.entries)
        times = [at for at, _, _ in entries]
        if any(b <= a for a, b in itertools.pairwise(times)):
            raise ValueError(f"cue times must strictly increase, got {times}")
        object.__setattr__(self, "entries", entries)
        object.__setattr__(self, "_times", times)

    def sample(self, t: float) -> tuple[float, float]:
        i = bisect_right(self._times, t) - 1
        if i < 0:
            return self.base.sample(t)
        at, track, loop = self.entries[i]
        if track is None:
            return self.base.sample(t)
        local = t - at
        end = track.duration
        if loop and end is not None and end > 0 and local >= end:
            local = math.fmod(local, end)
        return track.sample(local)

    @property
    def duration(self) -> float | None:
        """The end of the last cue's clip (None if it loops or never ends, or if ``base``
        never ends and the last clip leaves this joint to it)."""
        if not self.entries:
            return self.base.duration
        at, track, loop = self.entries[-1]
        if track is None:
            return None if self.base.duration is None else max(at, self.base.duration)
        if loop or track.duration is None:
            return None
        return at + track.duration


def sequence_for(
    joint: str, base: Track, cues: Sequence[Cue], clips: dict[str, dict[str, Track]]
) -> ClipSequence:
    """``joint``'s :class:`ClipSequence` through ``cues`` over ``clips`` (clip name -> joint
    name -> track). KeyError names a cue's unknown clip."""
    entries = []
    for cue in sorted(cues, key=lambda c: c.at_s):
        if cue.clip not in clips:
            raise KeyError(f"cue at {cue.at_s:g} s: no clip {cue.clip!r} (clips: "
                           f"{', '.join(sorted(clips)) or 'none'})")  # fmt: skip
        entries.append((float(cue.at_s), clips[cue.clip].get(joint), cue.loop))
    return ClipSequence(base, tuple(entries))
