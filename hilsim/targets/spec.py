"""Rig-file target specs (angles in degrees) turned into tracks: :func:`track_from_spec`.

This module sits above :mod:`hilsim.targets.tracks`, :mod:`hilsim.targets.csv_file` and
:mod:`hilsim.targets.sources` (other tools' files) and imports them; none imports it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hilsim.dynamics.springs import Spring
from hilsim.targets.csv_file import CsvAnimation, CsvCurve
from hilsim.targets.sources import (
    SOURCE_KEYS,
    FileCache,
    SourceError,
    rig_file,
    track_from_source,
)
from hilsim.targets.tracks import (
    MAX_TRACK_DEG,
    MAX_TRACK_TURNS,
    Hold,
    Keyframes,
    Layered,
    Sine,
    Step,
    Track,
    easing_names,
)


class SpecError(ValueError):
    """A target spec that cannot be used. ``key`` is the offending key inside the spec (e.g.
    ``"easing"`` or ``"keys[2]"``); the message is ``"<key>: <what is wrong and what is allowed>"``
    so a rig loader can prefix its file name and the spec's own key path."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key, self.detail = key, message


#: per target type: (required keys, optional keys), besides "type"
SPEC_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "keyframes": (("keys",), ("easing",)),
    "csv": (("file",), ("column", "interpolation")),
    "sine": (("amplitude_deg", "frequency_hz"), ("phase_deg", "offset_deg")),
    "step": (("at_s", "before_deg", "after_deg"), ()),
    "hold": (("value_deg",), ()),
    "layers": (("layers",), ()),
    **SOURCE_KEYS,
}
#: how deep layers may nest (a layer that is itself layers): beyond it, a mistake
MAX_LAYER_DEPTH = 4


def _spec_number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(key, f"must be a number, got {value!r}")
    if not math.isfinite(value):
        raise SpecError(key, f"must be finite, got {value!r}")
    if key.endswith("_deg") and key != "phase_deg" and abs(value) > MAX_TRACK_DEG:
        raise SpecError(  # a position (a phase may be any angle)
            key, f"must be within ±{MAX_TRACK_DEG}° ({MAX_TRACK_TURNS} turns), got {value!r}"
        )
    return float(value)


def track_from_spec(
    spec: Mapping[str, Any],
    *,
    base_dir: str | Path = ".",
    joint_name: str,
    csv_cache: FileCache | None = None,
    spring: Spring | None = None,
    notes: list[str] | None = None,
    _depth: int = 0,
) -> Track:
    """Build a track from a rig file's target table (angles in degrees, times in seconds).

    Specs, one per type (keys marked ? are optional)::

        {type = "keyframes", keys = [[t_s, deg], ...], easing? = "linear" | [name per segment]}
        {type = "csv", file = "anim.csv", column? = <joint_name>, interpolation? = "linear"}
        {type = "sine", amplitude_deg, frequency_hz, phase_deg? = 0, offset_deg? = 0}
        {type = "step", at_s, before_deg, after_deg}
        {type = "hold", value_deg}
        {type = "layers", layers = [<spec>, <spec>, ...]}              the specs' targets added
        {type = "bottango" | "blender_servo" | "fseq" | "audio" | "lipsync" | "midi", file, ...}
                                                    another tool's file (hilsim.targets.sources)

    Args:
        spec: the table, e.g. parsed TOML.
        base_dir: directory that CSV file names are relative to (the rig file's directory).
        joint_name: the joint this track drives; the default CSV column.
        csv_cache: a dict shared across calls so each file (CSV or another tool's) is read
            once (keyed by the resolved path, with the reader's options).
        spring: the joint's spring (an audio target's ``lead_ms = "auto"`` is its lag).
        notes: a list that gathers what another tool's file says the user should read.

    Raises:
        SpecError: unknown type or key, a missing key, a wrong value; names the key, lists what is
            allowed.
        CsvFormatError: a CSV file that cannot be used (``file:line: ...``).
        FormatError: another tool's file that cannot be used (``file:where: ...``).
    """
    kind = spec.get("type")
    if kind not in SPEC_KEYS:
        got = "missing" if kind is None else f"unknown target type {kind!r}"
        raise SpecError("type", f"{got}; allowed: {', '.join(sorted(SPEC_KEYS))}")
    required, optional = SPEC_KEYS[kind]
    allowed = ("type", *required, *optional)
    for key in spec:
        if key not in allowed:
            raise SpecError(
                str(key), f"unknown key for a {kind!r} target; allowed: {', '.join(allowed)}"
            )
    for key in required:
        if key not in spec:
            raise SpecError(key, f"missing; a {kind!r} target needs {', '.join(required)}")
    deg = math.radians
    if kind == "hold":
        return Hold(deg(_spec_number("value_deg", spec["value_deg"])))
    if kind == "step":
        at, before, after = (_spec_number(k, spec[k]) for k in required)
        return Step(at, deg(before), deg(after))
    if kind == "sine":
        freq = _spec_number("frequency_hz", spec["frequency_hz"])
        if freq < 0.0:
            raise SpecError("frequency_hz", f"must be >= 0, got {freq!r}")
        return Sine(
            deg(_spec_number("amplitude_deg", spec["amplitude_deg"])),
            freq,
            deg(_spec_number("phase_deg", spec.get("phase_deg", 0.0))),
            deg(_spec_number("offset_deg", spec.get("offset_deg", 0.0))),
        )
    if kind == "keyframes":
        return _keyframes_from_spec(spec)
    if kind == "layers":
        return _layers_from_spec(spec, base_dir, joint_name, csv_cache, spring, notes, _depth)
    if kind in SOURCE_KEYS:
        try:
            return track_from_source(
                kind, spec, base_dir=Path(base_dir), spring=spring, cache=csv_cache, notes=notes
            )
        except SourceError as exc:
            raise SpecError(exc.key, exc.detail) from None
    return _csv_from_spec(spec, Path(base_dir), joint_name, csv_cache)


