"""The show runtime: which clip each joint plays, tick by tick, from cues, a timeline and idle.

A show (:mod:`hilsim.live.show_spec` reads its file) has three layers of clips. Per joint, the
first layer whose clip drives that joint wins; a joint no clip drives follows its base track
(the rig's own ``target``)::

    cue        a clip started by a trigger, with lockout, window and ``then``
    timeline   ``[[timeline]]`` clips at fixed show times (looped if asked)
    idle       ``[idle]`` clips in sequence or at random; from the first tick, underneath

It is pure: no threads, no clock reads, no sleeps. The director calls :meth:`ShowRuntime.trigger`
for each trigger, and :meth:`ShowRuntime.tick` once per tick with the show time. The loop then
samples :attr:`ShowRuntime.tracks`. Everything changes only in ``tick``, so a trigger takes
effect at the next tick.

A cut is a step in the *target*, never at a servo: the spring and the safety filter smooth it.
Events are :class:`~hilsim.live.inbox.LiveEvent` (source ``"show"``): ``cue_start``,
``cue_end``, ``cue_ignored``, ``idle_resume``, ``clip_start``, ``clip_end``,
``trigger_unmatched``, ``triggers_dropped``. Their fields: ``docs/live.md`` (Triggers).
"""

from __future__ import annotations

import math
import random
from bisect import bisect_right
from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Any

from hilsim.live.inbox import LiveEvent
from hilsim.live.show_spec import API_CUE, CUE_ADDRESS, Clip, CueSpec, RuntimeSpec
from hilsim.live.triggers import Timers, day_seconds, normalise_key
from hilsim.targets.tracks import Track

#: triggers queued between two ticks beyond this are dropped (counted, one event per tick)
MAX_PENDING = 64
#: clip ends followed within one tick (a chain of very short clips) before restarting at t
MAX_CHAIN = 16
_UNMATCHED_MEMORY = 32


def _order(ev: LiveEvent) -> tuple[float, int]:
    """Events by time; at one time, ends first, then idle resuming, then the rest."""
    return ev.t, _RANK.get(ev.kind, 2)


_RANK = {"cue_end": 0, "clip_end": 0, "idle_resume": 1}


class ShowTrack(Track):
    """One joint's target under the runtime: the source the runtime chose at the last tick,
    sampled at clip-local time ``t + runtime.offset - start`` (wrapped when it loops), or a
    held pose. Allocates nothing beyond the sample's tuple."""

    def __init__(self, runtime: ShowRuntime, base: Track) -> None:
        self._rt, self.base = runtime, base
        self._track, self._start, self._period = base, 0.0, 0.0
        self._held: tuple[float, float] | None = None

    def sample(self, t: float) -> tuple[float, float]:
        held = self._held
        if held is not None:
            return held
        local = t + self._rt.offset - self._start
        period = self._period
        if period > 0.0 and local >= period:
            local = math.fmod(local, period)
        return self._track.sample(local)

    def _set(
        self, track: Track, start: float, period: float, held: tuple[float, float] | None
    ) -> None:
        self._track, self._start, self._period, self._held = track, start, period, held


