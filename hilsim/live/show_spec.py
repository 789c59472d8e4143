"""The show file's clips, sounds, idle layer, cues and timeline, read into a :class:`RuntimeSpec`.

The sections read here (paths relative to the show file):

- ``[clips.<name>]``: a rig target table per joint; a joint a clip does not name keeps what is
  under it (the idle clip, else the rig's own target);
- ``[sounds]``: a file per clip, or ``{ file, offset_ms }``; and the output's settings
  ``device`` (a name or an index, as sounddevice takes it) and ``required`` (no output at the
  start of a real-time show: refused, instead of a warning and a silent show);
- ``[idle]`` (or ``idle = [...]``): clips, ``order`` (``"sequence"`` or ``"random"``), ``seed``;
- ``[cues.<name>]``: ``trigger``, ``clip``, ``then``, ``lockout_s``, ``window``;
- ``[[timeline]]``: ``at_s``, ``clip``, ``loop``.

Trigger strings and windows: :mod:`hilsim.live.triggers`. Every cue also answers the OSC address
``/hilsim/cue/<its name>``. A cue named ``idle`` or ``hold`` is refused (``then`` would be
ambiguous). Every error is one ``ValueError`` line naming the file and the key, e.g.
``show.toml: cues.scare.lockout_s: must be a finite number >= 0, got -1``.

An example of every key: ``docs/live.md`` (the show file).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilsim.live.triggers import TIMER_KINDS, Trigger, Window, parse_trigger, parse_window
from hilsim.rig.clips import CLIP_NAME_RE
from hilsim.targets.sources import rig_file
from hilsim.targets.tracks import Track

#: what ``make_track(spec, joint_name, where)`` is: one clip track from its target table
MakeTrack = Callable[[dict[str, Any], str, str], Track]

CUE_KEYS = ("trigger", "clip", "then", "lockout_s", "window")
IDLE_KEYS = ("clips", "order", "seed")
TIMELINE_KEYS = ("at_s", "clip", "loop")
ORDERS = ("sequence", "random")
#: the longest show time a show file may name (s): a week (a timeline entry, a lockout)
MAX_SHOW_S = 7 * 86400.0
#: the shortest idle clip, and the shortest clip a cycle of cues (a -> b -> a by `then`) may
#: play (s): shorter ones would restart every tick and flood the log
MIN_REPEAT_S = 0.1
#: the OSC address prefix every cue answers to (``/hilsim/cue/<name>``)
CUE_ADDRESS = "/hilsim/cue/"
#: the trigger key every cue answers from the program running the show (``Show.cue``)
API_CUE = "api:cue/"


@dataclass(frozen=True)
class Clip:
    """A named clip: one track per joint it drives (``tracks``: joint name -> track).
    ``duration``: when its last finite track ends (s), None if every track is endless."""

    name: str
    tracks: dict[str, Track]
    duration: float | None


@dataclass(frozen=True)
class Sound:
    """A clip's sound: ``path`` (checked to exist at load), ``offset_s``: how much later than
    its clip the sound is heard (``offset_ms`` / 1000; for a servo that lags its target;
    negative: earlier). The player applies it (:mod:`hilsim.live.audio_out`)."""

    path: Path
    offset_s: float = 0.0


#: the keys of ``[sounds]`` that set up the output, never a clip's name
SOUND_SETTINGS = ("device", "required")


@dataclass(frozen=True)
class SoundOutput:
    """``[sounds]`` ``device`` (None: the default output) and ``required``."""

    device: str | int | None = None
    required: bool = False


@dataclass(frozen=True)
class IdleSpec:
    """The idle layer: ``clips`` in order, ``order`` "sequence" | "random", ``seed`` (None:
    the show's)."""

    clips: tuple[str, ...]
    order: str = "sequence"
    seed: int | None = None


@dataclass(frozen=True)
class CueSpec:
    """One cue: its ``triggers``, the ``clip`` it plays, ``then`` ("idle", "hold" or a cue's
    name), ``lockout_s`` and an optional ``window``."""

    name: str
    triggers: tuple[Trigger, ...]
    clip: str
    then: str = "idle"
    lockout_s: float = 0.0
    window: Window | None = None


@dataclass(frozen=True)
class TimelineEntry:
    """``[[timeline]]``: ``clip`` starts at show time ``at_s``; ``loop``: again at its end."""

    at_s: float
    clip: str
    loop: bool = False


@dataclass(frozen=True)
class RuntimeSpec:
    """Everything :class:`hilsim.live.show.ShowRuntime` plays (``read_runtime``)."""

    clips: dict[str, Clip] = field(default_factory=dict)
    sounds: dict[str, Sound] = field(default_factory=dict)
    sound_output: SoundOutput = field(default_factory=SoundOutput)
    idle: IdleSpec | None = None
    cues: dict[str, CueSpec] = field(default_factory=dict)
    timeline: tuple[TimelineEntry, ...] = ()

    @property
    def trigger_keys(self) -> tuple[str, ...]:
        """Every input trigger key a cue answers (normalised, sorted): what the director's
        inputs should listen for. Includes ``osc:/hilsim/cue/<name>`` for every cue."""
        keys = {t.key for c in self.cues.values() for t in c.triggers if t.kind not in TIMER_KINDS}
        keys.update(f"osc:{CUE_ADDRESS}{name}" for name in self.cues)
        return tuple(sorted(keys))


# ------------------------------------------------------------------------------ small readers


class _Section:
    """Error messages for one file: ``fail(key, what)`` -> ValueError("<where>: <key>: what")."""

    def __init__(self, where: str) -> None:
        self.where = where

    def fail(self, key: str, what: str) -> ValueError:
        return ValueError(f"{self.where}: {key}: {what}")

    def table(self, key: str, value: Any) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a table, got {value!r}")
        return value

    def unknown(self, key: str, table: dict[str, Any], allowed: Sequence[str]) -> None:
        for k in table:
            if k not in allowed:
                raise self.fail(f"{key}.{k}", f"unknown key; the keys are {', '.join(allowed)}")

    def name(self, key: str, value: Any, what: str = "a clip name") -> str:
        if not isinstance(value, str) or not CLIP_NAME_RE.fullmatch(value):
            raise self.fail(
                key, f"{what} is letters, digits and _ . + - (at most 64), got {value!r}"
            )
        return value

    def clip_ref(self, key: str, value: Any, clips: dict[str, Clip]) -> str:
        if not isinstance(value, str) or value not in clips:
            have = ", ".join(clips) or "none"
            raise self.fail(key, f"no clip {value!r}; the clips are {have}")
        return value

    def number(
        self,
        key: str,
        value: Any,
        *,
        default: float | None = None,
        lo: float = 0.0,
        hi: float = MAX_SHOW_S,
    ) -> float:
        """A finite number in lo..hi (by default a show time: 0..MAX_SHOW_S)."""
        if value is None and default is not None:
            return default
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(key, f"must be a finite number in {lo:g}..{hi:g}, got {value!r}")
        x = float(value)
        if not (math.isfinite(x) and lo <= x <= hi):
            raise self.fail(key, f"must be a finite number in {lo:g}..{hi:g}, got {value!r}")
        return x


# ------------------------------------------------------------------------------ the sections


def read_runtime(
    doc: dict[str, Any],
    where: str,
    base_dir: Path,
    joint_names: Sequence[str],
    make_track: MakeTrack,
) -> RuntimeSpec:
    """The clips, sounds, idle, cues and timeline of a parsed show file ``doc``.

    Args:
        doc: the whole file as parsed TOML (other sections are left to their readers).
        where: the file, for messages (e.g. ``"show.toml"``).
        base_dir: what relative sound paths are relative to (the show file's directory).
        joint_names: the rig's joints.
        make_track: ``make_track(spec, joint, where)`` builds one clip track from its target
            table (``where`` e.g. ``"clips.scare.jaw"``); its errors pass through.

    Raises:
        ValueError: one line, ``"<where>: <key>: <what is wrong>"``.
    """
    s = _Section(where)
    clips = _clips(s, doc.get("clips", {}), tuple(joint_names), make_track)
    raw_sounds = s.table("sounds", doc.get("sounds", {}))
    sounds = _sounds(s, raw_sounds, Path(base_dir), clips)
    output = _sound_output(s, raw_sounds)
    idle = _idle(s, doc["idle"], clips) if "idle" in doc else None
    cues = _cues(s, doc.get("cues", {}), clips)
    timeline = _timeline(s, doc.get("timeline", []), clips)
    _short_cycles(s, cues, clips)
    return RuntimeSpec(clips=clips, sounds=sounds, sound_output=output, idle=idle, cues=cues,
                       timeline=timeline)  # fmt: skip


def _clips(
    s: _Section, raw: Any, joints: tuple[str, ...], make_track: MakeTrack
) -> dict[str, Clip]:
    clips: dict[str, Clip] = {}
    for name, table in s.table("clips", raw).items():
        key = f"clips.{name}"
        s.name(key, name)
        if not isinstance(table, dict) or not table:
            raise s.fail(key, f"must be a table of <joint> = <target table>, got {table!r}")
        tracks: dict[str, Track] = {}
        for joint, target in table.items():
            jkey = f"{key}.{joint}"
            if joint not in joints:
                raise s.fail(jkey, f"no such joint; the joints are {', '.join(joints)}")
            if not isinstance(target, dict):
                raise s.fail(jkey, f"must be a target table, got {target!r}")
            tracks[joint] = make_track(target, joint, jkey)
        ends = [d for d in (tr.duration for tr in tracks.values()) if d is not None]
        clips[name] = Clip(name, tracks, max(ends) if ends else None)
    return clips


def _sounds(s: _Section, raw: Any, base_dir: Path, clips: dict[str, Clip]) -> dict[str, Sound]:
    sounds: dict[str, Sound] = {}
    for clip, value in s.table("sounds", raw).items():
        if clip in SOUND_SETTINGS:
            continue
        key = f"sounds.{clip}"
        s.clip_ref(key, clip, clips)
        offset_ms: Any = 0
        if isinstance(value, dict):
            s.unknown(key, value, ("file", "offset_ms"))
            if "file" not in value:
                raise s.fail(f"{key}.file", "missing: the sound file's path")
            file, offset_ms = value["file"], value.get("offset_ms", 0)
            fkey = f"{key}.file"
        else:
            file, fkey = value, key
        if not isinstance(file, str) or not file:
            raise s.fail(fkey, f"must be a sound file's path (a string), got {file!r}")
        path = rig_file(base_dir, file)
        if not path.is_file():
            raise s.fail(fkey, f"no such sound file: {path}")
        offset = s.number(f"{key}.offset_ms", offset_ms, lo=-10_000.0, hi=10_000.0)
        sounds[clip] = Sound(path, offset / 1000.0)
    return sounds


def _sound_output(s: _Section, raw: dict[str, Any]) -> SoundOutput:
    device = raw.get("device")
    ok = device is None or (isinstance(device, str) and device.strip()) or (
        isinstance(device, int) and not isinstance(device, bool) and device >= 0
    )  # fmt: skip
    if not ok:
        raise s.fail(
            "sounds.device",
            f"an output device's name or index (hilsim sounds lists them), got {device!r}",
        )
    required = raw.get("required", False)
    if not isinstance(required, bool):
        raise s.fail("sounds.required", f"true or false, got {required!r}")
    return SoundOutput(device, required)


def _idle(s: _Section, raw: Any, clips: dict[str, Clip]) -> IdleSpec:
    if isinstance(raw, list):  # idle = ["breathe", ...]
        raw = {"clips": raw}
    table = s.table("idle", raw)
    s.unknown("idle", table, IDLE_KEYS)
    names = table.get("clips")
    if not isinstance(names, list) or not names:
        raise s.fail("idle.clips", f"must be a list of one or more clip names, got {names!r}")
    for i, name in enumerate(names):
        s.clip_ref(f"idle.clips[{i}]", name, clips)
        dur = clips[name].duration
        if dur is not None and dur < MIN_REPEAT_S:
            raise s.fail(
                f"idle.clips[{i}]",
                f"clip {name!r} lasts {dur:g} s; an idle clip must last {MIN_REPEAT_S:g} s or more",
            )
    order = table.get("order", "sequence")
    if order not in ORDERS:
        raise s.fail("idle.order", f"must be one of {', '.join(ORDERS)}, got {order!r}")
    seed = table.get("seed")
    if seed is not None and (
        isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63
    ):
        raise s.fail("idle.seed", f"must be an integer >= 0, got {seed!r}")
    return IdleSpec(tuple(names), order, seed)


def _cues(s: _Section, raw: Any, clips: dict[str, Clip]) -> dict[str, CueSpec]:
    tables = s.table("cues", raw)
    cues: dict[str, CueSpec] = {}
    for name, table in tables.items():
        key = f"cues.{name}"
        s.name(key, name, "a cue name")
        if name in ("idle", "hold"):
            raise s.fail(key, f"{name!r} is a word `then` uses; name the cue otherwise")
        table = s.table(key, table)
        s.unknown(key, table, CUE_KEYS)
        if "clip" not in table:
            raise s.fail(f"{key}.clip", "missing: the clip the cue plays")
        clip = s.clip_ref(f"{key}.clip", table["clip"], clips)
        raw_trig = table.get("trigger", [])
        raw_list = [raw_trig] if isinstance(raw_trig, str) else raw_trig
        if not isinstance(raw_list, list):
            raise s.fail(f"{key}.trigger", f"must be a string or a list of them, got {raw_trig!r}")
        triggers = []
        for i, text in enumerate(raw_list):
            tkey = f"{key}.trigger" if isinstance(raw_trig, str) else f"{key}.trigger[{i}]"
            try:
                triggers.append(parse_trigger(text))
            except ValueError as exc:
                raise s.fail(tkey, str(exc)) from None
        then = table.get("then", "idle")
        if not isinstance(then, str) or (then not in ("idle", "hold") and then not in tables):
            have = ", ".join(tables)
            raise s.fail(
                f"{key}.then", f"must be 'idle', 'hold' or a cue's name ({have}), got {then!r}"
            )
        lockout = s.number(f"{key}.lockout_s", table.get("lockout_s", 0))
        window = None
        if "window" in table:
            try:
                window = parse_window(table["window"])
            except ValueError as exc:
                raise s.fail(f"{key}.window", str(exc)) from None
        cues[name] = CueSpec(name, tuple(triggers), clip, then, lockout, window)
    return cues


def _short_cycles(s: _Section, cues: dict[str, CueSpec], clips: dict[str, Clip]) -> None:
    """Cues whose ``then`` come back round to themselves through clips that all end within
    MIN_REPEAT_S would start and end every tick: refused, naming the cycle."""
    for first in cues:
        path, name = [first], cues[first].then
        while name in cues and name not in path:
            path.append(name)
            name = cues[name].then
        if name != first:
            continue
        durations = [clips[cues[c].clip].duration for c in path]
        if all(d is not None and d < MIN_REPEAT_S for d in durations):
            loop = " -> ".join([*path, first])
            raise s.fail(
                f"cues.{first}.then",
                f"the cues {loop} go round through clips shorter than {MIN_REPEAT_S:g} s: they "
                "would restart every tick; lengthen a clip or end the round with 'idle'/'hold'",
            )


def _timeline(s: _Section, raw: Any, clips: dict[str, Clip]) -> tuple[TimelineEntry, ...]:
    if not isinstance(raw, list):
        raise s.fail("timeline", f"must be [[timeline]] tables (at_s, clip, loop), got {raw!r}")
    entries: list[TimelineEntry] = []
    for i, table in enumerate(raw):
        key = f"timeline[{i}]"
        table = s.table(key, table)
        s.unknown(key, table, TIMELINE_KEYS)
        if "at_s" not in table:
            raise s.fail(f"{key}.at_s", "missing: when the clip starts (show time, s)")
        at = s.number(f"{key}.at_s", table["at_s"])
        if entries and not at > entries[-1].at_s:
            raise s.fail(f"{key}.at_s", f"must be after timeline[{i - 1}]'s {entries[-1].at_s:g} s")
        if "clip" not in table:
            raise s.fail(f"{key}.clip", "missing: the clip to start")
        clip = s.clip_ref(f"{key}.clip", table["clip"], clips)
        loop = table.get("loop", False)
        if not isinstance(loop, bool):
            raise s.fail(f"{key}.loop", f"must be true or false, got {loop!r}")
        dur = clips[clip].duration
        if loop and dur is not None and dur < MIN_REPEAT_S:
            raise s.fail(
                f"{key}.loop",
                f"clip {clip!r} lasts {dur:g} s; a looped clip must last "
                f"{MIN_REPEAT_S:g} s or more",
            )
        entries.append(TimelineEntry(at, clip, loop))
    return tuple(entries)
