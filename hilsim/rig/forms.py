"""The tables inside a joint: the two spring forms, and the target specs' keys.

Spring keys are fields of :class:`AnimatorSpring` and :class:`PhysicsSpring`; the loader reads them
with their defaults and bounds from there and builds a :class:`hilsim.springs.Spring`. The target
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
        "sample (time in s, angles in degrees); linear between rows, held before and after.",
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
    "file": Key("text", "The CSV file, relative to the rig file.", allowed="an existing file"),
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
    "layers": Key(
        "list",
        "The target tables whose angles are added, each as a joint's `target` (layers may nest "
        "4 deep).",
        allowed="at least one table",
    ),
}
