"""The tables inside a joint: the two spring forms, and the target specs' keys.

Spring keys are fields of :class:`AnimatorSpring` and :class:`PhysicsSpring`; the loader reads them
with their defaults and bounds from there and builds a
:class:`hilsim.dynamics.springs.Spring`. The target
keys are :data:`hilsim.targets.spec.SPEC_KEYS`, checked by :func:`~hilsim.targets.spec.
track_from_spec`; :data:`TARGET_KEYS` and :data:`TARGET_TYPES` only say what they mean, for
``docs/rig.md`` (whose generator refuses a key without an entry here).
"""

from __future__ import annotations

from dataclasses import dataclass

from hilsim.rig.keys import Key, number_text, rig_key
from hilsim.targets.tracks import EASINGS

#: spring sanity bounds (both forms): natural frequency, damping ratio, feed-forward
SPRING_HZ_RANGE = (0.01, 1e6)
MAX_DAMPING_RATIO = 1000.0
MAX_RESPONSE = 100.0
MAX_FEEDFORWARD = 100.0  # |b| <= MAX_FEEDFORWARD·(c + 2√(k·m))

WHY_HZ = "slower never moves in a show; faster is beyond any loop"
WHY_Z = "beyond it the joint creeps for minutes"
WHY_R = "the joint would react to the target's speed 100 times over"


@dataclass(frozen=True)
class AnimatorSpring:
    """The animators' form: ``spring = { frequency_hz = 2.5, damping_ratio = 0.75 }``."""

    frequency_hz: float = rig_key(
        "number",
        "Natural frequency f: how fast the joint follows its target.",
        unit="Hz",
        bounds={
            "positive": True,
            "at_least": SPRING_HZ_RANGE[0],
            "at_most": SPRING_HZ_RANGE[1],
            "why": WHY_HZ,
        },
        example=2.5,
    )
    damping_ratio: float = rig_key(
        "number",
        "Damping ratio ζ: 0 undamped (rings for ever), 1 critically damped, > 1 sluggish.",
        bounds={"nonnegative": True, "at_most": MAX_DAMPING_RATIO, "why": WHY_Z},
        example=0.75,
    )
    response: float = rig_key(
        "number",
        "Response r: 0 follows the target like a plain spring, 1 reacts to the target's velocity "
        "at once, > 1 overshoots the target's motion, < 0 anticipates it.",
        default=0.0,
        bounds={"at_least": -MAX_RESPONSE, "at_most": MAX_RESPONSE, "why": WHY_R},
        example=0.5,
    )


@dataclass(frozen=True)
class PhysicsSpring:
    """The physics form, ``m·x'' + c·x' + k·x = k·u + b·u'`` (x the joint, u the target, rad):
    ``spring = { m = 1.0, c = 0.8, k = 25.0 }``. The animator form's bounds apply to
    √(k/m)/2π and c/(2√(k·m))."""

    m: float = rig_key("number", "Mass (inertia) m.", bounds={"positive": True}, example=1.0)
    c: float = rig_key(
        "number",
        "Damping c.",
        bounds={"nonnegative": True},
        allowed=f"the damping ratio c/(2√(k·m)) <= {number_text(MAX_DAMPING_RATIO)}",
        example=0.8,
    )
    k: float = rig_key(
        "number",
        "Stiffness k.",
        bounds={"positive": True},
        allowed="the natural frequency √(k/m)/2π within "
        f"{number_text(SPRING_HZ_RANGE[0])} .. {number_text(SPRING_HZ_RANGE[1])} Hz",
        example=25.0,
    )
    b: float = rig_key(
        "number",
        "Velocity feed-forward b of the target.",
        default=0.0,
        allowed=f"|b| <= {number_text(MAX_FEEDFORWARD)}·(c + 2√(k·m))",
    )


