"""``hilsim tracks RIG``: what a rig will ask of each joint, before anything moves.

``--at T1,T2,... [--json]`` prints every joint's target (degrees, before the spring) at those
show times: as JSON ``{"joint": [values...]}`` with ``--json``, else one line per joint.
Without ``--at`` it runs the show's targets, springs and safety filter offline
(:mod:`hilsim.show.preview`), writes a preview plot (target, spring, command, limits, and
where the safety filter changes the command) and prints a warning per joint and limit the
targets break (:mod:`hilsim.targets.check`). A rig with several ``[buses.<name>]`` shows every
bus's joints, bus by bus, as ``hilsim run`` runs the whole figure; ``--bus NAME`` shows one.
Nothing opens a port. Exit codes: 0 done (warnings or not), 2 the rig or an option cannot be
used (one line on stderr).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hilsim.exit_codes import ExitCode

if TYPE_CHECKING:
    from hilsim.rig import Rig
    from hilsim.show.parts import Parts

HELP = (
    "show what a rig's animation asks of each joint (targets at times as JSON, or a preview plot)"
)
#: preview length when the animation never ends and no --duration is given (s)
ENDLESS_PREVIEW_S = 20.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", metavar="RIG", help="rig file (TOML)")
    parser.add_argument(
        "--bus",
        metavar="NAME",
        help="a rig with several [buses.<name>]: show this bus's joints only (default: every bus)",
    )
    parser.add_argument(
        "--at", metavar="T1,T2,...", help="show times (s) at which to print each joint's target"
    )
    parser.add_argument("--json", action="store_true", help="with --at: print JSON")
    parser.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="preview length (s); default the animation's length "
        f"({ENDLESS_PREVIEW_S:g} s if it never ends)",
    )
    parser.add_argument(
        "--out", metavar="FILE", help="preview PNG (default <out_dir>/<rig>-tracks.png)"
    )


def _say(message: str) -> None:
    print(f"hilsim tracks: {message}", file=sys.stderr)


def parse_times(text: str) -> list[float]:
    """``"0,0.5,1"`` -> [0.0, 0.5, 1.0]; ValueError naming the bad item."""
    times = []
    for item in text.split(","):
        try:
            t = float(item)
        except ValueError:
            raise ValueError(f"--at: {item.strip()!r} is not a time in s") from None
        if not (math.isfinite(t) and t >= 0):
            raise ValueError(f"--at: {item.strip()!r} must be a finite time >= 0 s")
        times.append(t)
    return times


def run(args: argparse.Namespace) -> int:
    from hilsim.rig import RigError, load_rigs, select_bus
    from hilsim.show.parts import build_parts

    try:
        times = parse_times(args.at) if args.at is not None else None
        if args.json and times is None:
            raise ValueError("--json needs --at T1,T2,...")
        if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
            raise ValueError(f"--duration must be a finite time > 0 s, got {args.duration!r}")
        if args.out is not None and Path(args.out).suffix.lower() != ".png":
            raise ValueError(f"--out {args.out}: the preview is a PNG; give a name ending in .png")
        rigs = load_rigs(args.config)
        if args.bus is not None or len(rigs) == 1:
            rigs = (select_bus(rigs, args.bus),)
        shows = [(rig, build_parts(rig)) for rig in rigs]  # one per bus, in the file's order
    except (RigError, ValueError) as exc:
        _say(str(exc))
        return int(ExitCode.USAGE)
    for _rig, parts in shows:
        for note in parts.targets.notes:  # what the animation files say, on stderr
            _say(f"note: {note}")
    if times is not None:
        from hilsim.show.preview import targets_at

        values = {k: v for _rig, parts in shows for k, v in targets_at(parts, times).items()}
        if args.json:
            print(json.dumps(values))
        else:
            for name, row in values.items():
                print(f"{name}: " + ", ".join(f"{v:.4f}" for v in row))
        return int(ExitCode.OK)
    return _preview(args, shows)


def _preview(args: argparse.Namespace, shows: list[tuple[Rig, Parts]]) -> int:
    from hilsim.show.preview import combine, plot_preview, preview
    from hilsim.targets.check import check_tracks

    rig = shows[0][0]
    lengths = [parts.targets.duration for _rig, parts in shows]
    # the figure's length: its longest bus's (a bus that never ends: the figure never does)
    ends = [d for d in lengths if d is not None]
    longest = max(ends) if len(ends) == len(lengths) else None
    duration = args.duration or longest or ENDLESS_PREVIEW_S
    if args.duration is None and longest is None:
        _say(f"the animation never ends: previewing its first {ENDLESS_PREVIEW_S:g} s")
    try:
        previews = [preview(parts, duration) for _rig, parts in shows]
    except ValueError as exc:
        _say(str(exc))
        return int(ExitCode.USAGE)
    for each, parts in shows:
        for w in check_tracks(parts.targets, each.joints, each.loop.period_s, duration_s=duration):
            _say(f"warning: {w}")
    p = previews[0] if len(shows) == 1 else combine(previews, [str(r.bus_name) for r, _ in shows])
    for i, name in enumerate(p.joints):
        count = int(p.clamped[:, i].sum())
        if count:
            which = p.limits_text(i)
            _say(
                f"{name}: the safety filter would change the command on {count} tick(s) "
                f"after the {rig.safety.soft_start_s:g} s soft start"
                + (f": {which}" if which else "")
            )
    out = Path(args.out) if args.out else Path(rig.telemetry.out_dir) / f"{rig.name}-tracks.png"
    title = f"{rig.name}: targets through the springs and safety filter"
    if len(shows) > 1:
        title += f" ({len(shows)} buses: {', '.join(str(r.bus_name) for r, _ in shows)})"
    elif args.bus is not None:
        title += f" (bus {args.bus})"
    try:
        path = plot_preview(p, out, title)
    except OSError as exc:
        _say(f"cannot write {out}: {exc}")
        return int(ExitCode.USAGE)
    print(f"  preview: {path}", file=sys.stderr)
    return int(ExitCode.OK)
