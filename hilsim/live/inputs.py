"""The show's live inputs: each one built, opened, polled once a tick and closed, in one place.

:class:`LiveInputs` holds what a show file's ``[inputs.*]`` (and ``--live``) ask for: the
clocks a show can follow (MTC or LTC chase, FPP MultiSync), the value inputs (OSC, MIDI CC, sACN,
Art-Net, gamepad, Bottango live, the program's controls, teach-by-hand), the triggers (OSC,
MIDI notes, keys) and the show's sound output. The director owns the decisions (who holds a
joint, the show runtime, the log); this module only turns each input's poll into calls on the
director (:class:`Sink`): a value, a release, a stop, a hand-taught pose.

To add an input: build it in :meth:`LiveInputs.__init__` (its module imported only when a show
uses it), start its receiver in :meth:`LiveInputs.open` (a closer and one line saying where it
listens), poll it in :meth:`LiveInputs.show_time` (a clock) or :meth:`LiveInputs.poll` (values,
triggers) and name it in :data:`SUMMARIES` for the summary's ``live`` section. The director's
tick does not change. Nothing here waits: each receiver's thread hands over under its lock.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from hilsim._types import JsonDict
from hilsim.live.controls import Controls
from hilsim.live.inbox import LiveEvent
from hilsim.live.showfile import ShowSpec

if TYPE_CHECKING:  # each input's module is imported when a show uses that input
    from drivers.clock import Clock
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
    from hilsim.live.teach import Teach
    from hilsim.live.timecode import MtcChase

#: the inputs whose ``summary()`` goes into the summary's ``live`` section, in this order
SUMMARIES = (
    "midi", "chase", "multisync", "bottango", "gamepad", "keyboard", "teach", "audio", "ltc",
)  # fmt: skip


class Sink(Protocol):
    """Where the inputs' polls go: the director (its live layer, its stop flag)."""

    def set_value(
        self,
        joint: str,
        deg: float,
        t_msg: float,
        source: str = "api",
        events: list[LiveEvent] | None = None,
        *,
        standing: bool = False,
    ) -> None: ...

    def release(
        self, joint: str | None, t: float, reason: str, source: str = "show"
    ) -> list[LiveEvent]: ...

    def request_stop(self, what: str) -> None: ...

    def teach_value(self, joint: str, deg: float) -> None: ...


def has_live_inputs(spec: ShowSpec) -> bool:
    """Does the show take anything live (then a timeline does not end it)?"""
    return any(
        x is not None
        for x in (spec.osc, spec.midi, spec.bottango, spec.gamepad, spec.keyboard, spec.teach,
                  spec.sacn, spec.artnet, spec.multisync)
    )  # fmt: skip


