"""The show file: what ``hilsim run RIG --show SHOW.toml`` runs besides the rig's own targets.

A show file names the clips a figure plays, what starts them, and the live inputs that may
drive it. The rig (its servos, limits and springs) stays in the rig file. Every section is
optional; paths are relative to the show file. Sections: ``[show]``, ``[clips.*]``,
``[sounds]``, ``[idle]``, ``[cues.*]``, ``[[timeline]]``, ``[inputs.osc]``, ``[inputs.midi]``,
``[inputs.mtc]``, ``[inputs.ltc]``, ``[inputs.sacn]``, ``[inputs.artnet]``, ``[inputs.multisync]``,
``[inputs.gamepad]``, ``[inputs.keyboard]``, ``[inputs.bottango]``, ``[record]`` and
``[teach]``. ``--live`` has a built-in one.

Clips, sounds, idle, cues and the timeline are read by :mod:`hilsim.live.show_spec`. The
Bottango, gamepad, keyboard and teach sections are read by their own modules. Errors are one
line naming the file and the key (:class:`~hilsim.rig.RigError`).

Every section with an example: ``docs/live.md`` (the show file, live inputs).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hilsim.live.inbox import MAX_LIVE_DEG
from hilsim.live.midi import CcMapping
from hilsim.live.netguard import GuardConfig, read_guard
from hilsim.rig import Rig, RigError
from hilsim.rig.reader import Reader

if TYPE_CHECKING:  # each section's reader is imported when a show file has that section
    from hilsim.live.bottango_config import BottangoConfig
    from hilsim.live.dmx_config import DmxConfig
    from hilsim.live.gamepad import GamepadConfig
    from hilsim.live.keyboard import KeyboardConfig
    from hilsim.live.ltc_chase import LtcConfig
    from hilsim.live.multisync import MultiSyncConfig
    from hilsim.live.show_spec import MakeTrack, RuntimeSpec
    from hilsim.live.teach import TeachConfig

#: the default OSC port of ``hilsim run --live``
DEFAULT_OSC_PORT = 9000
TOP_KEYS = ("show", "clips", "sounds", "idle", "cues", "timeline", "inputs", "record", "teach")
INPUT_KEYS = ("osc", "midi", "mtc", "ltc", "sacn", "artnet", "multisync", "bottango", "gamepad",
              "keyboard")  # fmt: skip


@dataclass(frozen=True)
class OscConfig:
    port: int = DEFAULT_OSC_PORT
    guard: GuardConfig = field(default_factory=GuardConfig)
    #: no value for a joint this long: it holds, one input_lost event (a fader app sends only
    #: when it moves, so this is "the sender went away", not "the hand is still")
    lost_after_s: float = 2.0
    #: no fresh value for a joint this long: it is handed back to the show (None: held until
    #: released, so a performer holding a fader still keeps the joint)
    release_after_s: float | None = None
    max_rx_per_s: float = 2000.0
    #: joint -> (degrees at 0, degrees at 1); default: every joint over its limits
    joints: dict[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class MidiConfig:
    port: str | None = None
    lost_after_s: float | None = None
    release_after_s: float | None = None
    cc: tuple[CcMapping, ...] = ()


@dataclass(frozen=True)
class MtcConfig:
    freewheel_s: float = 0.5
    offset_s: float = 0.0
    jump_s: float = 0.1


@dataclass(frozen=True)
class RecordConfig:
    #: the joints recorded (None: every joint a live input drives)
    joints: tuple[str, ...] | None = None
    tolerance_deg: float = 0.5


@dataclass
class ShowSpec:
    """A loaded show file (or the built-in one of ``--live``)."""

    path: Path | None
    name: str
    seed: int = 0
    runtime: RuntimeSpec | None = None  # None: no clips or cues
    osc: OscConfig | None = None
    midi: MidiConfig | None = None
    mtc: MtcConfig | None = None
    ltc: LtcConfig | None = None
    sacn: DmxConfig | None = None
    artnet: DmxConfig | None = None
    multisync: MultiSyncConfig | None = None
    bottango: BottangoConfig | None = None
    gamepad: GamepadConfig | None = None
    keyboard: KeyboardConfig | None = None
    record: RecordConfig | None = None
    teach: TeachConfig | None = None
    notes: list[str] = field(default_factory=list)


def live_spec(rig: Rig, port: int = DEFAULT_OSC_PORT) -> ShowSpec:
    """``hilsim run --live`` without a show file: OSC on 127.0.0.1 for every joint over its
    limits, and keys typed in the terminal as triggers (no cues: they only show up)."""
    return ShowSpec(
        path=None,
        name=f"{rig.name} live",
        osc=OscConfig(port=port, joints=joint_ranges(rig)),
        record=RecordConfig(),
    )


def joint_ranges(rig: Rig) -> dict[str, tuple[float, float]]:
    """Each joint's limits in degrees: what OSC's 0..1 spans unless the show says otherwise."""
    return {j.name: (math.degrees(j.min_rad), math.degrees(j.max_rad)) for j in rig.joints}


def load_show(path: str | Path, rig: Rig, make_track: MakeTrack) -> ShowSpec:
    """Read and check a show file against ``rig`` (its joints). ``make_track(spec, joint,
    where)`` builds one clip track. Raises RigError (one line)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError(f"{path}: no such show file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RigError(f"{path}: cannot read the show file: {exc}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"{path}: not valid TOML: {exc}") from None
    top = Reader(path, doc, "")
    show = top.sub("show")
    spec = ShowSpec(
        path=path,
        name=show.get("name", str, path.stem),
        seed=show.integer("seed", 0, lo=0, hi=2**63 - 1),
    )
    show.finish(("name", "seed"))
    names = rig.joint_names
    where = f"{path.name}"
    try:
        if any(k in doc for k in ("clips", "idle", "cues", "timeline", "sounds")):
            from hilsim.live.show_spec import read_runtime

            spec.runtime = read_runtime(doc, where, path.parent, names, make_track)
        for key in ("clips", "sounds", "idle", "cues", "timeline"):
            top.used.add(key)
        inputs = top.sub("inputs")
        if "osc" in inputs.table:
            spec.osc = _osc(inputs.sub("osc"), rig)
        if "midi" in inputs.table:
            spec.midi = _midi(inputs.sub("midi"), names)
        if "mtc" in inputs.table:
            spec.mtc = _mtc(inputs.sub("mtc"))
        if "ltc" in inputs.table:
            from hilsim.live.ltc_chase import read_ltc

            spec.ltc = read_ltc(inputs.sub("ltc"), path.parent)
            if spec.mtc is not None:
                raise inputs.fail("ltc", "inputs.mtc sets the show time too: keep one")
        _network_inputs(inputs, spec, rig)
        if "bottango" in inputs.table:
            from hilsim.live.bottango_live import from_table as bottango_table

            spec.bottango = bottango_table(
                inputs.get("bottango", dict), f"{where}: inputs.bottango", names
            )
        if "gamepad" in inputs.table:
            from hilsim.live.gamepad import GamepadConfig

            spec.gamepad = GamepadConfig.from_table(
                inputs.get("gamepad", dict), f"{where}: inputs.gamepad", names
            )
        if "keyboard" in inputs.table:
            from hilsim.live.keyboard import KeyboardConfig

            spec.keyboard = KeyboardConfig.from_table(
                inputs.get("keyboard", dict), f"{where}: inputs.keyboard"
            )
        inputs.finish(INPUT_KEYS)
        if "record" in doc:
            spec.record = _record(top.sub("record"), names)
        if "teach" in doc:
            from hilsim.live.teach import TeachConfig

            spec.teach = TeachConfig.from_table(top.get("teach", dict), f"{where}: teach", names)
        top.finish(TOP_KEYS)
    except RigError:
        raise
    except ValueError as exc:  # the section readers say "<where>.<key>: what is wrong"
        msg = str(exc)
        raise RigError(msg if msg.startswith(where) else f"{path}: {msg}") from None
    if spec.mtc is not None and spec.midi is None:
        spec.midi = MidiConfig()  # timecode comes in on a MIDI port
    return spec


