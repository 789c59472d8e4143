"""The parts of a show: a loaded rig turned into what :class:`~hilsim.show.loop.HilLoop` runs.

:func:`build_parts` makes the targets, the joint map, the safety filter and the integrator
from a rig; :func:`with_show` adds a show file's (or ``--live``'s) director. Errors are
:class:`~hilsim.rig.RigError`, naming the file and the key.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hilsim.dynamics.integrators import Integrator, make_integrator
from hilsim.rig import Rig, RigError
from hilsim.rig.joint_map import JointMap
from hilsim.rig.model import JointConfig
from hilsim.safety.filter import SafetyFilter
from hilsim.targets import TargetSet, Track, track_from_spec

if TYPE_CHECKING:  # the live package is imported only for a show (see with_show)
    from hilsim.live.director import Director

__all__ = ["Parts", "build_parts", "build_targets", "track_maker", "with_show"]


@dataclass
class Parts:
    """Everything a :class:`~hilsim.show.loop.HilLoop` runs, built from one rig."""

    rig: Rig
    targets: TargetSet
    joint_map: JointMap
    safety: SafetyFilter
    integrator: Integrator
    #: live inputs and the show runtime (``hilsim run --show/--live``), or None
    director: Director | None = None


#: ``make(spec, joint, where)``: a joint's track from a target table (see :func:`track_maker`)
TrackMaker = Callable[[Mapping[str, Any], JointConfig, str], Track]


def track_maker(rig: Rig, base_dir: Path, source: Path | str, notes: list[str]) -> TrackMaker:
    """``make(spec, joint, where)``: one of ``rig``'s joints' track from a target table in the
    file ``source`` (a rig or a show file; relative paths from ``base_dir``), each animation
    file read once whichever joints use it; what the files say goes into ``notes``; an error
    is a RigError naming ``source`` and ``where``."""
    cache: dict[object, object] = {}  # parsed files by path (or by file and options)

    def make(spec: Mapping[str, Any], joint: JointConfig, where: str) -> Track:
        try:
            return track_from_spec(
                spec,
                base_dir=base_dir,
                joint_name=joint.name,
                csv_cache=cache,
                notes=notes,
                spring=joint.spring,
            )
        except (ValueError, OSError) as exc:
            raise RigError(f"{source}: {where}: {exc}") from None

    return make


def build_targets(rig: Rig) -> TargetSet:
    """One track per joint from the rig's ``target`` tables, through its ``[[play]]`` of
    ``[clips]`` if it has them (:mod:`hilsim.targets.clips`); errors name file and key."""
    notes: list[str] = []  # what the files say the user should read (TargetSet.notes)
    track = track_maker(rig, rig.base_dir, rig.path, notes)

    tracks = [
        track(j.target, j, f"joints[{i}].target ({j.name})") for i, j in enumerate(rig.joints)
    ]
    if rig.play:
        from hilsim.targets.clips import Cue, sequence_for

        names = set(rig.joint_names)
        clips = {
            name: {jn: track(spec, rig.joints[rig.joint_names.index(jn)], f"clips.{name}.{jn}")
                   for jn, spec in table.items() if jn in names}  # this bus's joints
            for name, table in rig.clips
        }  # fmt: skip
        cues = [Cue(p.at_s, p.clip, p.loop) for p in rig.play]
        tracks = [
            sequence_for(j.name, tr, cues, clips) for j, tr in zip(rig.joints, tracks, strict=True)
        ]
    targets = TargetSet(tracks, rig.joint_names)
    targets.notes = tuple(notes)
    return targets


def build_parts(rig: Rig, targets: TargetSet | None = None) -> Parts:
    """The show's parts; ``targets`` defaults to :func:`build_targets`. Raises RigError."""
    j = rig.joints
    safety = SafetyFilter(
        np.array([jt.min_rad for jt in j]),
        np.array([jt.max_rad for jt in j]),
        np.array([jt.max_speed_rad_s for jt in j]),
        np.array([jt.max_accel_rad_s2 for jt in j]),
        rig.loop.period_s,
        soft_start_s=rig.safety.soft_start_s,
        joint_names=rig.joint_names,
    )
    return Parts(
        rig=rig,
        targets=build_targets(rig) if targets is None else targets,
        joint_map=JointMap.of(j),
        safety=safety,
        integrator=make_integrator(rig.loop.integrator, rig.spring_bank()),
    )


def with_show(parts: Parts, show_path: str | None, live: bool, *, virtual: bool = False) -> Parts:
    """``parts`` with a :class:`~hilsim.live.director.Director` for the show file (and/or
    ``--live``: OSC on 127.0.0.1 for every joint; neither: only ``Show.cue/set_joint/
    release``, ending with the rig's animation); its targets replace the rig's, which stay
    under it; ``virtual``: sounds are scheduled and logged, not played. Raises RigError (one
    line) for a show file that cannot be used."""
    from hilsim.live.director import build_director
    from hilsim.live.showfile import (
        OscConfig,
        RecordConfig,
        ShowSpec,
        joint_ranges,
        live_spec,
        load_show,
    )

    rig = parts.rig
    if show_path is None and not live:  # Show.cue/set_joint/release alone (the panel)
        spec = ShowSpec(path=None, name=f"{rig.name} controls", record=RecordConfig())
    elif show_path is None:
        spec = live_spec(rig)
    else:
        notes: list[str] = []
        make = track_maker(rig, Path(show_path).parent, show_path, notes)
        joints = dict(zip(rig.joint_names, rig.joints, strict=True))
        spec = load_show(show_path, rig, lambda s, name, where: make(s, joints[name], where))
        spec.notes += notes
        if live and spec.osc is None:
            spec.osc = OscConfig(joints=joint_ranges(rig))
    try:
        director = build_director(spec, rig.joint_names, parts.targets, silent=virtual)
    except (ValueError, OSError) as exc:
        raise RigError(f"{show_path or '--live'}: {exc}") from None
    if show_path is None and not live:  # no inputs of its own: it ends with the animation
        for track in director.tracks:
            track.end = parts.targets.duration
    parts.director, parts.targets = director, director.targets
    return parts