class LiveInputs:
    """The inputs' state machines (no I/O until :meth:`open`); ``silent``: sounds scheduled and
    logged, not played (virtual time: no sound device)."""

    def __init__(
        self,
        spec: ShowSpec,
        names: Sequence[str],
        runtime: ShowRuntime | None,
        *,
        silent: bool = False,
    ) -> None:
        self.spec = spec
        self._closers: list[Callable[[], None]] = []
        keys = tuple(getattr(runtime, "trigger_keys", ()) or ())
        _unheard_triggers(spec, keys)
        self.osc: OscInput | None = None
        self.midi: MidiCcInput | None = None
        self.midi_triggers: MidiTriggerInput | None = None
        self.chase: MtcChase | None = None
        self.bottango: BottangoLive | None = None
        self.gamepad: GamepadInput | None = None
        self.keyboard: KeyboardInput | None = None
        self.teach: Teach | None = None
        self.audio: AudioOut | None = None
        cues = () if runtime is None else tuple(runtime.spec.cues)
        #: cues and joint values from the program running the show (hilsim.Show)
        self.api = Controls(names, cues)
        if spec.osc is not None:
            from hilsim.live.osc import OscInput

            osc_keys = [k[4:] for k in keys if k.startswith("osc:")]
            self.osc = OscInput(
                spec.osc.joints,
                guard=spec.osc.guard,
                lost_after_s=spec.osc.lost_after_s,
                triggers=[a for a in osc_keys if not a.startswith("/hilsim/cue/")],
                releasable=names,
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
        #: LTC (a WAV file or an audio input): the show's chase when it has no MTC
        self.ltc: LtcChase | None = None
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

            self.teach = Teach(names, spec.teach)
        self.audio = _audio_out(runtime, silent)

    # ------------------------------------------------------------------ life cycle
    def open(self, clock: Clock, now: Callable[[], float], say: Callable[[str], None]) -> None:
        """Start the receivers (sockets, ports, threads), stamping with ``now()`` (on the real
        ``clock``, at the kernel's arrival time). Raises
        ValueError / OSError / RuntimeError with one line on a port that cannot be opened
        (what was opened is closed first)."""
        spec = self.spec
        if clock.virtual and spec.ltc is not None and not spec.ltc.is_wav:
            raise ValueError(
                f"inputs.ltc.source = {spec.ltc.source!r}: an audio input runs in real time, "
                "a --virtual-time show does not; rehearse on a WAV of the timecode "
                "(tools/make_ltc_wav.py), or run in real time"
            )
        #: real clock: each datagram stamped when the kernel received it (netguard)
        stamps = not clock.virtual
        try:
            if self.osc is not None:
                from hilsim.live.osc import listen

                assert spec.osc is not None  # self.osc is built from it
                rx = listen(self.osc, spec.osc.port, now, max_rx_per_s=spec.osc.max_rx_per_s,
                            arrival_stamps=stamps)  # fmt: skip
                self._closers.append(rx.close)
                say(f"OSC on {spec.osc.guard.bind_address}:{spec.osc.port}: "
                    f"/hilsim/joint/<{'|'.join(self.osc.ranges)}> 0..1, /hilsim/cue/<name>, "
                    "/hilsim/release[/<joint>], /hilsim/stop")  # fmt: skip
            for dmx in self.dmx:
                from hilsim.live.dmx_input import listen as dmx_listen

                rx = dmx_listen(dmx, now, max_rx_per_s=dmx.config.max_rx_per_s,
                                arrival_stamps=stamps)  # fmt: skip
                self._closers.append(rx.close)
                c = dmx.config
                groups = " (multicast)" if c.multicast else " (broadcast)" if c.broadcast else ""
                say(f"{dmx.name} on {dmx.config.guard.bind_address}:{dmx.config.port}{groups}: "
                    f"universes {', '.join(map(str, dmx.config.universes))}")  # fmt: skip
            if self.multisync is not None:
                from hilsim.live.multisync import listen as sync_listen

                rx = sync_listen(self.multisync, now, arrival_stamps=stamps)
                self._closers.append(rx.close)
                ms = self.multisync.config
                say(f"FPP MultiSync on {ms.guard.bind_address}:{ms.port}"
                    f"{' (multicast)' if ms.multicast else ''}: "
                    f"following {ms.sequence or 'any sequence'}")  # fmt: skip
            sinks = [s for s in (self.midi, self.midi_triggers, self.chase) if s is not None]
            if sinks:
                from hilsim.live.midi import open_midi_input

                assert spec.midi is not None  # the show file gives [inputs.mtc] one too
                port = open_midi_input(spec.midi.port, sinks, now)
                self._closers.append(port.close)
                say(f"MIDI in: {port.name}")
            for part in (self.bottango, self.gamepad, self.keyboard, self.audio, self.ltc):
                if part is not None and hasattr(part, "start"):
                    note = part.start(now)
                    self._closers.append(part.close)
                    if note:
                        say(str(note))
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop every receiver, last opened first; closing never stops the exit path."""
        while self._closers:
            close = self._closers.pop()
            with contextlib.suppress(Exception):
                close()

    # ------------------------------------------------------------------ one tick
    def show_time(self, t: float, events: list[LiveEvent], sink: Sink) -> float | None:
        """The show time at loop time ``t`` from the clock the show follows (MTC chase, FPP
        MultiSync; the later one named wins), None: the show follows its own clock."""
        t_show: float | None = None
        chase = self.chase if self.chase is not None else self.ltc
        if chase is not None:
            cp = chase.poll(t)
            events += cp.events
            t_show = 0.0 if cp.show_time_s is None else cp.show_time_s
        sync = self.multisync
        if sync is not None:  # an FPP master's time
            for ev in sync.poll(t):
                events.append(ev)
                if sync.stop_requested and ev.kind in ("multisync_stop", "input_lost"):
                    sink.request_stop(str(ev.detail["message"]))
            t_show = sync.show_time(t)
        return t_show

    def poll(
        self,
        t: float,
        present_rad: Sequence[float],
        events: list[LiveEvent],
        triggers: list[str],
        sink: Sink,
    ) -> None:
        """Each input's news at loop time ``t`` into ``sink``; events and trigger keys are
        appended to ``events`` and ``triggers``. ``present_rad``: the joints' present
        positions (joint frame) read this tick (teach-by-hand follows them)."""
        osc = self.osc
        if osc is not None:
            for ev in osc.poll(t):
                if ev.kind == "cue":
                    triggers.append("osc:" + ev.detail["address"])
                    events.append(ev)
                elif ev.kind == "release":
                    events += sink.release(ev.detail["joint"], ev.t, ev.detail["message"], "osc")
                elif ev.kind == "stop":
                    events.append(ev)
                    sink.request_stop(ev.detail.get("message", "OSC /hilsim/stop"))
                else:
                    events.append(ev)
            for joint in osc.updated:  # only what arrived: a held value is set already
                cur = osc.targets.get(joint)
                assert cur is not None  # set by this poll; only a release before it forgets
                sink.set_value(joint, cur.deg, cur.t, "osc", events)
        midi = self.midi
        if midi is not None:
            mp = midi.poll(t)
            events += mp.events
            for tm, joint, deg in mp.samples:
                sink.set_value(joint, deg, tm, "midi", events)
        for dmx in self.dmx:
            dp = dmx.poll(t)
            events += dp.events
            for joint in dp.releases:
                events += sink.release(joint, t, f"{dmx.name} value 0 (zero = release)", dmx.source)
            for joint, deg, tm in dp.values:
                sink.set_value(joint, deg, tm, dmx.source, events)
        if self.midi_triggers is not None:
            triggers += [key for _, key in self.midi_triggers.poll(t)]
        for part in (self.gamepad, self.bottango, self.api):
            if part is not None:
                self._poll_part(part, t, events, triggers, sink)
        if self.keyboard is not None:
            triggers += self.keyboard.poll(t)
        teach = self.teach
        if teach is not None:
            present_deg = [math.degrees(x) for x in present_rad]
            teach.record(t, present_deg)
            for joint, deg in teach.targets_deg(present_deg).items():
                sink.teach_value(joint, deg)

    def _poll_part(
        self,
        part: GamepadInput | BottangoLive | Controls,
        t: float,
        events: list[LiveEvent],
        triggers: list[str],
        sink: Sink,
    ) -> None:
        """A gamepad, the Bottango live driver or the program's controls: releases, values,
        triggers, events, a stop. The gamepad and Bottango report a standing value every
        tick; the controls only what was set."""
        p = part.poll(t)
        events += getattr(p, "events", ())
        triggers += getattr(p, "triggers", ())
        source = "api" if part is self.api else getattr(part, "source", "bottango")
        for joint in getattr(p, "releases", ()):
            events += sink.release(joint, t, "Show.release()", source)
        for joint, deg in (getattr(p, "values", None) or {}).items():
            if deg is not None:
                sink.set_value(joint, deg, t, source, events, standing=part is not self.api)
        if getattr(p, "stop", False):  # the part's own events say it (one line)
            sink.request_stop(getattr(p, "stop_reason", None) or f"{type(part).__name__} stop")

    # ------------------------------------------------------------------ reports
    def states(self) -> list[str]:
        """The followed clocks' states for the status line (``MTC locked``, ...)."""
        out = []
        if self.chase is not None:
            out.append(f"MTC {self.chase.state}")
        if self.ltc is not None:
            out.append(self.ltc.status)
        if self.multisync is not None:
            out.append(f"MultiSync {self.multisync.state}")
        return out

    def summary(self) -> JsonDict:
        """Each input's own report for the summary's ``live`` section; never raises."""
        out: JsonDict = {}
        if self.osc is not None:
            out["osc_drops"] = self.osc.guard.drops.snapshot()
        for dmx in self.dmx:
            out[dmx.source] = dmx.summary()
        for name in SUMMARIES:
            summary = getattr(getattr(self, name), "summary", None)
            if callable(summary):
                try:
                    out[name] = summary()
                except Exception as exc:  # a summary is a report: never the exit path's end
                    out[name] = {"error": repr(exc)}
        return out


def _unheard_triggers(spec: ShowSpec, keys: Sequence[str]) -> None:
    """A trigger nothing in this show can send: a note said at load."""
    heard: dict[str, Any] = {"osc": spec.osc, "midi": spec.midi, "key": spec.keyboard}
    section = {"osc": "osc", "midi": "midi", "key": "keyboard"}
    for key in keys:
        kind = key.split(":", 1)[0]
        cue_address = key.startswith("osc:/hilsim/cue/")  # every cue's own, always listed
        if heard.get(kind, True) is None and spec.gamepad is None and not cue_address:
            spec.notes.append(
                f"trigger {key!r}: the show has no [inputs.{section[kind]}], so nothing can send it"
            )


def _audio_out(runtime: ShowRuntime | None, silent: bool) -> AudioOut | None:
    """The show's sound output when its clips have sounds (preloaded: a bad file is said at
    load as ``sounds: ...``)."""
    sounds = getattr(getattr(runtime, "spec", None), "sounds", None)
    if not sounds:
        return None
    from hilsim.live.audio_out import AudioOut, SilentBackend

    assert runtime is not None  # the sounds are the runtime's
    out = runtime.spec.sound_output
    audio = AudioOut(
        SilentBackend() if silent else None,
        device=None if out is None else out.device,
        required=out is not None and out.required,
    )
    try:
        audio.preload(
            [s.path for s in sounds.values()],
            offsets_ms={str(s.path): s.offset_s * 1e3 for s in sounds.values()},
        )
    except ValueError as exc:
        raise ValueError(f"sounds: {exc}") from None
    return audio
