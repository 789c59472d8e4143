"""A rig's named clips and the order the show plays them: ``[clips.<name>]`` and ``[[play]]``.

::

    [clips.idle]                       # a clip: a target table per joint it drives
    jaw = { type = "hold", value_deg = 10 }

    [clips.scare]
    jaw = { type = "bottango", file = "anims", effector = "0", degrees = [0, 40] }

    [[play]]                           # the show: each entry starts a clip at a show time
    at_s = 0
    clip = "idle"
    loop = true

    [[play]]
    at_s = 3.0
    clip = "scare"

Each clip plays from its own time 0; a joint a clip does not name follows its own ``target``.
The targets are checked when the show's parts are built (:func:`hilsim.show.parts.build_targets`),
like a joint's ``target``; here only the form: clip names, joint names, the entries' times.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from hilsim.rig.keys import rig_key
from hilsim.rig.model import JointConfig
from hilsim.rig.reader import Reader, finish, read_key

CLIP_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,63}")


@dataclass(frozen=True)
class PlayEntry:
    """One ``[[play]]`` table: start ``clip`` at show time ``at_s``."""

    at_s: float = rig_key(
        "number", "When the clip starts (show time).", unit="s", bounds={"nonnegative": True}
    )
    clip: str = rig_key("text", "The clip to start: a `[clips.<name>]` table's name.")
    loop: bool = rig_key(
        "bool",
        "Play the clip again from its start when it ends (until the next entry).",
        default=False,
        allowed="`true` | `false`",
    )


def read_clips(
    top: Reader, joints: tuple[JointConfig, ...]
) -> tuple[tuple[tuple[str, dict[str, Any]], ...], tuple[PlayEntry, ...]]:
    """``(clips, play)`` from the top level (``joints``: the rig's, for their names): clips as
    ``((name, {joint: target table}), ...)`` in file order, play entries in time order. Raises
    RigError naming the key."""
    joint_names = tuple(j.name for j in joints)
    raw = top.get("clips", dict, {})
    clips = []
    for name, table in raw.items():
        where = f"clips.{name}"
        if not CLIP_NAME_RE.fullmatch(name):
            raise top.fail(where, "a clip name is letters, digits and _ . + - (at most 64)")
        if not isinstance(table, dict) or not table:
            raise top.fail(where, f"must be a table of <joint> = <target table>, got {table!r}")
        for joint, target in table.items():
            if joint not in joint_names:
                raise top.fail(
                    f"{where}.{joint}", f"no such joint; the joints are {', '.join(joint_names)}"
                )
            if not isinstance(target, dict):
                raise top.fail(f"{where}.{joint}", f"must be a target table, got {target!r}")
        clips.append((name, dict(table)))
    entries = top.get("play", list, [])
    play: list[PlayEntry] = []
    for i, table in enumerate(entries):
        if not isinstance(table, dict):
            raise top.fail(f"play[{i}]", f"must be a table (at_s, clip, loop), got {table!r}")
        r = Reader(top.path, table, f"play[{i}]")
        entry = PlayEntry(
            at_s=read_key(r, PlayEntry, "at_s"),
            clip=read_key(r, PlayEntry, "clip"),
            loop=read_key(r, PlayEntry, "loop"),
        )
        finish(r, PlayEntry)
        if entry.clip not in raw:
            have = ", ".join(raw) or "none"
            raise r.fail("clip", f"no clip {entry.clip!r}; the clips are {have}")
        if play and not entry.at_s > play[-1].at_s:
            raise r.fail("at_s", f"must be after play[{i - 1}]'s {play[-1].at_s:g} s")
        if not math.isfinite(entry.at_s):
            raise r.fail("at_s", f"must be finite, got {entry.at_s!r}")
        play.append(entry)
    if raw and not play:
        raise top.fail("clips", "no [[play]] entry plays them: say when each clip starts")
    return tuple(clips), tuple(play)