class ShowRuntime:
    """Plays a :class:`~hilsim.live.show_spec.RuntimeSpec` (module docstring).

    Args:
        spec: the show's clips, sounds, idle, cues and timeline.
        joint_names: the rig's joints, in the order of ``base_tracks``.
        base_tracks: each joint's own target (what it follows when no clip drives it).
        seed: the idle layer's random picks (the ``[idle]`` ``seed`` overrides it).
        wall_start: the local wall-clock time at show time 0, for ``daily:`` triggers and cue
            windows. None: read once here (the only clock read), and only if the show has one.

    Attributes:
        tracks: one :class:`ShowTrack` per joint, for the loop's TargetSet.
        offset: show time minus the time the tracks are sampled at (s); the director sets it
            each tick when it chases timecode and samples the tracks at the loop's own time.
    """

    def __init__(
        self,
        spec: RuntimeSpec,
        joint_names: Sequence[str],
        base_tracks: Sequence[Track],
        *,
        seed: int = 0,
        wall_start: datetime | None = None,
    ) -> None:
        names = tuple(joint_names)
        if len(names) != len(base_tracks):
            raise ValueError(f"{len(base_tracks)} base tracks for {len(names)} joints")
        self.spec, self.names = spec, names
        self.offset = 0.0
        self.tracks: tuple[ShowTrack, ...] = tuple(ShowTrack(self, b) for b in base_tracks)
        # per clip: its track for each joint (None where it does not drive it)
        self._per_joint = {
            name: tuple(clip.tracks.get(j) for j in names) for name, clip in spec.clips.items()
        }
        self._cues_by_key: dict[str, list[CueSpec]] = {}
        for cue in spec.cues.values():
            keys = {t.key for t in cue.triggers} | {
                f"osc:{CUE_ADDRESS}{cue.name}",
                f"{API_CUE}{cue.name}",  # Show.cue(name)
            }
            for key in sorted(keys):
                self._cues_by_key.setdefault(key, []).append(cue)
        timers = [trig for cue in spec.cues.values() for trig in cue.triggers]
        needs_wall = any(c.window for c in spec.cues.values()) or any(
            trig.kind == "daily" for trig in timers
        )
        if wall_start is None and needs_wall:
            wall_start = datetime.now()
        self.wall_start = wall_start
        self._timers = Timers(timers, wall_start)
        idle = spec.idle
        self._idle = tuple(spec.clips[c] for c in idle.clips) if idle else ()
        self._random = idle is not None and idle.order == "random" and len(self._idle) > 1
        rng_seed = idle.seed if idle is not None and idle.seed is not None else seed
        self._rng = random.Random(rng_seed)
        self._idle_i, self._idle_start = -1, 0.0
        self._tl = spec.timeline
        self._tl_times = [e.at_s for e in spec.timeline]
        self._tl_i, self._tl_active, self._tl_loop_n = -1, False, 0
        self._cue: CueSpec | None = None
        self._cue_start, self._cue_held = 0.0, False
        self._last_fired: dict[str, float] = {}
        self._pending: list[tuple[str, float]] = []
        self._dropped = 0
        self._unmatched: set[str] = set()
        self._t_last: float | None = None
        self._front: str | None = None
        self._events: list[LiveEvent] = []
        #: what drives each joint after the last tick: "cue scare", "hold scare",
        #: "timeline song", "idle breathe" or "rig" (the status line's per-joint layer)
        self.layers: list[str] = ["rig"] * len(names)

    # ------------------------------------------------------------------ what the director reads
    @property
    def trigger_keys(self) -> tuple[str, ...]:
        """Every input trigger key a cue answers (normalised); see RuntimeSpec.trigger_keys."""
        return self.spec.trigger_keys

    @property
    def duration(self) -> float | None:
        """None (a show runs until stopped), except a show of a timeline only (no idle, no
        cues) whose last clip neither loops nor is endless: its end (s)."""
        spec = self.spec
        if spec.idle is not None or spec.cues or not spec.timeline:
            return None
        last = spec.timeline[-1]
        dur = spec.clips[last.clip].duration
        return None if last.loop or dur is None else last.at_s + dur

    @property
    def now_playing(self) -> str:
        """For the status line: ``"cue scare (2.1/4.0 s)"``, ``"hold scare"``, ``"timeline
        song"``, ``"idle breathe"`` or ``"rig targets"``."""
        t = self._t_last or 0.0
        cue = self._cue
        if cue is not None:
            if self._cue_held:
                return f"hold {cue.name}"
            dur = self.spec.clips[cue.clip].duration
            total = "" if dur is None else f"/{dur:.1f}"
            return f"cue {cue.name} ({max(0.0, t - self._cue_start):.1f}{total} s)"
        if self._tl_active:
            return f"timeline {self._tl[self._tl_i].clip}"
        if self._idle_i >= 0:
            return f"idle {self._idle[self._idle_i].name}"
        return "rig targets"

    # ------------------------------------------------------------------ input
    def trigger(self, key: str, t: float) -> None:
        """Queue trigger ``key`` (e.g. ``"osc:/hilsim/cue/scare"``, ``"midi:note:60"``,
        ``"key:s"``) that arrived at show time ``t``; it takes effect at the next :meth:`tick`.
        More than :data:`MAX_PENDING` between two ticks are dropped (counted)."""
        if len(self._pending) >= MAX_PENDING:
            self._dropped += 1
            return
        self._pending.append((normalise_key(str(key)), float(t)))

    # ------------------------------------------------------------------ one tick
    def tick(self, t: float) -> list[LiveEvent]:
        """Advance to show time ``t`` (s, finite, normally not decreasing): clip ends and what
        follows them, the timeline, timers and queued triggers, the idle layer. Returns this
        tick's events in time order (all at times <= ``t``)."""
        t = float(t)
        last = self._t_last
        first = last is None
        prev = -math.inf if last is None else last
        events: list[LiveEvent] = []
        self._events = events
        change_t = t
        if not first and t < prev:  # time went back (a timecode jump): no negative clip times
            self._cue_start = min(self._cue_start, t)
            self._idle_start = min(self._idle_start, t)
        change_t = self._cue_ends(t, change_t)
        change_t = self._timeline(t, change_t)
        if first and self._idle:
            self._next_idle(t, t)
        self._fire(self._timers.due(prev, t) + self._take_pending(t), t)
        self._idle_chain(t)
        self._t_last = t
        self._fronts(first, change_t, t)
        self._resolve()
        events.sort(key=_order)  # stable: causes stay before effects at one time
        return events

    def _emit(self, t: float, kind: str, message: str, **detail: Any) -> LiveEvent:
        ev = LiveEvent(t, kind, "show", {"message": message, **detail})
        self._events.append(ev)
        return ev

    # ------------------------------------------------------------------ cues
    def _cue_ends(self, t: float, change_t: float) -> float:
        """Follow the playing cue's end (and its ``then`` chain) up to ``t``."""
        for _ in range(MAX_CHAIN):
            cue = self._cue
            if cue is None or self._cue_held:
                break
            dur = self.spec.clips[cue.clip].duration
            if dur is None or self._cue_start + dur > t:
                break
            end = self._cue_start + dur
            self._emit(end, "cue_end", f"cue {cue.name}: clip {cue.clip} ended, then {cue.then}",
                       cue=cue.name, clip=cue.clip, reason="end", then=cue.then)  # fmt: skip
            if cue.then == "hold":
                self._cue_held = True
            elif cue.then == "idle":
                self._cue, change_t = None, end
            else:
                self._cue = None  # ended, not cut
                self._start_cue(self.spec.cues[cue.then], end, f"then of {cue.name}")
        else:  # a chain of clips shorter than a tick: go on from now
            self._cue_start = t
        return change_t

    def _start_cue(self, cue: CueSpec, t: float, why: str) -> None:
        old = self._cue
        if old is not None and not self._cue_held:
            self._emit(t, "cue_end", f"cue {old.name}: cut by cue {cue.name}",
                       cue=old.name, clip=old.clip, reason="cut", then=cue.name)  # fmt: skip
        self._cue, self._cue_start, self._cue_held = cue, t, False
        self._last_fired[cue.name] = t
        detail: dict[str, Any] = {"cue": cue.name, "clip": cue.clip, "trigger": why}
        sound = self.spec.sounds.get(cue.clip)
        if sound is not None:
            detail.update(sound=str(sound.path), sound_offset_s=0.0)
        self._emit(t, "cue_start", f"cue {cue.name}: clip {cue.clip} ({why})", **detail)

    def _fire(self, keys: list[str], t: float) -> None:
        """Fire every cue answering each key, in order, at ``t``: window, lockout, start."""
        started: set[str] = set()
        for key in keys:
            cues = self._cues_by_key.get(key)
            if not cues:
                if key not in self._unmatched and len(self._unmatched) < _UNMATCHED_MEMORY:
                    self._unmatched.add(key)
                    self._emit(t, "trigger_unmatched", f"{key}: no cue answers it", trigger=key)
                continue
            for cue in cues:
                reason = self._refusal(cue, t, started)
                if reason:
                    self._emit(t, "cue_ignored", f"cue {cue.name}: {key} ignored ({reason})",
                               cue=cue.name, trigger=key, reason=reason)  # fmt: skip
                    continue
                started.add(cue.name)
                self._start_cue(cue, t, key)

    def _refusal(self, cue: CueSpec, t: float, started: set[str]) -> str:
        if cue.name in started:
            return "duplicate"
        if cue.window is not None and not cue.window.contains(day_seconds(self._wall(t))):
            return "window"
        last = self._last_fired.get(cue.name)
        if last is not None and t - last < cue.lockout_s:
            return "lockout"
        return ""

    def _take_pending(self, t: float) -> list[str]:
        keys = [k for k, _ in self._pending]
        self._pending.clear()
        if self._dropped:
            self._emit(t, "triggers_dropped", f"{self._dropped} triggers dropped (flood)",
                       count=self._dropped)  # fmt: skip
            self._dropped = 0
        return keys

    def _wall(self, t: float) -> datetime:
        assert self.wall_start is not None  # __init__ set it: a cue has a window
        return self.wall_start + timedelta(seconds=t)

    # ------------------------------------------------------------------ timeline
    def _timeline(self, t: float, change_t: float) -> float:
        if not self._tl:
            return change_t
        i = bisect_right(self._tl_times, t) - 1
        active, loop_n = False, 0
        if i >= 0:
            entry = self._tl[i]
            dur = self.spec.clips[entry.clip].duration
            local = t - entry.at_s
            if entry.loop and dur:
                active, loop_n = True, int(local // dur)
            else:
                active = dur is None or not self._idle or local < dur
            if active and (i != self._tl_i or loop_n != self._tl_loop_n):
                self._clip_event("timeline", entry.clip, entry.at_s + loop_n * (dur or 0), t)
            if not active and self._tl_active and i == self._tl_i:
                end = entry.at_s + (dur or 0.0)
                self._emit(end, "clip_end", f"timeline: clip {entry.clip} ended",
                           layer="timeline", clip=entry.clip)  # fmt: skip
                change_t = end
        self._tl_i, self._tl_active, self._tl_loop_n = i, active, loop_n
        return change_t

    # ------------------------------------------------------------------ idle
    def _next_idle(self, start: float, t: float) -> None:
        n = len(self._idle)
        if self._random:
            if self._idle_i < 0:
                i = self._rng.randrange(n)
            else:  # any other clip, never the same twice in a row
                i = self._rng.randrange(n - 1)
                i += i >= self._idle_i
        else:
            i = (self._idle_i + 1) % n
        self._idle_i, self._idle_start = i, start
        self._clip_event("idle", self._idle[i].name, start, max(start, t))

    def _idle_chain(self, t: float) -> None:
        if self._idle_i < 0:
            return
        for _ in range(MAX_CHAIN):
            dur = self._idle[self._idle_i].duration
            if dur is None or self._idle_start + dur > t:
                return
            end = self._idle_start + dur
            self._next_idle(end, end)
        self._idle_start = t  # a time jump: go on from now

    # ------------------------------------------------------------------ front layer, sounds
    def _clip_event(self, layer: str, clip: str, start: float, t: float) -> None:
        self._emit(t, "clip_start", f"{layer}: clip {clip}", layer=layer, clip=clip,
                   local_s=max(0.0, t - start))  # fmt: skip

    def _front_layer(self) -> str | None:
        if self._cue is not None:
            return "cue"
        if self._tl_active:
            return "timeline"
        return "idle" if self._idle_i >= 0 else None

    def _front_clip(self, layer: str) -> tuple[Clip, float]:
        if layer == "timeline":
            entry = self._tl[self._tl_i]
            dur = self.spec.clips[entry.clip].duration
            return self.spec.clips[entry.clip], entry.at_s + self._tl_loop_n * (dur or 0.0)
        return self._idle[self._idle_i], self._idle_start

    def _fronts(self, first: bool, change_t: float, t: float) -> None:
        """Sounds go with the layer in front: its last clip_start this tick gets its sound;
        a layer coming back to the front (idle resuming) gets a clip_start that picks its
        sound up where the clip is."""
        front, was = self._front_layer(), self._front
        self._front = front
        if front is None or front == "cue":
            return
        since = change_t if front != was else -math.inf
        mine = [
            ev
            for ev in self._events
            if ev.kind == "clip_start" and ev.detail["layer"] == front and ev.t >= since
        ]
        if front != was and not first:
            if front == "idle":
                self._emit(change_t, "idle_resume", f"idle: {self._idle[self._idle_i].name}",
                           clip=self._idle[self._idle_i].name)  # fmt: skip
            if not mine:
                clip, start = self._front_clip(front)
                at = min(max(change_t, start), t)
                msg = f"{front}: clip {clip.name} (resumed)"
                ev = self._emit(at, "clip_start", msg, layer=front, clip=clip.name,
                                local_s=at - start, resumed=True)  # fmt: skip
                mine = [ev]
        if mine:
            ev = mine[-1]
            sound = self.spec.sounds.get(ev.detail["clip"])
            if sound is not None:
                offset = ev.detail["local_s"]
                ev.detail.update(sound=str(sound.path), sound_offset_s=offset)

    # ------------------------------------------------------------------ per joint
    def _resolve(self) -> None:
        """Point each joint's track at the first layer driving it: cue, timeline, idle, base."""
        cue = self._cue
        cue_tr = self._per_joint[cue.clip] if cue is not None else None
        cue_dur = self.spec.clips[cue.clip].duration if cue is not None else None
        tl_tr: tuple[Track | None, ...] | None = None
        tl_start = tl_period = 0.0
        if self._tl_active:
            entry = self._tl[self._tl_i]
            tl_tr, tl_start = self._per_joint[entry.clip], entry.at_s
            dur = self.spec.clips[entry.clip].duration
            tl_period = dur if entry.loop and dur else 0.0
        idle_tr = self._per_joint[self._idle[self._idle_i].name] if self._idle_i >= 0 else None
        layers = self.layers
        cue_label = "" if cue is None else f"{'hold' if self._cue_held else 'cue'} {cue.name}"
        tl_label = f"timeline {self._tl[self._tl_i].clip}" if self._tl_active else ""
        idle_label = f"idle {self._idle[self._idle_i].name}" if self._idle_i >= 0 else ""
        for j, st in enumerate(self.tracks):
            if cue_tr is not None and (tr := cue_tr[j]) is not None:
                held = None
                if self._cue_held:
                    held = (tr.sample(cue_dur or 0.0)[0], 0.0)
                st._set(tr, self._cue_start, 0.0, held)
                layers[j] = cue_label
            elif tl_tr is not None and (tr := tl_tr[j]) is not None:
                st._set(tr, tl_start, tl_period, None)
                layers[j] = tl_label
            elif idle_tr is not None and (tr := idle_tr[j]) is not None:
                st._set(tr, self._idle_start, 0.0, None)
                layers[j] = idle_label
            else:
                st._set(st.base, 0.0, 0.0, None)
                layers[j] = "rig"