#: the target types, what they are and an example, in SPEC_KEYS order
TARGET_TYPES: dict[str, tuple[str, str]] = {
    "keyframes": (
        "Keys `[time_s, deg]` joined by an easing per segment; held before the first key and "
        "after the last.",
        '{ type = "keyframes", keys = [[0, 0], [1, 30], [2.5, -10]], easing = "smooth" }',
    ),
    "csv": (
        "A column of a CSV animation: a header row `time_s,<joint>,...`, then one row per "
        "sample (time in s, angles in degrees); linear between rows (`interpolation = "
        '"hold"`: each row held until the next, as a take\'s `raw.csv` was live), held before '
        "and after.",
        '{ type = "csv", file = "demo_animation.csv" }',
    ),
    "sine": (
        "offset + amplitude · sin(2π · frequency · t + phase).",
        '{ type = "sine", amplitude_deg = 30, frequency_hz = 0.25 }',
    ),
    "step": (
        "`before_deg` until `at_s`, then `after_deg`.",
        '{ type = "step", at_s = 1.0, before_deg = 0, after_deg = 20 }',
    ),
    "hold": ("One angle, all show long.", '{ type = "hold", value_deg = 0 }'),
    "layers": (
        "Several targets on one joint, added (e.g. a jaw from audio plus a keyframed offset); "
        "ends when its last finite layer ends.",
        '{ type = "layers", layers = [{ type = "sine", amplitude_deg = 5, frequency_hz = 1 }, '
        '{ type = "keyframes", keys = [[0, 0], [2, 20]] }] }',
    ),
    "bottango": (
        "One effector's curves in one animation of a Bottango export (generated code "
        "`GeneratedCodeAnimations.cpp`, an SD card's folder holding `anims/`, or JSON), "
        "as Bottango's driver plays them: the exact Bézier curves, the last value held after "
        "the last. With a registration (`rSVPin`, `rSVI2C`, `rMTR`, `rSTPin`/`rSTDir`, "
        "`rECC`) the effector sits at its registered start signal until its first curve (the "
        "driver parks it there), and the target is the driver's signal (Bottango's Arduino "
        "driver 0.8.0c1, `LoopDrivenEffector`): moved toward the curves at most at the "
        "registered speed limit (`maxPWMPerSec` and kin, per second), "
        "so where a curve or a jump (the first curve starting away from the start signal, an "
        "instant move) is faster it runs behind in a straight line at the limit until it meets "
        "the curve; one note says where. The rig's spring, speed limits and safety filter "
        "then act on that target. An effector with no registration (it needs `movement`) "
        "follows the bare curves, the first one's start held before it.",
        '{ type = "bottango", file = "GeneratedCodeAnimations.cpp", effector = "0", '
        "degrees = [0, 40] }",
    ),
    "blender_servo": (
        "One servo of a blender-servo-animation export (`.json`, `.bin`, `.h`): a position "
        "per frame, held (as the add-on's Arduino library plays it) or joined; a servo "
        "missing from a frame holds its last position. A `.bin`/`.h` record whose ID or "
        "position byte is 0x0A or 0x3C is read as written; the add-on's Arduino library "
        "(2.0.0) takes those bytes for a frame end or a record start wherever they stand and "
        "drops the record (a 0x0A also delays every later frame by one): one note says so, "
        "naming the first such servo and frame.",
        '{ type = "blender_servo", file = "wave.json", servo = 0, position = [544, 2400], '
        "degrees = [-90, 90] }",
    ),
    "fseq": (
        "A channel (8-bit) or coarse/fine pair (16-bit) of an xLights/FPP `.fseq` sequence "
        "(v2: plain, zstd or zlib, sparse ranges; v1), frames held.",
        '{ type = "fseq", file = "show.fseq", channel = 1, fine = 2, degrees = [-90, 90] }',
    ),
    "audio": (
        "A jaw from a sound file: RMS envelope, attack and release, threshold and full-open "
        'level; `lead_ms = "auto"` leads it by the joint\'s spring lag so the commanded jaw '
        "is in time with the sound.",
        '{ type = "audio", file = "line.wav", degrees = [0, 20], lead_ms = "auto" }',
    ),
    "lipsync": (
        "Mouth-shape cues (Rhubarb TSV/JSON/XML, Moho `.dat`, Papagayo `.pgo`) through a "
        "table of openings 0..1 per shape, held from cue to cue.",
        '{ type = "lipsync", file = "line.tsv", degrees = [0, 20], shapes = { X = 0, A = 0, '
        "B = 0.2, C = 0.5, D = 1, E = 0.6, F = 0.3, G = 0.1, H = 0.4 } }",
    ),
    "midi": (
        "A controller or a note of a Standard MIDI File (`.mid`, format 0 or 1), in live "
        "MIDI's words: value 0 -> `degrees[0]`, 127 -> `degrees[1]`; a note is `degrees[1]` "
        "from note-on to note-off. Ticks become seconds through the file's tempo map (every "
        "Set Tempo, 120 bpm before the first) or its SMPTE rate; the value is held until the "
        "next (or joined), and the last until the file's end.",
        '{ type = "midi", file = "show.mid", channel = 1, control = 7, degrees = [-30, 30] }',
    ),
}

