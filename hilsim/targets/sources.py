"""Rig target specs that name another tool's animation file, turned into tracks.

:func:`hilsim.targets.spec.track_from_spec` hands a spec of one of these types here::

    {type = "bottango", file, effector, degrees, signal? | movement?, animation? = 0}
    {type = "blender_servo", file, servo, position, degrees, interpolation? = "hold",
     fps? (.bin only)}
    {type = "fseq", file, channel, degrees, fine?, values? (default the full 8/16-bit range),
     zero? = "value", interpolation? = "hold"}
    {type = "audio", file, degrees, audio_channel? = "mix", window_ms?, attack_ms?, release_ms?,
     threshold?, full?, band_hz?, lead_ms? = 0 | "auto"}
    {type = "lipsync", file, degrees, shapes, preston_blair?, fps? (Moho .dat), voice?,
     names? = "auto"}
    {type = "midi", file, channel, degrees, control? | note?, fine? = false,
     interpolation? = "hold"}

``degrees`` is the pair of joint angles the file's two reference values map to: the signal
range's ends (``signal``, default the effector's registered range), the positions
(``position``), the DMX values (``values``), a shut and a wide-open jaw (audio: opening 0 and
1; lip-sync: shape values 0 and 1), a MIDI value 0 and 127 (16383 ``fine``) or a note off and
on. The files never say their units, so the rig always does.
Files are relative to the rig file and read once per build (``cache``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from hilsim.dynamics.springs import Spring
from hilsim.targets.formats.common import FormatError, UnitMap
from hilsim.targets.tracks import Track

if TYPE_CHECKING:
    from hilsim.targets.formats.bottango import BottangoExport

#: per source type: (required keys, optional keys), besides "type"
SOURCE_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "bottango": (("file", "effector", "degrees"), ("animation", "signal", "movement")),
    "blender_servo": (("file", "servo", "position", "degrees"), ("interpolation", "fps")),
    "fseq": (
        ("file", "channel", "degrees"),
        ("fine", "values", "zero", "interpolation"),
    ),
    "audio": (
        ("file", "degrees"),
        (
            "audio_channel",
            "window_ms",
            "attack_ms",
            "release_ms",
            "threshold",
            "full",
            "band_hz",
            "lead_ms",
        ),
    ),
    "lipsync": (("file", "degrees", "shapes"), ("preston_blair", "fps", "voice", "names")),
    "midi": (("file", "channel", "degrees"), ("control", "note", "fine", "interpolation")),
}


#: the highest frame rate a file's frames may be read at (a slip, beyond it)
MAX_FPS = 1000

#: a target table as the rig file gives it (TOML values)
Spec = Mapping[str, Any]
#: the files one build has read, by (reader, path, options): what each reader made of one
FileCache = dict[Hashable, Any]
#: what a file says its user should read, gathered over a build (None: not gathered)
Notes = list[str] | None
_T = TypeVar("_T")


class SourceError(ValueError):
    """A source spec key that cannot be used: ``key`` and the message, as SpecError has."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key, self.detail = key, message


def _pair(spec: Mapping[str, Any], key: str) -> tuple[float, float]:
    value = spec[key]
    if (
        not isinstance(value, list | tuple)
        or len(value) != 2
        or not all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
            for x in value
        )
    ):
        raise SourceError(key, f"must be two finite numbers [a, b], got {value!r}")
    return float(value[0]), float(value[1])