def _layers_from_spec(
    spec: Mapping[str, Any],
    base_dir: str | Path,
    joint_name: str,
    csv_cache: FileCache | None,
    spring: Spring | None,
    notes: list[str] | None,
    depth: int,
) -> Layered:
    layers = spec["layers"]
    if not isinstance(layers, list | tuple) or not layers:
        raise SpecError("layers", f"must be a non-empty list of target tables, got {layers!r}")
    if depth >= MAX_LAYER_DEPTH:
        raise SpecError("layers", f"nested more than {MAX_LAYER_DEPTH} deep")
    tracks = []
    for i, layer in enumerate(layers):
        if not isinstance(layer, Mapping):
            raise SpecError(f"layers[{i}]", f"must be a target table, got {layer!r}")
        try:
            tracks.append(
                track_from_spec(
                    layer,
                    base_dir=base_dir,
                    joint_name=joint_name,
                    csv_cache=csv_cache,
                    spring=spring,
                    notes=notes,
                    _depth=depth + 1,
                )
            )
        except SpecError as exc:
            raise SpecError(f"layers[{i}].{exc.key}", exc.detail) from None
    return Layered(tuple(tracks))


def _keyframes_from_spec(spec: Mapping[str, Any]) -> Keyframes:
    keys = spec["keys"]
    if not isinstance(keys, list | tuple) or not keys:
        raise SpecError("keys", f"must be a non-empty list of [time_s, deg] pairs, got {keys!r}")
    times, values = [], []
    for i, key in enumerate(keys):
        if not isinstance(key, list | tuple) or len(key) != 2:
            raise SpecError(f"keys[{i}]", f"must be a [time_s, deg] pair, got {key!r}")
        times.append(_spec_number(f"keys[{i}][0]", key[0]))
        values.append(math.radians(_spec_number(f"keys[{i}][1]", key[1])))
    easing = spec.get("easing", "linear")
    if not isinstance(easing, str) and not (
        isinstance(easing, list | tuple) and all(isinstance(e, str) for e in easing)
    ):
        raise SpecError("easing", f"must be a name or a list of names, got {easing!r}")
    try:
        names = easing_names(easing, len(keys) - 1)
    except ValueError as exc:
        raise SpecError("easing", str(exc).removeprefix("easing: ")) from None
    try:
        return Keyframes(times, values, names)
    except ValueError as exc:
        raise SpecError("keys", str(exc)) from None


def _csv_from_spec(
    spec: Mapping[str, Any],
    base_dir: Path,
    joint_name: str,
    cache: FileCache | None,
) -> CsvCurve:
    file, column = spec["file"], spec.get("column", joint_name)
    if not isinstance(file, str) or not file:
        raise SpecError("file", f"must be a file name, got {file!r}")
    if not isinstance(column, str) or not column:
        raise SpecError("column", f"must be a column name, got {column!r}")
    path = rig_file(base_dir, file)
    anim: CsvAnimation | None = cache.get(path) if cache is not None else None
    if anim is None:
        if not path.is_file():
            raise SpecError("file", f"no such file: {path}")
        anim = CsvAnimation.load(path)
        if cache is not None:
            cache[path] = anim
    if column not in anim.columns:
        how = "" if "column" in spec else " (the column defaults to the joint name)"
        raise SpecError(
            "column",
            f"{path}:1: no column {column!r}{how}; the joint columns are {', '.join(anim.names)}",
        )
    how = spec.get("interpolation", "linear")
    if how not in ("linear", "hold"):
        raise SpecError("interpolation", f'must be "linear" or "hold", got {how!r}')
    return anim.curve(column, how)
