"""blender-servo-animation exports (``.json``, ``.bin``, ``.h``) as tracks in joint radians.

The Blender add-on bakes one position per servo per frame at the scene's fps; its Arduino
library holds each frame until the next. The three forms carry the same frames and give
identical tracks. Frame ``k`` is at show time ``k / fps``; a ``.bin`` file has no fps, so the
caller gives it.

A servo missing from a frame holds its previous value: the add-on drops unchanged positions
and out-of-range ones alike. :meth:`BlenderServoAnimation.notes` says how many frames were
held. The file does not say the positions' unit (µs, PCA9685 ticks or degrees). The caller
gives a :class:`~hilsim.targets.formats.common.UnitMap`, or the bone's :class:`BoneSettings`::
In ``.bin`` and ``.h`` a ``0A`` or ``3C`` byte inside a record (an ID or position byte) is
read as data here; the add-on's Arduino library misreads it, which
:meth:`BlenderServoAnimation.misread_note` says in one line.

    anim = read_blender_servo(path, fps=None)          # fps only for .bin
    track = anim.track(0, UnitMap((1000, 2000), (0, 40), "us"), interpolation="hold")

Every bad input is one :class:`~hilsim.targets.formats.common.FormatError` naming the file and
the position (``line``, ``byte``, ``frame``). Each form's layout and the rules:
``docs/targets.md`` (blender-servo-animation).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hilsim.targets.formats.blender_servo_forms import (
    MAX_SERVO_ID,
    arduino_misread,
    is_int,
    is_number,
    parse_h,
    parse_json,
    records,
)
from hilsim.targets.formats.common import FormatError, SampledTrack, UnitMap, read_bytes

#: the suffixes read, each a form of the same frames
FORMS = (".json", ".bin", ".h")
#: ``angle=`` of :meth:`BoneSettings.unit_map`: the servo's angle (0..rotation_range) or the
#: bone's rotation (0 at its rest pose, as animated in Blender)
ANGLES = ("servo", "bone")


@dataclass(frozen=True)
class BoneSettings:
    """One bone's "Servo Settings" in the add-on, as the rig repeats them.

    ``position_min``/``position_max``: the output range (µs, PCA9685 ticks or degrees);
    ``rotation_range``: the servo's travel (degrees) over that range; ``neutral_angle``: the servo
    angle (degrees) of the bone's rest pose; ``multiplier`` and ``reverse_direction`` as set on
    the bone. The add-on computes ``angle = neutral_angle - s·multiplier·rotation`` (s = -1 when
    reversed) and ``position = position_min + angle·(position_max - position_min)/rotation_range``.

    Raises ValueError naming the field for a range that cannot be inverted.
    """

    servo_id: int
    position_min: float
    position_max: float
    rotation_range: float
    neutral_angle: float
    multiplier: float = 1.0
    reverse_direction: bool = False

    def __post_init__(self) -> None:
        if not is_int(self.servo_id) or not 0 <= self.servo_id <= MAX_SERVO_ID:
            raise ValueError(f"servo_id must be an integer 0-255, got {self.servo_id!r}")
        for name in ("position_min", "position_max", "rotation_range", "neutral_angle"):
            value = getattr(self, name)
            if not is_number(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if not self.position_min < self.position_max:
            raise ValueError(
                f"position_min ({self.position_min:g}) must be below position_max "
                f"({self.position_max:g}), as the add-on requires"
            )
        if not self.rotation_range > 0:
            raise ValueError(f"rotation_range must be > 0 degrees, got {self.rotation_range!r}")
        if not is_number(self.multiplier) or self.multiplier <= 0:
            raise ValueError(f"multiplier must be a number > 0, got {self.multiplier!r}")
        if not isinstance(self.reverse_direction, bool):
            raise ValueError(
                f"reverse_direction must be true or false, got {self.reverse_direction!r}"
            )

    def unit_map(self, angle: str) -> UnitMap:
        """Position -> degrees: ``angle="servo"`` the servo angle (position_min -> 0°,
        position_max -> rotation_range), ``angle="bone"`` the bone's rotation about its axis
        (0 at the rest pose: neutral_angle - servo angle, divided by the multiplier, negated
        when reversed)."""
        lo, hi = float(self.position_min), float(self.position_max)
        if angle == "servo":
            return UnitMap((lo, hi), (0.0, float(self.rotation_range)), "position")
        if angle == "bone":
            sign = -1.0 if self.reverse_direction else 1.0
            k = sign / self.multiplier
            return UnitMap(
                (lo, hi),
                (k * self.neutral_angle, k * (self.neutral_angle - self.rotation_range)),
                "position",
            )
        raise ValueError(f"angle must be one of {', '.join(ANGLES)}, got {angle!r}")


@dataclass(frozen=True, eq=False)
class BlenderServoAnimation:
    """The positions of one export, one record per position the file lists: record ``r`` sets
    servo ``servo[r]`` to ``position[r]`` in frame ``frame_of[r]`` (ascending); a servo the file
    leaves out of a frame holds. ``form`` is ``"json"``, ``"bin"`` or ``"h"``."""

    path: str
    form: str
    fps: int
    n_frames: int
    frame_of: np.ndarray
    servo: np.ndarray
    position: np.ndarray
    scene: str = ""

    @property
    def frames(self) -> tuple[dict[int, int], ...]:
        """Frame by frame: servo ID -> position, for the servos the file lists in it."""
        out: list[dict[int, int]] = [{} for _ in range(self.n_frames)]
        cols = (self.frame_of.tolist(), self.servo.tolist(), self.position.tolist())
        for k, sid, pos in zip(*cols, strict=True):
            out[k][sid] = pos
        return tuple(out)

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return tuple(np.unique(self.servo).tolist())

    @property
    def duration(self) -> float:
        """The file's length (s): frames / fps."""
        return self.n_frames / self.fps

    def _listed(self, servo_id: int) -> tuple[np.ndarray, np.ndarray]:
        mask = self.servo == servo_id
        if not mask.any():
            ids = ", ".join(map(str, self.servo_ids))
            raise FormatError(self.path, f"servo {servo_id}", f"not in the file (servos: {ids})")
        return self.frame_of[mask], self.position[mask].astype(np.float64)

    def positions(self, servo_id: int) -> np.ndarray:
        """One position per frame (float64), a missing frame holding the one before; frames
        before the servo's first position take that first position."""
        ks, vs = self._listed(servo_id)
        last = np.searchsorted(ks, np.arange(self.n_frames), side="right") - 1
        return vs[np.maximum(last, 0)]

    def held_frames(self, servo_id: int) -> tuple[int, ...]:
        """Frames that carry no position for ``servo_id`` (held from the frame before)."""
        return tuple(np.setdiff1d(np.arange(self.n_frames), self._listed(servo_id)[0]).tolist())

    def misread_note(self) -> str | None:
        """One line when a ``.bin``/``.h`` record's ID or position byte is 0x0A or 0x3C, which
        the add-on's own Arduino library takes for a frame end or a record start wherever it
        stands (it drops the record; a 0x0A also puts every later frame a frame late): hilsim
        reads fixed 5-byte records, so it plays the file as exported. None otherwise (and for
        ``.json``, which that library does not read)."""
        found = arduino_misread(self.servo, self.position) if self.form != "json" else None
        if found is None:
            return None
        n, r, what = found
        others = f"1 of {n} such records here" if n > 1 else "the only such record here"
        return (
            f"{self.path}: servo {int(self.servo[r])} in frame {int(self.frame_of[r])}: {what}: "
            f"it drops the record ({others}; each 0x0a also plays every later frame a frame "
            "late); hilsim reads the 5-byte records, as exported"
        )

    def notes(self, servo_id: int) -> tuple[str, ...]:
        """What the rig should print about this servo's frames: frames held for lack of a
        position, which the format cannot tell apart from positions dropped as out of range;
        and, for the whole file, :meth:`misread_note` (the same line for every servo, so a
        rig that prints each line once prints it once)."""
        misread = self.misread_note()
        notes = [misread] if misread else []
        held = self.held_frames(servo_id)
        if not held:
            return tuple(notes)
        first = int(self._listed(servo_id)[0][0])
        notes += [
            f"{self.path}: servo {servo_id}: {len(held)} of {self.n_frames} frames carry no "
            f"position and hold the one before (first such frame: {held[0]}); the format cannot "
            f"tell an unchanged position from one Blender dropped as outside the bone's range"
        ]
        if first:
            notes.append(
                f"{self.path}: servo {servo_id}: no position before frame {first}; frames "
                f"0-{first - 1} take frame {first}'s"
            )
        return tuple(notes)

    def track(
        self,
        servo_id: int,
        unit_map: UnitMap,
        *,
        interpolation: str = "hold",
        valid: tuple[float, float] | None = None,
    ) -> SampledTrack:
        """Servo ``servo_id``'s positions through ``unit_map`` as a track (joint radians).

        ``interpolation``: ``"hold"`` (the Arduino library's playback) or ``"linear"``.
        ``valid``: the range the positions must lie in (a position outside it is a FormatError
        naming its frame); None checks nothing.
        """
        pos = self.positions(servo_id)  # (SampledTrack refuses an unknown interpolation)
        if valid is not None:
            lo, hi = valid
            bad = np.flatnonzero((pos < lo) | (pos > hi))
            if bad.size:
                k = int(bad[0])
                raise FormatError(self.path, f"frame {k}", f"servo {servo_id} at {pos[k]:g}, "
                                  f"outside the bone's range {lo:g}-{hi:g} (the add-on never "
                                  "exports such a position: are these the export's "
                                  "settings?)")  # fmt: skip
        times = np.arange(self.n_frames + 1, dtype=np.float64) / self.fps
        values = unit_map.to_rad(np.append(pos, pos[-1]))
        return SampledTrack(
            times, values, interpolation, source=f"{self.path} servo {servo_id} ({self.form})"
        )

    def track_for(
        self, bone: BoneSettings, *, angle: str, interpolation: str = "hold"
    ) -> SampledTrack:
        """The track of ``bone.servo_id`` through the bone's own map (``angle`` "servo" or
        "bone", see :meth:`BoneSettings.unit_map`), positions checked against its range."""
        return self.track(
            bone.servo_id,
            bone.unit_map(angle),
            interpolation=interpolation,
            valid=(bone.position_min, bone.position_max),
        )


