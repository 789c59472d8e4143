"""Write ``docs/rig.md``, the rig-file reference, from the rig's definitions.

    python -m hilsim.rig.doc > docs/rig.md

Every key, its unit, default, what is allowed and an example come from the :class:`~hilsim.rig.
keys.Key` metadata on the fields of :mod:`hilsim.rig.model` and :mod:`hilsim.rig.forms`, and the
target keys from :data:`hilsim.targets.spec.SPEC_KEYS`: nothing here lists a key by hand.
``tests/hilsim/test_rig_doc.py`` fails when the committed file is stale.
"""

from __future__ import annotations

import json
import sys
from enum import StrEnum
from typing import Any

from hilsim.rig.bus import BusConfig
from hilsim.rig.clips import PlayEntry
from hilsim.rig.forms import TARGET_KEYS, TARGET_TYPES, AnimatorSpring, PhysicsSpring
from hilsim.rig.keys import REQUIRED, Key, allowed_text, default_value, key_fields, toml_name
from hilsim.rig.model import JointConfig, LoopConfig, Rig, SafetyConfig, TelemetryConfig
from hilsim.targets.spec import SPEC_KEYS
from hilsim.telemetry.format import JOINT_FIELDS

COMMAND = "python -m hilsim.rig.doc > docs/rig.md"

#: the sections of a rig file: (heading, TOML header, dataclass), in file order
SECTIONS: tuple[tuple[str, str, type], ...] = (
    ("Top level", "", Rig),
    ("[bus]", "[bus]", BusConfig),
    ("[loop]", "[loop]", LoopConfig),
    ("[safety]", "[safety]", SafetyConfig),
    ("[telemetry]", "[telemetry]", TelemetryConfig),
    ("[[joints]]", "[[joints]]", JointConfig),
)

#: unit of each telemetry.csv per-joint block (hilsim.telemetry.format.JOINT_FIELDS)
COLUMN_UNITS = {
    "target": "rad, the animation target",
    "sim_x": "rad, the spring's position",
    "sim_v": "rad/s, the spring's velocity",
    "cmd": "rad, the command after the safety filter",
    "present": "rad, read back from the servo (`nan`: no valid read)",
    "status": "no unit: the read status (0 OK, 1 STALE, 2 ERROR, 3 ALERT, 4 UNREAD: not asked "
    "this tick, on a bus that reads in rotation)",
}

INTRO = """\
# Rig file reference

A rig file is TOML: one file describes a figure's bus, loop, safety, telemetry and joints.
`hilsim run RIG.toml` loads it with `hilsim.rig.load_rig`, which refuses an unknown key, a wrong
type or a value out of bounds with one line naming the file and the key, e.g.

    configs/demo.toml: joints[2].max_deg: must be greater than min_deg (-30.0), got -40.0

`configs/demo.toml` is a commented example on the emulated bus, `configs/hardware_example.toml`
the same figure on real servos. Below, every key: *default* "required" means the key must be given;
*allowed* lists the choices or bounds the loader enforces.

## Angle units

* **Rig files are in degrees** (keys ending `_deg`, `_deg_s`, `_deg_s2`, and the angles of target
  keyframes and CSV animations). Everything inside hilsim is in radians.
* Joint angles are in the **joint frame**: servo angle = `home_deg + direction · joint angle`,
  where servo angle 0 is the centre tick (2048; 512 on AX and SCS servos, whose 1024 ticks span
  300 degrees).
* The run's telemetry (`telemetry.csv`; `.csv.gz` or Parquet for a big rig, see
  `telemetry.format`) holds, per joint `<j>`, in the joint frame:
"""


def _toml(value: Any) -> str:
    """A value as TOML writes it."""
    if isinstance(value, StrEnum):
        value = value.value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    raise TypeError(f"no TOML for {value!r}")


def _default(key: Key) -> str:
    if key.default_doc:
        return key.default_doc
    if key.default is REQUIRED:
        return "required"
    if key.default is None:
        return "none"
    return f"`{_toml(default_value(key))}`"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _table(rows: list[tuple[str, Key]]) -> list[str]:
    out = ["| key | unit | default | allowed | meaning |", "|---|---|---|---|---|"]
    for name, key in rows:
        cells = (f"`{name}`", key.unit, _default(key), allowed_text(key), key.doc)
        out.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return out


def example_value(key: Key) -> Any:
    """The value a key takes in the examples: its example, else its default; None: left out."""
    if key.example is not None:
        return key.example
    if key.default is REQUIRED or key.default is None:
        return None
    return default_value(key)


def example_lines(cls: type) -> list[str]:
    """``key = value`` for every key of ``cls`` that is not a table of its own."""
    lines = []
    for field_name, key in key_fields(cls):
        value = example_value(key)
        if value is not None and not (cls is Rig and key.kind in ("table", "list")):
            lines.append(f"{toml_name(field_name, key)} = {_toml(value)}")
    return lines