def _number(spec: Mapping[str, Any], key: str) -> float:
    value = spec[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SourceError(key, f"must be a finite number, got {value!r}")
    return float(value)


def _unit(spec: Spec, source: str | tuple[float, float], unit: str) -> UnitMap:
    """The rig's map from ``source`` (a pair, or the key of the spec's pair) to its
    ``degrees``."""
    degrees = _pair(spec, "degrees")
    key, pair = (source, _pair(spec, source)) if isinstance(source, str) else ("degrees", source)
    try:
        return UnitMap(pair, degrees, unit)
    except ValueError as exc:
        raise SourceError(key, str(exc)) from None


def _cached(cache: FileCache | None, key: tuple[Hashable, ...], load: Callable[[], _T]) -> _T:
    if cache is None:
        return load()
    if key not in cache:
        cache[key] = load()
    made: _T = cache[key]  # the key names the reader: what it made
    return made


def _note(notes: Notes, *lines: str) -> None:
    """What the rig's user should read about a file, said once per build."""
    if notes is not None:
        notes.extend(line for line in lines if line not in notes)


def rig_file(base_dir: Path, name: str) -> Path:
    """A file a rig or show names: ``~`` is the user's home, a relative name is relative to
    the file that names it (``base_dir``)."""
    try:
        path = Path(name).expanduser()
    except RuntimeError:  # ~user of no such user: the name as it is (then "no such file")
        path = Path(name)
    return (Path(base_dir) / path).resolve()


def _file(spec: Mapping[str, Any], base_dir: Path) -> Path:
    file = spec["file"]
    if not isinstance(file, str) or not file:
        raise SourceError("file", f"must be a file name, got {file!r}")
    path = rig_file(base_dir, file)
    if not path.exists():
        raise SourceError("file", f"no such file: {path}")
    return path


def track_from_source(
    kind: str,
    spec: Mapping[str, Any],
    *,
    base_dir: Path,
    spring: Spring | None = None,
    cache: FileCache | None = None,
    notes: Notes = None,
) -> Track:
    """The track of a source spec (keys already checked against :data:`SOURCE_KEYS`).
    ``notes`` gathers what the files say that the user should read (a Bottango animation's
    playback settings, frames a Blender export left out). Raises SourceError for a bad key,
    FormatError (``file:where: ...``) for a bad file."""
    path = _file(spec, base_dir)
    return _BUILDERS[kind](spec, path, spring, cache, notes)


def _bottango(
    spec: Spec, path: Path, _spring: Spring | None, cache: FileCache | None, notes: Notes
) -> Track:
    from hilsim.targets.formats.bottango import read_export

    export = _cached(cache, ("bottango", path), lambda: read_export(path))
    _note(notes, *(f"{path.name}: {a.describe()}" for a in export.animations.values()))
    _note(notes, *(f"{path.name}: {line}" for line in export.info))
    effector = spec["effector"]
    if isinstance(effector, bool) or not isinstance(effector, str | int):
        raise SourceError("effector", f"must be the effector's identifier, got {effector!r}")
    animation = spec.get("animation", 0)
    if isinstance(animation, bool) or not isinstance(animation, str | int):
        raise SourceError("animation", f"must be an index or a name, got {animation!r}")
    if "signal" in spec and "movement" in spec:
        raise SourceError("movement", "give signal or movement, not both")
    _effector_exists(export, str(effector))
    if "movement" in spec:
        track = export.track(animation, str(effector), movement=_unit(spec, "movement", ""))
    elif "signal" in spec:
        track = export.track(animation, str(effector), signal=_unit(spec, "signal", "signal"))
    else:
        eff = export.effectors.get(str(effector))
        if eff is None or eff.signal_min is None or eff.signal_max is None:
            raise SourceError(
                "signal",
                f"effector {str(effector)!r} has no registered signal range in {export.path}: give "
                "movement = [0, 1] (Bottango's movement) with degrees",
            )
        # degrees at the ends of the effector's registered range (e.g. 1000-2000 µs)
        umap = _unit(spec, (eff.signal_min, eff.signal_max), eff.unit)
        track = export.track(animation, str(effector), signal=umap)
    behind = getattr(track, "behind", ())
    if behind:  # the driver's speed limit keeps its signal off the curves
        anim = export.animation(animation)
        name = f"animation {anim.index}" + (f' "{anim.name}"' if anim.name else "")
        (a, b), n = behind[0], len(behind)
        times = "once (" if n == 1 else f"{n} times (first "
        _note(notes, f"{path.name}: {name} effector {effector}: its registered speed limit "
              f"({getattr(track, 'limit', '')}) keeps the driver's signal off the curves {times}"
              f"{a:.3f}-{b:.3f} s); the target is that signal, as the driver moves the "
              "servo")  # fmt: skip
    return track


def _effector_exists(export: BottangoExport, effector: str) -> None:
    """A FormatError naming the export's effectors when ``effector`` is none of them: the
    first thing to fix, before any advice about its signal range or curves."""
    known = set(export.effectors)
    for anim in export.animations.values():
        known.update(anim.segments, anim.loop_segments)
    if effector not in known:
        have = sorted(known, key=lambda e: (not e.isdigit(), int(e) if e.isdigit() else 0, e))
        listed = ", ".join(have) or "none"
        raise FormatError(
            export.path, "", f"no effector {effector!r} in this export; it has {listed}"
        )


def _blender(
    spec: Spec, path: Path, _spring: Spring | None, cache: FileCache | None, notes: Notes
) -> Track:
    from hilsim.targets.formats.blender_servo import read_blender_servo

    fps = spec.get("fps")
    if fps is not None and (
        isinstance(fps, bool) or not isinstance(fps, int) or not 1 <= fps <= MAX_FPS
    ):
        raise SourceError("fps", f"must be a whole 1 .. {MAX_FPS:g} frames per second, got {fps!r}")
    anim = _cached(cache, ("blender_servo", path, fps), lambda: read_blender_servo(path, fps=fps))
    servo = spec["servo"]
    if isinstance(servo, bool) or not isinstance(servo, int):
        raise SourceError("servo", f"must be the servo ID in the export, got {servo!r}")
    umap = _unit(spec, "position", "position")
    track = anim.track(servo, umap, interpolation=spec.get("interpolation", "hold"))
    _note(notes, *anim.notes(servo))
    return track


def _fseq(
    spec: Spec, path: Path, _spring: Spring | None, cache: FileCache | None, _notes: Notes
) -> Track:
    from hilsim.targets.formats.fseq import FseqChannel, dmx_unit_map, read_fseq

    seq = _cached(cache, ("fseq", path), lambda: read_fseq(path))
    fine = spec.get("fine")
    if "values" in spec:
        umap = _unit(spec, "values", "DMX")
    else:
        umap = dmx_unit_map(_pair(spec, "degrees"), 8 if fine is None else 16)
    try:
        channel = FseqChannel(
            spec["channel"],
            umap,
            fine=fine,
            zero=spec.get("zero", "value"),
            interpolation=spec.get("interpolation", "hold"),
        )
    except ValueError as exc:
        raise SourceError("channel", str(exc)) from None
    return seq.tracks({"joint": channel})["joint"]


def _audio(
    spec: Spec, path: Path, spring: Spring | None, _cache: FileCache | None, _notes: Notes
) -> Track:
    from hilsim.targets.formats.audio_jaw import EnvelopeSettings, jaw_track, spring_lag_s

    settings: dict[str, Any] = {}
    for key in ("window_ms", "attack_ms", "release_ms", "threshold", "full"):
        if key in spec:
            settings[key] = _number(spec, key)
    if "band_hz" in spec:
        settings["band_hz"] = _pair(spec, "band_hz")
    try:
        env = EnvelopeSettings(**settings)
    except ValueError as exc:
        raise SourceError(str(exc).split(" ")[0], str(exc)) from None
    lead = spec.get("lead_ms", 0.0)
    if lead == "auto":
        if spring is None:
            raise SourceError("lead_ms", '"auto" needs the joint\'s spring')
        lead_s = spring_lag_s(spring)
    elif isinstance(lead, bool) or not isinstance(lead, int | float) or not math.isfinite(lead):
        raise SourceError("lead_ms", f'must be a number of ms or "auto", got {lead!r}')
    else:
        lead_s = lead / 1000.0
    channel = spec.get("audio_channel", "mix")
    jaw = _unit(spec, (0.0, 1.0), "opening")
    try:
        return jaw_track(path, jaw, env, channel=channel, lead_s=lead_s)
    except ValueError as exc:
        if type(exc) is ValueError:  # a setting the reader refused (a FormatError names the file)
            text = str(exc)  # the channel, the lead, or the track's values (the degrees)
            key = "audio_channel" if "channel" in text else "lead_ms" if "lead_s" in text else ""
            raise SourceError(key or "degrees", text) from None
        raise


def _lipsync(
    spec: Spec, path: Path, _spring: Spring | None, cache: FileCache | None, _notes: Notes
) -> Track:
    from hilsim.targets.formats.lipsync import ShapeTable, cue_track, read_cues

    fps = spec.get("fps")
    if fps is not None:
        fps = _number(spec, "fps")
        if not 1.0 <= fps <= MAX_FPS:
            raise SourceError("fps", f"must be 1 .. {MAX_FPS:g} frames per second, got {fps!r}")
    voice = spec.get("voice")
    if voice is not None and (isinstance(voice, bool) or not isinstance(voice, str | int)):
        raise SourceError("voice", f"must be a voice's name or index, got {voice!r}")
    names = spec.get("names", "auto")
    if not isinstance(names, str):
        raise SourceError("names", f"must be a vocabulary's name, got {names!r}")
    try:
        cues = _cached(
            cache,
            ("lipsync", path, fps, names, voice),
            lambda: read_cues(path, fps=fps, names=names, voice=voice),
        )
    except ValueError as exc:
        if type(exc) is ValueError:
            raise SourceError("fps" if "fps" in str(exc) else "names", str(exc)) from None
        raise
    for key in ("shapes", "preston_blair"):
        if key in spec and not isinstance(spec[key], Mapping):
            raise SourceError(key, f"must be a table of shape = value, got {spec[key]!r}")
    try:
        table = ShapeTable(
            rhubarb=dict(spec["shapes"]), preston_blair=dict(spec.get("preston_blair", {}))
        )
    except ValueError as exc:
        raise SourceError("shapes", str(exc)) from None
    return cue_track(cues, table, _unit(spec, (0.0, 1.0), "opening"))


def _midi(
    spec: Spec, path: Path, _spring: Spring | None, cache: FileCache | None, notes: Notes
) -> Track:
    """A controller or a note of a Standard MIDI File, in live MIDI's words."""
    from hilsim.targets.formats.midi_file import read_midi_file

    channel = spec["channel"]
    if isinstance(channel, bool) or not isinstance(channel, int) or not 1 <= channel <= 16:
        raise SourceError("channel", f"must be a MIDI channel 1-16, got {channel!r}")
    if ("control" in spec) == ("note" in spec):
        raise SourceError("control", "give control (a controller) or note, one of the two")
    key = "control" if "control" in spec else "note"
    fine = spec.get("fine", False)
    if not isinstance(fine, bool) or (fine and key == "note"):
        raise SourceError("fine", f"must be true or false, with control; got {fine!r}")
    top = 31 if fine else 127
    number = spec[key]
    if isinstance(number, bool) or not isinstance(number, int) or not 0 <= number <= top:
        pair = " (a 14-bit pair's MSB; its LSB is control + 32)" if fine else ""
        raise SourceError(key, f"must be 0-{top}{pair}, got {number!r}")
    degrees = _pair(spec, "degrees")
    if degrees[0] == degrees[1]:
        raise SourceError("degrees", f"the two angles are equal ({degrees[0]:g})")
    seq = _cached(cache, ("midi", path), lambda: read_midi_file(path))
    _note(notes, f"{path.name}: {seq.describe()}")
    if key == "note":
        if "interpolation" in spec:
            raise SourceError("interpolation", "a note is a step: it is always held")
        return seq.note_track(channel, number, degrees)
    try:
        return seq.cc_track(
            channel, number, degrees, fine=fine, interpolation=spec.get("interpolation", "hold")
        )
    except ValueError as exc:
        if type(exc) is ValueError:  # the interpolation (a FormatError names the file)
            raise SourceError("interpolation", str(exc)) from None
        raise


_BUILDERS: dict[str, Callable[[Spec, Path, Spring | None, FileCache | None, Notes], Track]] = {
    "bottango": _bottango,
    "blender_servo": _blender,
    "fseq": _fseq,
    "audio": _audio,
    "lipsync": _lipsync,
    "midi": _midi,
}
