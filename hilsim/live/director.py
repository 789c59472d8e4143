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

import contextlib
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from drivers.clock import Clock
from hilsim._types import JsonDict
from hilsim.live.controls import Controls
from hilsim.live.inbox import MAX_LIVE_DEG, LiveEvent
from hilsim.live.live_layer import LiveLayer
from hilsim.live.showfile import ShowSpec
from hilsim.targets.tracks import TargetSet, Track

if TYPE_CHECKING:  # each input's module is imported when a show uses that input
    from hilsim.live.audio_out import AudioOut
    from hilsim.live.bottango_live import BottangoLive
    from hilsim.live.dmx_input import DmxInput
    from hilsim.live.gamepad import GamepadInput
    from hilsim.live.keyboard import KeyboardInput
    from hilsim.live.ltc_chase import LtcChase
    from hilsim.live.midi import MidiCcInput, MidiTriggerInput
    from hilsim.live.multisync import MultiSyncRemote
    from hilsim.live.osc import OscInput
    from hilsim.live.show import ShowRuntime
    from hilsim.live.takes import Take
    from hilsim.live.teach import Teach
    from hilsim.live.timecode import MtcChase

#: an event's ``detail`` keys that the log line's own fields take
_RESERVED = frozenset(("kind", "message", "t", "event", "tick"))


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
        if self.runtime is not None and not self._live_inputs(spec):
            end = getattr(self.runtime, "duration", None)
            if end is not None:  # a timeline only: the show ends with it
                for tr in self.tracks:
                    tr.end = end
        self._build_inputs(spec, silent)
        self._log: Callable[..., None] = lambda *a, **k: None
        self._stop: StopRequest | None = None
        self._closers: list[Callable[[], None]] = []
        self.take: Take | None = None
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

    @staticmethod
    def _live_inputs(spec: ShowSpec) -> bool:
        return any(
            x is not None
            for x in (spec.osc, spec.midi, spec.bottango, spec.gamepad, spec.keyboard, spec.teach,
                      spec.sacn, spec.artnet, spec.multisync)
        )  # fmt: skip

    def _build_inputs(self, spec: ShowSpec, silent: bool) -> None:
        """The inputs' state machines (no I/O yet); ``silent``: sounds scheduled and logged,
        not played (virtual time: no sound device)."""
        keys = tuple(getattr(self.runtime, "trigger_keys", ()) or ())
        heard = {"osc": spec.osc, "midi": spec.midi, "key": spec.keyboard}
        section = {"osc": "osc", "midi": "midi", "key": "keyboard"}
        for key in keys:  # a trigger nothing in this show can send: said at load
            kind = key.split(":", 1)[0]
            cue_address = key.startswith("osc:/hilsim/cue/")  # every cue's own, always listed
            if heard.get(kind, True) is None and spec.gamepad is None and not cue_address:
                spec.notes.append(
                    f"trigger {key!r}: the show has no [inputs.{section[kind]}], so nothing "
                    "can send it"
                )
        self.osc: OscInput | None = None
        self.midi: MidiCcInput | None = None
        self.midi_triggers: MidiTriggerInput | None = None
        self.chase: MtcChase | None = None
        self.bottango: BottangoLive | None = None
        self.gamepad: GamepadInput | None = None
        self.keyboard: KeyboardInput | None = None
        self.teach: Teach | None = None
        self.audio: AudioOut | None = None
        cues = () if self.runtime is None else tuple(self.runtime.spec.cues)
        #: cues and joint values from the program running the show (hilsim.Show)
        self.api = Controls(self.names, cues)
        if spec.osc is not None:
            from hilsim.live.osc import OscInput

            osc_keys = [k[4:] for k in keys if k.startswith("osc:")]
            self.osc = OscInput(
                spec.osc.joints,
                guard=spec.osc.guard,
                lost_after_s=spec.osc.lost_after_s,
                triggers=[a for a in osc_keys if not a.startswith("/hilsim/cue/")],
                releasable=self.names,
            )
        if spec.midi is not None:
            from hilsim.live.midi import MidiCcInput, MidiTriggerInput

            if spec.midi.cc:
                self.midi = MidiCcInput(spec.midi.cc, lost_after_s=spec.midi.lost_after_s)
            midi_keys = [k for k in keys if k.startswith("midi:")]
            if midi_keys:
                self.midi_triggers = MidiTriggerInput(midi_keys)
        if spec.mtc is not None:
            from hilsim.live.timecode import MtcChase

            m = spec.mtc
            self.chase = MtcChase(freewheel_s=m.freewheel_s, jump_s=m.jump_s, offset_s=m.offset_s)
        self.ltc: LtcChase | None = None  # LTC (a WAV file or an audio input)
        if spec.ltc is not None:
            from hilsim.live.ltc_chase import LtcChase

            self.ltc = LtcChase(spec.ltc)
        #: sACN and Art-Net in (hilsim.live.dmx_input)
        self.dmx: list[DmxInput] = []
        for dmx_config in (spec.sacn, spec.artnet):
            if dmx_config is not None:
                from hilsim.live.dmx_input import DmxInput

                self.dmx.append(DmxInput(dmx_config))
        self.multisync: MultiSyncRemote | None = None
        if spec.multisync is not None:
            from hilsim.live.multisync import MultiSyncRemote

            self.multisync = MultiSyncRemote(spec.multisync)
        if spec.bottango is not None:
            from hilsim.live.bottango_live import BottangoLive

            self.bottango = BottangoLive.from_config(spec.bottango)
        if spec.gamepad is not None:
            from hilsim.live.gamepad import GamepadInput

            self.gamepad = GamepadInput(spec.gamepad)
        if spec.keyboard is not None:
            from hilsim.live.keyboard import KeyboardInput

            self.keyboard = KeyboardInput(spec.keyboard)
        if spec.teach is not None:
            from hilsim.live.teach import Teach

            self.teach = Teach(self.names, spec.teach)
        sounds = getattr(spec.runtime, "sounds", None)
        if sounds:
            from hilsim.live.audio_out import AudioOut, SilentBackend

            out = self.runtime.spec.sound_output if self.runtime is not None else None
            self.audio = AudioOut(
                SilentBackend() if silent else None,
                device=None if out is None else out.device,
                required=out is not None and out.required,
            )
            try:
                self.audio.preload(
                    [s.path for s in sounds.values()],
                    offsets_ms={str(s.path): s.offset_s * 1e3 for s in sounds.values()},
                )
            except ValueError as exc:
                raise ValueError(f"sounds: {exc}") from None

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
        spec = self.spec
        try:
            if self.osc is not None:
                from hilsim.live.osc import listen

                assert spec.osc is not None  # self.osc is built from it
                rx = listen(self.osc, spec.osc.port, self.now, max_rx_per_s=spec.osc.max_rx_per_s)
                self._closers.append(rx.close)
                say(f"OSC on {spec.osc.guard.bind_address}:{spec.osc.port}: "
                    f"/hilsim/joint/<{'|'.join(self.osc.ranges)}> 0..1, /hilsim/cue/<name>, "
                    "/hilsim/release[/<joint>], /hilsim/stop")  # fmt: skip
            for dmx in self.dmx:
                from hilsim.live.dmx_input import listen as dmx_listen

                rx = dmx_listen(dmx, self.now, max_rx_per_s=dmx.config.max_rx_per_s)
                self._closers.append(rx.close)
                groups = " (multicast)" if dmx.config.multicast else ""
                say(f"{dmx.name} on {dmx.config.guard.bind_address}:{dmx.config.port}{groups}: "
                    f"universes {', '.join(map(str, dmx.config.universes))}")  # fmt: skip
            if self.multisync is not None:
                from hilsim.live.multisync import listen as sync_listen

                rx = sync_listen(self.multisync, self.now)
                self._closers.append(rx.close)
                ms = self.multisync.config
                say(f"FPP MultiSync on {ms.guard.bind_address}:{ms.port}"
                    f"{' (multicast)' if ms.multicast else ''}: "
                    f"following {ms.sequence or 'any sequence'}")  # fmt: skip
            sinks = [s for s in (self.midi, self.midi_triggers, self.chase) if s is not None]
            if sinks:
                from hilsim.live.midi import open_midi_input

                assert spec.midi is not None  # the show file gives [inputs.mtc] one too
                port = open_midi_input(spec.midi.port, sinks, self.now)
                self._closers.append(port.close)
                say(f"MIDI in: {port.name}")
            for part in (self.bottango, self.gamepad, self.keyboard, self.audio, self.ltc):
                if part is not None and hasattr(part, "start"):
                    note = part.start(self.now)
                    self._closers.append(part.close)
                    if note:
                        say(str(note))
        except BaseException:
            self.close_inputs()
            raise

    def begin(self, t0: float, log: Callable[..., None], stop: StopRequest | None) -> None:
        """Tick 0 is at clock time ``t0``; ``log(kind, message, **fields)`` writes an event,
        ``stop.request_command(what)`` ends the show through the exit policy."""
        self.t0, self._log, self._stop = t0, log, stop

    def close_inputs(self) -> None:
        while self._closers:
            close = self._closers.pop()
            with contextlib.suppress(Exception):  # closing never stops the exit path
                close()

    # ------------------------------------------------------------------ one tick
    # long on purpose: one tick: each input in turn, in the order they act
    def tick(self, k: int, t: float, present_rad: Sequence[float]) -> None:  # noqa: C901, PLR0912
        """Tick ``k`` at show time ``t`` (s, k·period): poll, decide, log. ``present_rad``: the
        joints' present positions (joint frame) read this tick."""
        events: list[LiveEvent] = []
        triggers: list[str] = []
        chase = self.chase if self.chase is not None else self.ltc
        if chase is not None:
            cp = chase.poll(t)
            events += cp.events
            self.offset = (0.0 if cp.show_time_s is None else cp.show_time_s) - t
        sync = self.multisync
        if sync is not None:  # an FPP master's time
            for ev in sync.poll(t):
                events.append(ev)
                if sync.stop_requested and ev.kind in ("multisync_stop", "input_lost"):
                    self.counts["stops"] += 1
                    if self._stop is not None:
                        self._stop.request_command(str(ev.detail["message"]))
            self.offset = sync.show_time(t) - t
        t_show = t + self.offset
        osc = self.osc
        if osc is not None:
            for ev in osc.poll(t):
                if ev.kind == "cue":
                    triggers.append("osc:" + ev.detail["address"])
                    events.append(ev)
                elif ev.kind == "release":
                    events += self.release(ev.detail["joint"], ev.t, ev.detail["message"], "osc")
                elif ev.kind == "stop":
                    self._stop_command(ev.detail.get("message", "OSC /hilsim/stop"), ev, events)
                else:
                    events.append(ev)
            for joint in osc.updated:  # only what arrived: a held value is set already
                cur = osc.targets.get(joint)
                assert cur is not None  # set by this poll; only a release before it forgets
                self._set(joint, cur.deg, cur.t, "osc", events)
        midi = self.midi
        if midi is not None:
            mp = midi.poll(t)
            events += mp.events
            for tm, joint, deg in mp.samples:
                self._set(joint, deg, tm, "midi", events)
        for dmx in self.dmx:
            dp = dmx.poll(t)
            events += dp.events
            for joint in dp.releases:
                events += self.release(joint, t, f"{dmx.name} value 0 (zero = release)", dmx.source)
            for joint, deg, tm in dp.values:
                self._set(joint, deg, tm, dmx.source, events)
        if self.midi_triggers is not None:
            triggers += [key for _, key in self.midi_triggers.poll(t)]
        for part in (self.gamepad, self.bottango, self.api):
            if part is not None:
                self._poll_part(part, t, events, triggers)
        if self.keyboard is not None:
            triggers += self.keyboard.poll(t)
        teach = self.teach
        if teach is not None:
            present_deg = [math.degrees(x) for x in present_rad]
            teach.record(t, present_deg)
            for joint, deg in teach.targets_deg(present_deg).items():
                self.layer.teach(self.index[joint], math.radians(deg))
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

    def _set(
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

    def _poll_part(
        self,
        part: GamepadInput | BottangoLive | Controls,
        t: float,
        events: list[LiveEvent],
        triggers: list[str],
    ) -> None:
        """A gamepad, the Bottango live driver or the program's controls: releases, values,
        triggers, events, a stop. The gamepad and Bottango report a standing value every
        tick; the controls only what was set."""
        p = part.poll(t)
        events += getattr(p, "events", ())
        triggers += getattr(p, "triggers", ())
        source = "api" if part is self.api else getattr(part, "source", "bottango")
        for joint in getattr(p, "releases", ()):
            events += self.release(joint, t, "Show.release()", source)
        for joint, deg in (getattr(p, "values", None) or {}).items():
            if deg is not None:
                self._set(joint, deg, t, source, events, standing=part is not self.api)
        if getattr(p, "stop", False):  # the part's own events say it (one line)
            what = getattr(p, "stop_reason", None) or f"{type(part).__name__} stop"
            self.counts["stops"] += 1
            if self._stop is not None:
                self._stop.request_command(what)

    def _stop_command(self, what: str, ev: LiveEvent, events: list[LiveEvent]) -> None:
        events.append(ev)
        self.counts["stops"] += 1
        if self._stop is not None:
            self._stop.request_command(what)

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

    def _event(self, k: int, ev: LiveEvent) -> None:
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
        if self.chase is not None:
            parts.append(f"MTC {self.chase.state}")
        if self.ltc is not None:
            parts.append(self.ltc.status)
        if self.multisync is not None:
            parts.append(f"MultiSync {self.multisync.state}")
        return "; ".join(parts)

    # ------------------------------------------------------------------ the end
    def close(self, run_dir: Path | None) -> JsonDict:
        """Stop the inputs; write the take (raw CSV and reduced keys) into ``run_dir``;
        return the summary's ``live`` section. Never raises: a full disk is said in it."""
        self.close_inputs()
        out: JsonDict = {"show": self.spec.name, **self.counts, **self.layer.counts}
        if self.osc is not None:
            out["osc_drops"] = self.osc.guard.drops.snapshot()
        for dmx in self.dmx:
            out[dmx.source] = dmx.summary()
        parts = ("midi", "chase", "multisync", "bottango", "gamepad", "keyboard", "teach", "audio")
        for name in (*parts, "ltc"):
            part = getattr(self, name)
            summary = getattr(part, "summary", None)
            if callable(summary):
                try:
                    out[name] = summary()
                except Exception as exc:  # a summary is a report: never the exit path's end
                    out[name] = {"error": repr(exc)}
        if run_dir is not None:
            out["takes"] = self._write_takes(run_dir)
        return out

    def _write_takes(self, run_dir: Path) -> JsonDict:
        written: JsonDict = {}
        try:
            if self.take is not None and any(len(self.take.raw(j)[0]) for j in self.take.joints):
                from hilsim.live.takes import write_take

                assert self.spec.record is not None  # the take is made from it
                written["live"] = write_take(
                    self.take, run_dir / "take", self.spec.record.tolerance_deg
                )
            if self.teach is not None:
                written["teach"] = self.teach.finish(run_dir / "teach")
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
