"""Teach-by-hand: chosen joints go limp while the show runs, a person moves them, and their
present positions become a take, reduced to keyframes ready to replay.

The show file's ``[teach]`` names the joints and a ``tolerance_deg``. Per tick (the loop and the
director, :mod:`hilsim.live.director`):

1. At the start the loop turns torque off on the teach joints only, and tells the servo watch
   that torque off is expected there (``watch.set_limp``). An Alert, silence, a hardware error
   or a reset still stop the show.
2. The director passes every tick's present positions to :meth:`Teach.record`, which keeps the
   teach joints' samples as a :class:`~hilsim.live.takes.Take`.
3. **A limp joint's target follows its present position** (:meth:`Teach.targets_deg`). So the
   spring, the safety filter and the goal sent sit where the hand holds the horn, and nothing
   jumps when torque returns. A servo with Drive Mode bit 3 (Torque On by Goal Update) would
   turn itself on: :func:`hilsim.show.session.check_teach` refuses it at start.
4. At the end :meth:`Teach.finish` writes ``raw.csv``, ``keys.csv`` and ``take.toml``, each
   whole or not at all.

The tolerance is against the hand, not the readings. A reading is within half an encoder
count (:data:`HALF_COUNT_DEG`) of the horn, so readings are reduced within ``reduce_deg``.
More: ``docs/live.md`` (Teach by hand).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hilsim.live.takes import Take, write_take

#: the default tolerance of the reduced keys (deg): about two encoder counts of an X-series
#: servo (0.088° each), so the keys keep what a hand did and drop the encoder's last digit
DEFAULT_TOLERANCE_DEG = 0.2
#: half an X-series encoder count (deg): how far a reading may be from where the horn is
HALF_COUNT_DEG = 180.0 / 4096
_KEYS = ("joints", "tolerance_deg")


@dataclass(frozen=True)
class TeachConfig:
    """``[teach]``: the joints taught by hand (rig order) and the reduction's tolerance."""

    joints: tuple[str, ...]
    tolerance_deg: float = DEFAULT_TOLERANCE_DEG

    @classmethod
    def from_table(
        cls, table: Mapping[str, Any], where: str, joint_names: Sequence[str]
    ) -> TeachConfig:
        """Read ``[teach]``; raises ValueError ``"<where>.<key>: ..."`` (one line)."""
        if not isinstance(table, Mapping):
            raise ValueError(f"{where}: must be a table, got {type(table).__name__}")
        for key in table:
            if key not in _KEYS:
                raise ValueError(f"{where}.{key}: unknown key; allowed: {', '.join(_KEYS)}")
        if "joints" not in table:
            raise ValueError(f'{where}.joints: missing: the joints moved by hand, e.g. ["jaw"]')
        joints = table["joints"]
        names = tuple(joint_names)
        if not isinstance(joints, list | tuple) or not joints:
            raise ValueError(f"{where}.joints: must be a non-empty list of joint names")
        for j in joints:
            if j not in names:
                raise ValueError(
                    f"{where}.joints: no such joint {j!r} (joints: {', '.join(names)})"
                )
        if len(set(joints)) != len(joints):
            raise ValueError(f"{where}.joints: a joint is named twice: {list(joints)!r}")
        tol = table.get("tolerance_deg", DEFAULT_TOLERANCE_DEG)
        if isinstance(tol, bool) or not isinstance(tol, int | float):
            raise ValueError(f"{where}.tolerance_deg: must be a number of degrees, got {tol!r}")
        if not 0 < tol <= 90:
            raise ValueError(f"{where}.tolerance_deg: must be > 0 and <= 90, got {tol!r}")
        order = [n for n in names if n in joints]  # the rig's order
        return cls(tuple(order), float(tol))


