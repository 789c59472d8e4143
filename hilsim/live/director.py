"""The director: once per tick, everything live decides where each joint should go.

``hilsim run RIG --show SHOW.toml`` (or ``--live``) gives the loop a :class:`Director`. Per
tick, before the loop samples the targets (:meth:`Director.tick`)::

    timecode (MTC chase)         the show time: t_show = t_sim, or the chased timecode,
    FPP MultiSync                or the master's time (hilsim.live.multisync)
    live inputs, polled          OSC, MIDI CC, gamepad, Bottango live, teach-by-hand: the
                                 latest value per joint; triggers (OSC, MIDI note/CC, keys)
    the show runtime             cues fired (lockout, windows, timers), clips started and
                                 ended, idle resumed; sounds started with their clips
    events, takes, stop          events.jsonl; live samples kept for the take; a stop
                                 command (OSC /hilsim/stop, Bottango STOP) -> the exit policy

Each joint's target is one :class:`DirectedTrack`: its live value while a live input holds
the joint (held when the input is lost, until it is released), else the show runtime's clip,
else the rig's own target, sampled at the show time. Where two live inputs drive one joint,
the latest value wins. Who holds each joint, takes and releases (OSC ``/hilsim/release``,
``Show.release``, ``release_after_s``): :class:`~hilsim.live.live_layer.LiveLayer`. All
of it reaches the servos only through the springs and the safety filter: a cut, a timecode
jump or a fader slammed to the end is a step in the *target*, never in the command.

Nothing here waits: the inputs' receiver threads hand over under a lock and the loop takes
what is there. Inputs are stamped with show time (``now()`` below; 0 until tick 0), so a test
feeds them with timestamps and runs the loop in virtual time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from drivers.clock import Clock
from hilsim._types import JsonDict
from hilsim.live.inbox import MAX_LIVE_DEG, LineGate, LiveEvent
from hilsim.live.inputs import LiveInputs, has_live_inputs
from hilsim.live.live_layer import LiveLayer
from hilsim.live.showfile import ShowSpec
from hilsim.targets.tracks import TargetSet, Track

if TYPE_CHECKING:
    from hilsim.live.show import ShowRuntime
    from hilsim.live.takes import Take

#: an event's ``detail`` keys that the log line's own fields take
_RESERVED = frozenset(("kind", "message", "t", "event", "tick"))
#: the lines a storm of well-formed triggers repeats (a cue sent 1000 times a second): a few,
#: then one a second per cue (LineGate); the triggers themselves all act
_GATED = frozenset(("cue", "cue_ignored", "trigger"))


#: the run directory's folders a show's takes go in (the recorded live input, a teach
#: session): kept even when ``telemetry.format = "off"`` keeps nothing else
TAKE_DIRS = ("take", "teach")


class StopRequest(Protocol):
    """Where a stop command goes (the show's stop flag): the show ends by its exit policy."""

    def request_command(self, what: str) -> None: ...


class DirectedTrack(Track):
    """One joint's target under the director: ``live`` (rad) when set, else ``inner`` at the
    show time (t + the director's offset)."""

    def __init__(self, inner: Track, director: Director) -> None:
        self.inner, self._director = inner, director
        self.live: float | None = None
        self.end: float | None = None  # a show with an end (a timeline only): its length

    def sample(self, t: float) -> tuple[float, float]:
        live = self.live
        if live is not None:
            return live, 0.0
        return self.inner.sample(t + self._director.offset)

    @property
    def duration(self) -> float | None:
        return self.end


class Director:
    """Built by :func:`build_director`; :meth:`open` starts the inputs (before the show),
    the loop calls :meth:`begin` at tick 0 and :meth:`tick` every tick, :meth:`close` ends it."""

    def __init__(
        self, spec: ShowSpec, names: Sequence[str], base: TargetSet, *, silent: bool = False
    ) -> None:
        self.spec, self.names = spec, tuple(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.base = base  # the rig's own targets (under the show)
        self.offset = 0.0  # t_show - t_sim (MTC chase)
        self.t0: float | None = None  # the clock time of tick 0
        self.clock: Clock | None = None  # the show's clock, from open()
        self.runtime: ShowRuntime | None = None
        inner = list(base.tracks)
        if spec.runtime is not None:
            from hilsim.live.show import ShowRuntime

            self.runtime = ShowRuntime(spec.runtime, self.names, inner, seed=spec.seed)
            inner = list(self.runtime.tracks)
        self.tracks = [DirectedTrack(tr, self) for tr in inner]
        self.targets = TargetSet(self.tracks, self.names)
        self.targets.notes = base.notes
        if self.runtime is not None and not has_live_inputs(spec):
            end = getattr(self.runtime, "duration", None)
            if end is not None:  # a timeline only: the show ends with it
                for tr in self.tracks:
                    tr.end = end
        #: the live inputs (hilsim.live.inputs); the director's attributes name each one
        self.inputs = inputs = LiveInputs(spec, self.names, self.runtime, silent=silent)
        self.osc, self.midi, self.midi_triggers = inputs.osc, inputs.midi, inputs.midi_triggers
        self.chase, self.multisync, self.dmx = inputs.chase, inputs.multisync, inputs.dmx
        self.ltc = inputs.ltc
        self.bottango, self.gamepad = inputs.bottango, inputs.gamepad
        self.keyboard, self.teach = inputs.keyboard, inputs.teach
        self.audio, self.api = inputs.audio, inputs.api
        self._log: Callable[..., None] = lambda *a, **k: None
        self._stop: StopRequest | None = None
        self.take: Take | None = None
        self._gate = LineGate()
        if spec.record is not None:
            from hilsim.live.takes import Take

            self.take = Take(spec.record.joints)
        self.counts = {"events": 0, "cues": 0, "stops": 0, "live_values": 0, "values_refused": 0}
        runtime = self.runtime
        #: who holds each joint; every take and release goes through it
        self.layer = LiveLayer(
            self.names,
            self.tracks,
            release_after(spec),
            (lambda i: "rig") if runtime is None else (lambda i: runtime.layers[i]),
        )

    # ------------------------------------------------------------------ life cycle
    def now(self) -> float:
        """The show time a receiver stamps a message with: 0 until tick 0, then clock − t0."""
        t0 = self.t0
        if t0 is None:
            return 0.0
        assert self.clock is not None  # open() gave it, before begin() set t0
        return max(0.0, self.clock.now() - t0)

    def open(self, clock: Clock, say: Callable[[str], None]) -> None:
        """Start the receivers (sockets, ports, threads) before anything moves. Raises
        ValueError / OSError / RuntimeError with one line on a port that cannot be opened."""
        self.clock = clock
        self.inputs.open(clock, self.now, say)

    def begin(self, t0: float, log: Callable[..., None], stop: StopRequest | None) -> None:
        """Tick 0 is at clock time ``t0``; ``log(kind, message, **fields)`` writes an event,
        ``stop.request_command(what)`` ends the show through the exit policy."""
        self.t0, self._log, self._stop = t0, log, stop

    def close_inputs(self) -> None:
        self.inputs.close()

    # ------------------------------------------------------------------ one tick
    def tick(self, k: int, t: float, present_rad: Sequence[float]) -> None:
        """Tick ``k`` at show time ``t`` (s, k·period): poll, decide, log. ``present_rad``: the
        joints' present positions (joint frame) read this tick."""
        events: list[LiveEvent] = []
        triggers: list[str] = []
        inputs = self.inputs
        followed = inputs.show_time(t, events, self)  # a chased clock (MTC, MultiSync)
        if followed is not None:
            self.offset = followed - t
        t_show = t + self.offset
        inputs.poll(t, present_rad, events, triggers, self)
        events += self._released(self.layer.expire(t))  # after this tick's fresh values
        runtime = self.runtime
        if runtime is not None:
            for key in triggers:
                runtime.trigger(key, t_show)
            for ev in runtime.tick(t_show):
                events.append(ev)
                if self.audio is not None and ev.kind in ("cue_start", "clip_start", "cue_end"):
                    events += self._sound(ev, t_show)
        elif triggers:
            for key in triggers:
                events.append(LiveEvent(t, "trigger", "show", {"message": f"{key}: no cues"}))
        if self.audio is not None:
            events += self.audio.poll(t)
        for ev in events:
            self._event(k, ev)
        for ev in self._gate.due(t):  # lines held back by a storm, said once a second
            self._event(k, ev, gated=False)

    def set_value(
        self,
        joint: str,
        deg: float,
        t_msg: float,
        source: str = "api",
        events: list[LiveEvent] | None = None,
        *,
        standing: bool = False,
    ) -> None:
        """A live value (degrees) for ``joint`` from ``source``: it takes the joint (see
        :meth:`LiveLayer.take`); kept for the take when it changed."""
        i = self.index.get(joint)
        if i is None:
            return
        if not -MAX_LIVE_DEG <= deg <= MAX_LIVE_DEG:  # NaN, inf, absurd: never a target
            self.counts["values_refused"] += 1
            return
        rad = math.radians(deg)
        changed = self.tracks[i].live != rad
        was = self.layer.holder[i]
        ev = self.layer.take(i, rad, source, t_msg, standing=standing)
        if ev is not None:
            if was == "osc" and self.osc is not None:  # OSC no longer holds it: none to lose
                self.osc.targets.forget(joint)
            if events is not None:
                events.append(ev)
        if not changed or self.tracks[i].live != rad:  # the same value, or not taken
            return
        self.counts["live_values"] += 1
        if self.take is not None:
            self.take.record(t_msg + self.offset, joint, deg)

    _set = set_value  # the name tests and older callers use

    def teach_value(self, joint: str, deg: float) -> None:
        """Teach-by-hand's target for ``joint`` (degrees): the layer's teach value."""
        self.layer.teach(self.index[joint], math.radians(deg))

    def request_stop(self, what: str) -> None:
        """A stop command from an input: counted, then the show's exit policy."""
        self.counts["stops"] += 1
        if self._stop is not None:
            self._stop.request_command(what)

    def release(
        self, joint: str | None, t: float, reason: str, source: str = "show"
    ) -> list[LiveEvent]:
        """Hand ``joint`` (None: all) back to the show's layers at show time ``t``: the one
        way a live input, a control or a panel releases a joint. Returns the events."""
        return self._released(self.layer.release(joint, t, reason, source=source))

    def _released(self, events: list[LiveEvent]) -> list[LiveEvent]:
        """Joints OSC held are forgotten there: no value held, none to lose."""
        if self.osc is not None:
            for ev in events:
                if ev.kind == "live_release" and ev.source == "osc":
                    self.osc.targets.forget(ev.detail["joint"])
        return events

    def _sound(self, ev: LiveEvent, t_show: float) -> list[LiveEvent]:
        """A clip in front with a sound starts it, in step with the clip (late: further into
        the file); a cue without one, or a cue's end, stops the sound playing."""
        assert self.audio is not None  # called only with a show's sounds
        path = ev.detail.get("sound")
        if path:
            return self.audio.play(path, float(ev.detail.get("sound_offset_s", 0.0)), ev.t, t_show)
        if ev.kind in ("cue_start", "cue_end"):
            self.audio.stop()
        return []

    def _event(self, k: int, ev: LiveEvent, gated: bool = True) -> None:
        if gated and ev.kind in _GATED:
            what = ev.detail.get("cue") or ev.detail.get("address") or ev.detail.get("message")
            if self._gate.offer(ev, f"{ev.kind} {ev.source} {what}") is None:
                return
        self.counts["events"] += 1
        if ev.kind == "cue_start":
            self.counts["cues"] += 1
        if ev.kind in ("input_lost", "input_returned", "input_resumed"):
            joint = ev.detail.get("joint")
            joints = [joint] if joint is not None else ev.detail.get("joints")
            self.layer.mark_lost(ev.source, joints, ev.kind == "input_lost")
        fields = {key: v for key, v in ev.detail.items() if key not in _RESERVED}
        self._log(ev.kind, str(ev.detail.get("message", ev.kind)), tick=k, t=ev.t,
                  source=ev.source, **fields)  # fmt: skip

    # ------------------------------------------------------------------ the status line
    @property
    def layers(self) -> dict[str, str]:
        """What drives each joint now: ``"live osc"``, ``"LOST osc"`` (a lost input still
        holds it), ``"teach"``, ``"cue scare"``, ``"hold scare"``, ``"timeline song"``,
        ``"idle breathe"`` or ``"rig"``."""
        return {name: self.layer.label(i) for i, name in enumerate(self.names)}

    @property
    def now_playing(self) -> str:
        """The status line's show part: each joint and what drives it, then a cue's
        progress and the timecode chase's state."""
        parts = [", ".join(f"{n} {label}" for n, label in self.layers.items())]
        playing = "" if self.runtime is None else str(self.runtime.now_playing)
        if playing.startswith("cue "):
            parts.append(playing)
        parts += self.inputs.states()
        return "; ".join(parts)

    # ------------------------------------------------------------------ the end
    def close(self, run_dir: Path | None) -> JsonDict:
        """Stop the inputs; write the take (raw CSV and reduced keys) into ``run_dir``;
        return the summary's ``live`` section. Never raises: a full disk is said in it."""
        self.close_inputs()
        out: JsonDict = {"show": self.spec.name, **self.counts, **self.layer.counts}
        out.update(self.inputs.summary())
        if run_dir is not None:
            out["takes"] = self._write_takes(run_dir)
        return out

    def _write_takes(self, run_dir: Path) -> JsonDict:
        written: JsonDict = {}
        take_dir, teach_dir = (run_dir / name for name in TAKE_DIRS)
        try:
            if self.take is not None and any(len(self.take.raw(j)[0]) for j in self.take.joints):
                from hilsim.live.takes import write_take

                assert self.spec.record is not None  # the take is made from it
                written["live"] = write_take(self.take, take_dir, self.spec.record.tolerance_deg)
            if self.teach is not None:
                written["teach"] = self.teach.finish(teach_dir)
        except Exception as exc:  # a full disk: the show is over; say what was lost
            written["error"] = f"the take could not be written: {exc}"
        return written


def release_after(spec: ShowSpec) -> dict[str, float | None]:
    """Each live input's ``release_after_s`` (None: its joints are held until released)."""
    out: dict[str, float | None] = {}
    for source in ("osc", "midi", "gamepad", "bottango", "sacn", "artnet"):
        out[source] = getattr(getattr(spec, source), "release_after_s", None)
    return out


def build_director(
    spec: ShowSpec, names: Sequence[str], base: TargetSet, *, silent: bool = False
) -> Director:
    """The director for ``spec`` over the rig's own targets ``base``; ``silent``: no sound
    device (virtual time). Raises ValueError on a spec the inputs refuse (one line)."""
    return Director(spec, names, base, silent=silent)