#: what each target key means (the same key means the same in every type that has it)
TARGET_KEYS: dict[str, Key] = {
    "type": Key("text", "The target's type.", allowed=" | ".join(f'`"{t}"`' for t in TARGET_TYPES)),
    "keys": Key(
        "list",
        "The keyframes, `[time_s, deg]` pairs, times strictly increasing.",
        unit="s, deg",
        allowed="at least one pair",
    ),
    "easing": Key(
        "text",
        "One easing for every segment, or a list of one per segment.",
        default="linear",
        allowed=" | ".join(f'`"{e}"`' for e in EASINGS),
    ),
    "file": Key(
        "text",
        "The animation file (CSV, or another tool's), relative to the rig file.",
        allowed="an existing file (a Bottango SD card: its folder)",
    ),
    "column": Key(
        "text", "The CSV column to follow.", default_doc="the joint's name", allowed="a column"
    ),
    "amplitude_deg": Key("number", "Amplitude.", unit="deg"),
    "frequency_hz": Key("number", "Frequency.", unit="Hz", allowed=">= 0"),
    "phase_deg": Key("number", "Phase at t = 0.", unit="deg", default=0.0),
    "offset_deg": Key("number", "Centre of the swing.", unit="deg", default=0.0),
    "at_s": Key("number", "When the step happens (show time).", unit="s"),
    "before_deg": Key("number", "The angle before the step.", unit="deg"),
    "after_deg": Key("number", "The angle from the step on.", unit="deg"),
    "value_deg": Key("number", "The angle held.", unit="deg"),
    "degrees": Key(
        "list",
        "The joint angles the file's two reference values map to, linearly: the signal range's "
        "ends (bottango), the two `position`s (blender_servo), the two DMX `values` (fseq), a "
        "shut and a wide-open jaw (audio, lipsync: opening 0 and 1), MIDI value 0 and 127 "
        "(16383 with `fine`) or a note off and on (midi).",
        unit="deg",
        allowed="two finite numbers",
    ),
    "effector": Key(
        "text",
        "The Bottango effector: its pin, I²C address and pin written together (`643`), or "
        "motor identifier, as the export's registrations name it.",
    ),
    "animation": Key("text", "The Bottango animation: its index or name.", default=0),
    "signal": Key(
        "list",
        "Two signal values (e.g. µs) that `degrees` maps to.",
        default_doc="the effector's registered range",
        allowed="two finite, different numbers",
    ),
    "movement": Key(
        "list",
        "Two Bottango movements (0..1) that `degrees` maps to, instead of `signal` (an "
        "effector with no registered range needs it).",
        default_doc="none: the signal is mapped",
        allowed="two finite, different numbers",
    ),
    "servo": Key("integer", "The servo ID in the blender-servo-animation export."),
    "position": Key(
        "list",
        "Two positions in the export's unit that `degrees` maps to. The add-on's bone settings "
        "give them: position_min and position_max are servo angles 0 and rotation_range (the "
        "bone's rotation is neutral_angle minus the servo angle).",
        unit="µs, PCA9685 ticks or degrees, as the bone's output range was set",
        allowed="two finite, different numbers",
    ),
    "interpolation": Key(
        "text",
        "Frames (midi: controller values) held until the next, or joined linearly (a csv "
        "file: linear unless it says hold).",
        default="hold",
        allowed='`"hold"` | `"linear"`',
    ),
    "fps": Key(
        "number",
        "Frames per second where the file does not say (blender_servo `.bin`, Moho `.dat`).",
        unit="1/s",
        default_doc="the file's (required where it has none)",
    ),
    "channel": Key(
        "integer",
        "fseq: the channel, 1-based as xLights shows it (16-bit: the coarse one). Absolute in "
        "a sparse file too: the channel's number in the show, not its place among the "
        "channels the file stores (a file holding only 501-548 has channel 501, not 1). "
        "midi: the MIDI channel, 1-16 as a user sees it.",
    ),
    "fine": Key(
        "integer",
        "fseq: the fine channel of a 16-bit pair (1-based, absolute as `channel`). midi: "
        "`true` makes `control` (0-31) the MSB of a 14-bit pair whose LSB is `control` + 32 "
        "(0 -> `degrees[0]`, 16383 -> `degrees[1]`), as live MIDI's `fine`.",
        default_doc="none: an 8-bit channel (midi: false, 7-bit)",
    ),
    "control": Key(
        "integer",
        "midi: the controller number (e.g. 7, volume); give it or `note`.",
        default_doc="none: give `note`",
        allowed="0-127 (0-31 with `fine`)",
    ),
    "note": Key(
        "integer",
        "midi: the note number (60 = middle C); the joint is at `degrees[1]` while it "
        "sounds, `degrees[0]` else; always held.",
        default_doc="none: give `control`",
        allowed="0-127",
    ),
    "audio_channel": Key(
        "text",
        'audio: which channel of the file drives the jaw: `"mix"`, `"left"`, `"right"` or its '
        "index (e.g. the right channel of a tone track).",
        default="mix",
    ),
    "values": Key(
        "list",
        "fseq: two channel values that `degrees` maps to.",
        default_doc="the full range, 0-255 (8-bit) or 0-65535 (16-bit)",
    ),
    "zero": Key(
        "text",
        'fseq: `"hold"` makes a 0 hold the last position (xLights\' servo option).',
        default="value",
        allowed='`"value"` | `"hold"`',
    ),
    "window_ms": Key("number", "audio: the RMS window.", unit="ms", default=10.0),
    "attack_ms": Key(
        "number", "audio: the envelope's rise time constant.", unit="ms", default=10.0
    ),
    "release_ms": Key(
        "number", "audio: the envelope's fall time constant.", unit="ms", default=100.0
    ),
    "threshold": Key(
        "number", "audio: the RMS (1 = full scale) below which the jaw is shut.", default=0.02
    ),
    "full": Key("number", "audio: the RMS at which the jaw is wide open.", default=0.35),
    "band_hz": Key(
        "list",
        "audio: a band-pass [low, high] before the envelope.",
        unit="Hz",
        default_doc="none: the whole band",
    ),
    "lead_ms": Key(
        "number",
        'audio: how much earlier the jaw moves than the sound; `"auto"` = the joint\'s '
        "spring lag (c − b)/k, so the commanded jaw is in time.",
        unit="ms",
        default=0.0,
    ),
    "shapes": Key(
        "table",
        "lipsync: the opening (0 shut .. 1 wide) per Rhubarb mouth shape A-H, X.",
    ),
    "preston_blair": Key(
        "table",
        "lipsync: openings (or Rhubarb letters) per Preston Blair phoneme, for Papagayo and "
        "Blair-named Moho files.",
        default_doc="Rhubarb's own correspondence (MBP->A, etc->B, E->C, AI->D, O->E, U->F, "
        "FV->G, L->H, rest->X)",
    ),
    "voice": Key(
        "text", "lipsync: the Papagayo voice (name or index).", default_doc="the only voice"
    ),
    "names": Key(
        "text",
        "lipsync: a Moho file's vocabulary when it cannot be told.",
        default="auto",
        allowed='`"auto"` | `"rhubarb"` | `"preston_blair"`',
    ),
    "layers": Key(
        "list",
        "The target tables whose angles are added, each as a joint's `target` (layers may nest "
        "4 deep).",
        allowed="at least one table",
    ),
}