def example_rig() -> str:
    """A complete rig file made of every section's example (one joint)."""
    parts = []
    for _, header, cls in SECTIONS:
        parts.append("\n".join(([header] if header else []) + example_lines(cls)))
    return "\n\n".join(parts) + "\n"


def _rows(cls: type) -> list[tuple[str, Key]]:
    return [(toml_name(name, key), key) for name, key in key_fields(cls)]


def _springs() -> list[str]:
    out = [
        "## Springs",
        "",
        "`spring` is an inline table in one of two forms; giving terms of both is refused.",
        "",
    ]
    for title, cls in (("Animator form", AnimatorSpring), ("Physics form", PhysicsSpring)):
        doc = " ".join((cls.__doc__ or "").split()).replace("``", "`")
        out += [f"### {title}", "", doc, "", *_table(_rows(cls)), ""]
        example = {toml_name(n, k): example_value(k) for n, k in key_fields(cls)}
        out += ["```toml", f"spring = {_toml(example)}", "```", ""]
    return out


def _targets() -> list[str]:
    missing = sorted(
        {"type", *(k for r, o in SPEC_KEYS.values() for k in (*r, *o))} - set(TARGET_KEYS)
    )
    if missing or set(TARGET_TYPES) != set(SPEC_KEYS):
        raise SystemExit(
            f"hilsim.rig.forms does not describe target keys {missing} or types "
            f"{sorted(set(TARGET_TYPES) ^ set(SPEC_KEYS))}: add them to TARGET_KEYS/TARGET_TYPES"
        )
    out = [
        "## Targets",
        "",
        "`target` is an inline table; `type` picks the kind, the other keys are that type's "
        "(`hilsim.targets.spec.SPEC_KEYS`). Times are show time in s, angles in degrees, joint "
        "frame.",
        "",
    ]
    for kind, (required, optional) in SPEC_KEYS.items():
        meaning, example = TARGET_TYPES[kind]
        for k in (*required, *optional):
            if TARGET_KEYS[k].required != (k in required):
                raise SystemExit(f"TARGET_KEYS[{k!r}]: a default iff optional in SPEC_KEYS")
        rows = [(k, TARGET_KEYS[k]) for k in ("type", *required, *optional)]
        out += [f'### `type = "{kind}"`', "", meaning, "", *_table(rows), ""]
        out += ["```toml", f"target = {example}", "```", ""]
    return out


CLIPS_EXAMPLE = """\
[clips.idle]                 # a clip: a target table per joint it drives, from its own t = 0
jaw = { type = "hold", value_deg = 10 }

[clips.scare]
jaw = { type = "keyframes", keys = [[0, 30], [0.5, 35], [1.0, 5]] }

[[play]]                     # the show: each entry starts a clip; the next cuts to its own
at_s = 0
clip = "idle"
loop = true

[[play]]
at_s = 3.0
clip = "scare"
"""


def _clips() -> list[str]:
    return [
        "## Clips",
        "",
        "`[clips.<name>]` tables name clips: `<joint> = <target table>` for each joint the clip "
        "drives (any target type; times from the clip's own start). `[[play]]` tables, in time "
        "order, start them: each plays until the next, held at its end unless it loops. A joint "
        "the playing clip does not name follows its own `target`. A cut is a step in the target "
        "only: the spring and the safety filter take the joint there within its speed and "
        "acceleration limits.",
        "",
        *_table(_rows(PlayEntry)),
        "",
        "```toml",
        CLIPS_EXAMPLE.rstrip("\n"),
        "```",
        "",
    ]


def render() -> str:
    """The text of ``docs/rig.md``."""
    missing = set(JOINT_FIELDS) ^ set(COLUMN_UNITS)
    if missing:
        raise SystemExit(f"COLUMN_UNITS does not match telemetry JOINT_FIELDS: {sorted(missing)}")
    out = [f"<!-- generated by `{COMMAND}`; do not edit -->", "", INTRO.rstrip("\n")]
    out += [f"  * `{f}_<j>`: {COLUMN_UNITS[f]};" for f in JOINT_FIELDS]
    out[-1] = out[-1].rstrip(";") + "."
    out.append("")
    for heading, header, cls in SECTIONS:
        out += [f"## {heading}", "", *_table(_rows(cls)), ""]
        out += ["```toml", *([header] if header else []), *example_lines(cls), "```", ""]
    out += _springs()
    out += _targets()
    out += _clips()
    out += [
        "## A complete example",
        "",
        "Every section's example above, as one file (it loads as it is):",
        "",
        "```toml",
        example_rig().rstrip("\n"),
        "```",
    ]
    return "\n".join(out) + "\n"


def main() -> int:
    sys.stdout.write(render())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