def _network_inputs(inputs: Reader, spec: ShowSpec, rig: Rig) -> None:
    """``[inputs.sacn]``, ``[inputs.artnet]`` and ``[inputs.multisync]`` (after ``mtc``)."""
    for proto in ("sacn", "artnet"):
        if proto in inputs.table:
            from hilsim.live.dmx_config import read_dmx

            setattr(spec, proto, read_dmx(inputs.sub(proto), proto, joint_ranges(rig)))
    if "multisync" in inputs.table:
        from hilsim.live.multisync import read_multisync

        spec.multisync = read_multisync(inputs.sub("multisync"))
        if spec.mtc is not None or spec.ltc is not None:
            other = "mtc" if spec.mtc is not None else "ltc"
            raise inputs.fail("multisync", f"inputs.{other} sets the show time too: keep one")


def _osc(r: Reader, rig: Rig) -> OscConfig:
    port = r.integer("port", DEFAULT_OSC_PORT, lo=1, hi=65535)
    guard = read_guard(r, 1024)
    ranges = joint_ranges(rig)
    table = r.get("joints", dict, {})
    joints: dict[str, tuple[float, float]] = {}
    for name, rng in table.items():
        if name not in ranges:
            raise r.fail(f"joints.{name}", f"no such joint (joints: {', '.join(ranges)})")
        joints[name] = _pair(r, f"joints.{name}", rng)
    out = OscConfig(
        port=port,
        guard=guard,
        lost_after_s=r.number("lost_after_s", 2.0, positive=True),
        release_after_s=_release_after(r),
        max_rx_per_s=r.number("max_rx_per_s", 2000.0, positive=True, at_most=1e6),
        joints=joints or ranges,
    )
    r.finish()
    return out