def read_blender_servo(path: str | Path, *, fps: int | None = None) -> BlenderServoAnimation:
    """Read an export; its form is told by the suffix (``.json``, ``.bin``, ``.h``).

    ``fps`` is required for ``.bin`` (the file does not carry it); for ``.json`` and ``.h`` it
    may be given and must then equal the file's.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in FORMS:
        raise FormatError(p, "", f"unknown form {suffix or '(no suffix)'!r}: a blender-servo-"
                          f"animation export is one of {', '.join(FORMS)}")  # fmt: skip
    data = read_bytes(p)
    return parse_blender_servo(data, suffix[1:], p, fps=fps)


def parse_blender_servo(
    data: bytes, form: str, path: str | Path = "<bytes>", *, fps: int | None = None
) -> BlenderServoAnimation:
    """The same as :func:`read_blender_servo` on bytes already read; ``form`` is ``"json"``,
    ``"bin"`` or ``"h"``."""
    if fps is not None and (not is_int(fps) or fps < 1):
        raise ValueError(f"fps must be a whole number of frames per second ≥ 1, got {fps!r}")
    if not data:
        raise FormatError(path, "", "empty file")
    if form == "json":
        file_fps, recs, scene = parse_json(data, path)
    elif form == "h":
        file_fps, recs, scene = parse_h(data, path)
    elif form == "bin":
        if fps is None:
            raise FormatError(path, "", "a .bin export does not say its fps: give it (the "
                              "scene's frame rate)")  # fmt: skip
        file_fps, recs, scene = fps, records(data, path), ""
    else:
        raise ValueError(f"form must be json, bin or h, got {form!r}")
    if fps is not None and fps != file_fps:
        raise FormatError(path, "", f"the file says {file_fps} fps, not the {fps} given")
    if not recs[0]:
        raise FormatError(path, "", "no frames")
    if not recs[1].size:
        raise FormatError(path, "", f"{recs[0]} frames, none with a position")
    return BlenderServoAnimation(str(path), form, file_fps, *recs, scene)