class Teach:
    """The take of one teach-by-hand show.

    Args:
        joint_names: every joint of the rig, in bus order (the order of ``present_deg``).
        teach: the :class:`TeachConfig`, or the names of the joints taught.
        tolerance_deg: overrides the config's tolerance.

    Attributes:
        joints: the teach joints (rig order); ``limp_indices`` their indices in
        ``joint_names`` (for ``watch.set_limp`` and the servo IDs to turn limp); ``take``
        the raw samples; ``origin_s`` the first sample's time (None before one).
    """

    def __init__(
        self,
        joint_names: Sequence[str],
        teach: TeachConfig | Sequence[str],
        *,
        tolerance_deg: float | None = None,
    ) -> None:
        self.names = tuple(joint_names)
        if isinstance(teach, TeachConfig):
            config = teach
        else:
            config = TeachConfig.from_table({"joints": list(teach)}, "teach", self.names)
        tol = config.tolerance_deg if tolerance_deg is None else tolerance_deg
        self.config = TeachConfig.from_table(
            {"joints": list(config.joints), "tolerance_deg": tol}, "teach", self.names
        )
        self.joints = self.config.joints
        self.tolerance_deg = tol = self.config.tolerance_deg
        #: the tolerance the readings are reduced with (see the module docstring)
        self.reduce_deg = tol - HALF_COUNT_DEG if tol > 2 * HALF_COUNT_DEG else tol / 2
        self.limp_indices = tuple(self.names.index(j) for j in self.joints)
        self._pairs = tuple(zip(self.joints, self.limp_indices, strict=True))
        self.take = Take(self.joints)
        self.origin_s: float | None = None
        self.ticks = 0

    def record(self, t: float, present_deg: Sequence[float]) -> None:
        """One tick: show time ``t`` (s) and every joint's present position (joint frame,
        degrees; NaN where the read failed). Keeps the teach joints' samples; never raises
        for a value (a NaN or a time going back is skipped and counted in ``take.skipped``)."""
        if len(present_deg) != len(self.names):
            raise ValueError(
                f"one present position per joint ({len(self.names)}), got {len(present_deg)}"
            )
        self.ticks += 1
        take = self.take
        for joint, i in self._pairs:
            if take.record(t, joint, present_deg[i]) and self.origin_s is None:
                self.origin_s = float(t)

    def targets_deg(self, present_deg: Sequence[float]) -> dict[str, float]:
        """The live target of each teach joint this tick: its present position (degrees), so
        the spring, the safety filter and the goal follow the hand and torque returns without
        a jump. A joint without a valid reading is left out (its last value holds)."""
        out: dict[str, float] = {}
        for joint, i in self._pairs:
            deg = present_deg[i]
            if math.isfinite(deg):
                out[joint] = float(deg)
        return out

    def summary(self) -> dict[str, Any]:
        """For the run summary's ``live.teach``: joints, samples per joint, skipped."""
        return {
            "joints": list(self.joints),
            "samples": {j: len(self.take.raw(j)[0]) for j in self.joints},
            "skipped": dict(self.take.skipped),
            "tolerance_deg": self.tolerance_deg,
        }

    def finish(self, run_dir: str | Path) -> dict[str, Any]:
        """Write the take into ``run_dir`` (created): ``raw.csv``, ``keys.csv``, ``take.toml``
        (see the module docstring); returns what was written (paths, raw samples and keys per
        joint, the largest replay error found, ``origin_s``). Nothing recorded: nothing is
        written, and the result says so. Raises OSError when the disk refuses."""
        sampled = [j for j in self.joints if len(self.take.raw(j)[0])]
        if not sampled or self.origin_s is None:
            return {"written": False, "message": "teach-by-hand: no sample was recorded"}
        origin = self.origin_s
        written = write_take(
            self.take,
            run_dir,
            self.tolerance_deg,
            held=False,  # a hand moves continuously: the readings are a polyline
            reduce_deg=self.reduce_deg,
            origin_s=origin,
            comment=(
                f"# taught by hand, reduced within {self.tolerance_deg:g} deg; times from the "
                "first",
                f"# sample (show time {origin:g} s); linear keys [[t_s, deg], ...]",
            ),
        )
        return {"written": True, **written, "origin_s": origin}