def _pair(r: Reader, key: str, value: Any) -> tuple[float, float]:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        and all(math.isfinite(v) and abs(v) <= MAX_LIVE_DEG for v in value)
        and value[0] != value[1]
    )
    if not ok:
        raise r.fail(
            key,
            f"expected [degrees at 0, degrees at 1], two different numbers within "
            f"±{MAX_LIVE_DEG:g}, got {value!r}",
        )
    return float(value[0]), float(value[1])


def _midi(r: Reader, names: tuple[str, ...]) -> MidiConfig:
    port = r.get("port", str, None)
    lost = r.number("lost_after_s", None, positive=True)
    release = _release_after(r)
    maps = []
    entries = r.get("cc", list, [])
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise r.fail(f"cc[{i}]", f"expected a table, got {entry!r}")
        e = Reader(r.path, entry, r.key(f"cc[{i}]"))
        joint = e.get("joint", str)
        if joint not in names:
            raise e.fail("joint", f"no such joint {joint!r} (joints: {', '.join(names)})")
        lo, hi = _pair(e, "degrees", e.get("degrees", list))
        try:
            maps.append(
                CcMapping(
                    joint,
                    e.integer("channel", 1, lo=1, hi=16),
                    e.integer("control", ..., lo=0, hi=127),
                    lo,
                    hi,
                    fine=e.get("fine", bool, False),
                )
            )
        except ValueError as exc:
            if isinstance(exc, RigError):
                raise
            raise RigError(f"{r.path}: {e.where}: {exc}") from None
        e.finish()
    r.finish()
    try:
        from hilsim.live.midi import MidiCcInput

        MidiCcInput(maps, lost_after_s=lost)  # the mappings' own checks (a joint twice ...)
    except ValueError as exc:
        raise RigError(f"{r.path}: {r.where}: {exc}") from None
    return MidiConfig(port=port, lost_after_s=lost, release_after_s=release, cc=tuple(maps))


def _release_after(r: Reader) -> float | None:
    """``release_after_s``: a live value not refreshed this long hands its joint back."""
    return r.number("release_after_s", None, positive=True, at_most=7 * 86400.0)


def _mtc(r: Reader) -> MtcConfig:
    out = MtcConfig(
        freewheel_s=r.number("freewheel_s", 0.5, nonnegative=True, at_most=3600),
        offset_s=r.number(
            "offset_s", 0.0, at_least=-86400.0, at_most=86400.0, why="a timecode is within a day"
        ),
        jump_s=r.number("jump_s", 0.1, positive=True, at_most=3600),
    )
    r.finish()
    return out


def _record(r: Reader, names: tuple[str, ...]) -> RecordConfig:
    joints = r.get("joints", list, None)
    if joints is not None:
        for j in joints:
            if j not in names:
                raise r.fail("joints", f"no such joint {j!r} (joints: {', '.join(names)})")
    out = RecordConfig(
        joints=None if joints is None else tuple(joints),
        tolerance_deg=r.number("tolerance_deg", 0.5, positive=True, at_most=90),
    )
    r.finish()
    return out
