"""Record a take: raw ``(t, deg)`` samples of live input per joint, reduced to keyframes.

:class:`Take` keeps every sample the loop hands it (``record``; ``record_samples`` takes a MIDI
poll's ``samples``): one per message, in show time, per joint. It never raises in the loop's
path: a non-finite value or a time before the joint's last sample is skipped and counted
(``skipped``); a second sample at the same time replaces the first.

:meth:`Take.reduce` turns each joint's samples into linear keyframes within ``tolerance_deg``:
Ramer–Douglas–Peucker on (t, deg) with the *vertical* distance (the replay error at that time,
not the distance to the chord), then the replay is checked at every raw sample and the tolerance
halved until it holds (float rounding aside, the first pass does). Both the raw take and the
keys replay linearly between points (what a CSV track and ``easing = "linear"`` keys do), and
the largest difference between two such polylines lies at one of their points, so the check at
the samples bounds the error at every tick. :meth:`Take.replay_error` measures it at a loop's
ticks, against the raw take replayed linearly or *held* (each value until the next message,
which is what the live target was).

Out: :meth:`Reduced.keys` (``[[t, deg], ...]`` for a rig's ``type = "keyframes"``),
:meth:`Reduced.track` (a :class:`~hilsim.targets.Keyframes`), and :func:`write_csv_track` (the
format :mod:`hilsim.targets.csv_file` reads, written to a temporary file and renamed: a file is
whole or absent). Times are show times minus ``origin_s``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray, JsonDict
from hilsim.targets.tracks import Keyframes


class Take:
    """Raw live-input samples per joint (see the module docstring).

    Args:
        joints: the joints recorded; a sample for another joint is skipped and counted.
            ``None``: any joint, in the order first seen.
    """

    def __init__(self, joints: Sequence[str] | None = None) -> None:
        self._only = None if joints is None else frozenset(joints)
        self._t: dict[str, list[float]] = {j: [] for j in joints or ()}
        self._v: dict[str, list[float]] = {j: [] for j in joints or ()}
        self.skipped = {"not_finite": 0, "out_of_order": 0, "unknown_joint": 0}

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self._t)

    def record(self, t: float, joint: str, deg: float) -> bool:
        """Keep one sample (show time s, degrees); ``False`` if skipped (counted)."""
        if self._only is not None and joint not in self._only:
            self.skipped["unknown_joint"] += 1
            return False
        if not (math.isfinite(t) and math.isfinite(deg)):
            self.skipped["not_finite"] += 1
            return False
        ts = self._t.setdefault(joint, [])
        vs = self._v.setdefault(joint, [])
        if ts and t <= ts[-1]:
            if t < ts[-1]:
                self.skipped["out_of_order"] += 1
                return False
            vs[-1] = float(deg)  # the same instant: the later value wins
            return True
        ts.append(float(t))
        vs.append(float(deg))
        return True

    def record_samples(self, samples: Iterable[tuple[float, str, float]]) -> None:
        """Keep ``(t, joint, deg)`` samples, e.g. a MIDI poll's ``samples``."""
        for t, joint, deg in samples:
            self.record(t, joint, deg)

    def raw(self, joint: str) -> tuple[FloatArray, FloatArray]:
        """A joint's samples: times (s) and degrees, shape ``(n,)`` each."""
        return np.array(self._t[joint], dtype=np.float64), np.array(
            self._v[joint], dtype=np.float64
        )

    def write_raw_csv(
        self, path: str | Path, *, origin_s: float = 0.0, overwrite: bool = False
    ) -> Path:
        """Every joint's raw samples as one CSV track (see :func:`write_csv_track`); joints
        without samples are left out."""
        cols = {j: self.raw(j) for j in self._t if self._t[j]}
        return write_csv_track(path, cols, origin_s=origin_s, overwrite=overwrite)

    def __len__(self) -> int:
        """Samples kept, all joints."""
        return sum(len(ts) for ts in self._t.values())

    def reduce(self, tolerance_deg: float, *, held: bool = False) -> Reduced:
        """Each joint's samples as linear keys within ``tolerance_deg`` (> 0) of the raw take
        at every instant: replayed linearly, or ``held`` (each value until the next sample, as
        a live target was: a step is kept as a step, 1 µs wide). A joint with no samples is
        left out."""
        if not (isinstance(tolerance_deg, int | float) and 0 < tolerance_deg < math.inf):
            raise ValueError(
                f"take tolerance must be a positive number of degrees, got {tolerance_deg!r}"
            )
        keys: dict[str, FloatArray] = {}
        errors: dict[str, float] = {}
        for joint in self._t:
            t, v = self.raw(joint)
            if not len(t):
                continue
            if held:
                t, v = held_polyline(t, v)
            tol = float(tolerance_deg)
            for _ in range(60):  # halving: the first pass holds but for float rounding
                idx = rdp_vertical(t, v, tol)
                err = float(np.max(np.abs(np.interp(t, t[idx], v[idx]) - v)))
                if err <= tolerance_deg:
                    break
                tol /= 2
            keys[joint] = np.column_stack((t[idx], v[idx]))
            errors[joint] = err
        return Reduced(keys, float(tolerance_deg), errors)

    def replay_error(
        self, joint: str, reduced: Reduced, rate_hz: float, *, held: bool = False
    ) -> float:
        """The largest |reduced − raw| (deg) at the ticks ``k / rate_hz`` from the joint's first
        sample to its last; the raw take replayed linearly, or ``held`` (each value until the
        next sample, as the live target was)."""
        t, v = self.raw(joint)
        k = np.arange(math.ceil(t[0] * rate_hz - 1e-9), math.floor(t[-1] * rate_hz + 1e-9) + 1)
        ticks = k / rate_hz
        if held:
            raw = v[np.clip(np.searchsorted(t, ticks + 1e-12, side="right") - 1, 0, len(v) - 1)]
        else:
            raw = np.interp(ticks, t, v)
        key = reduced.keys_array(joint)
        return float(np.max(np.abs(np.interp(ticks, key[:, 0], key[:, 1]) - raw), initial=0.0))


def held_polyline(t: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Samples held until the next one, as a polyline: before each sample a point at the
    previous value, a microsecond earlier (half the gap when the gap is shorter)."""
    if len(t) < 2:
        return t, v
    gap = np.diff(t)
    before = t[1:] - np.minimum(1e-6, gap / 2)
    tt = np.empty(2 * len(t) - 1)
    vv = np.empty_like(tt)
    tt[0::2], vv[0::2] = t, v
    tt[1::2], vv[1::2] = before, v[:-1]
    return tt, vv


def rdp_vertical(t: FloatArray, v: FloatArray, tolerance: float) -> npt.NDArray[np.intp]:
    """Indices of the points Ramer–Douglas–Peucker keeps, measuring each point's *vertical*
    distance to the chord (the linear replay's error there); first and last always kept.
    Iterative (no recursion limit on long takes); numpy per segment."""
    n = len(t)
    keep = np.zeros(n, dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, n - 1)] if n > 2 else []
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        ts = t[i + 1 : j]
        chord = v[i] + (v[j] - v[i]) * (ts - t[i]) / (t[j] - t[i])
        err = np.abs(v[i + 1 : j] - chord)
        m = int(np.argmax(err))
        if err[m] > tolerance:
            m += i + 1
            keep[m] = True
            stack.append((i, m))
            stack.append((m, j))
    return np.flatnonzero(keep)


@dataclass(frozen=True)
class Reduced:
    """A take reduced to linear keys: ``keys_deg`` joint -> array ``(k, 2)`` of (t s, deg),
    the tolerance asked, and per joint the largest error found at the raw samples (deg)."""

    keys_deg: Mapping[str, FloatArray]
    tolerance_deg: float
    max_error_deg: Mapping[str, float]

    def keys_array(self, joint: str) -> FloatArray:
        return self.keys_deg[joint]

    def keys(self, joint: str, origin_s: float = 0.0) -> list[list[float]]:
        """``[[t, deg], ...]`` for a rig's ``{type = "keyframes", keys = ...}`` (times − origin)."""
        return [[float(t) - origin_s, float(d)] for t, d in self.keys_deg[joint]]

    def track(self, joint: str, origin_s: float = 0.0) -> Keyframes:
        """The keys as a linear :class:`~hilsim.targets.Keyframes` (radians), ready to replay."""
        k = self.keys_deg[joint]
        return Keyframes(k[:, 0] - origin_s, np.radians(k[:, 1]), "linear")

    def write_csv(
        self, path: str | Path, *, origin_s: float = 0.0, overwrite: bool = False
    ) -> Path:
        """Every joint's keys as one CSV track (see :func:`write_csv_track`)."""
        cols = {j: (k[:, 0], k[:, 1]) for j, k in self.keys_deg.items()}
        return write_csv_track(path, cols, origin_s=origin_s, overwrite=overwrite)


def write_csv_track(
    path: str | Path,
    columns: Mapping[str, tuple[FloatArray, FloatArray]],
    *,
    origin_s: float = 0.0,
    overwrite: bool = False,
) -> Path:
    """Write joints' (times s, degrees) as a CSV track: ``time_s,<joint>,...``.

    The rows are the union of every joint's times; each column is its joint's polyline there
    (held before its first and after its last point), so the file replays each joint exactly as
    its points do (:class:`~hilsim.targets.csv_file.CsvCurve` is linear and holds). Numbers are
    written with ``repr`` (they read back bit for bit). Written to ``<path>.tmp`` and renamed.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is false.
        ValueError: no columns, or a joint with no points.
    """
    path = Path(path)
    if not columns:
        raise ValueError(f"{path}: a CSV track needs at least one joint")
    for joint, (t, _) in columns.items():
        if not len(t):
            raise ValueError(f"{path}: joint {joint!r} has no samples")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; not overwritten")
    grid = np.unique(np.concatenate([np.asarray(t, dtype=np.float64) for t, _ in columns.values()]))
    names = list(columns)
    data = [np.interp(grid, *columns[j]) for j in names]
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8", newline="") as f:
        f.write(",".join(["time_s", *names]) + "\n")
        for r, t in enumerate(grid):
            f.write(
                ",".join([repr(float(t) - origin_s), *(repr(float(c[r])) for c in data)]) + "\n"
            )
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


def write_take(
    take: Take,
    directory: str | Path,
    tolerance_deg: float,
    *,
    held: bool = True,
    reduce_deg: float | None = None,
    origin_s: float = 0.0,
    comment: Sequence[str] = (),
) -> JsonDict:
    """Write a take into ``directory`` (created): ``raw.csv`` (every sample), ``keys.csv``
    (linear keys within ``tolerance_deg`` of the take; ``held``: of the take *as it was live*,
    each value held until the next, so a jump stays a jump) and ``take.toml``, a
    ``[clips.take]`` table to paste into a rig or show file (``type = "keyframes"``, linear).
    ``reduce_deg``: the tolerance the reduction uses (default ``tolerance_deg``; teach-by-hand
    keeps room for the encoder's rounding); ``origin_s``: the show time the files' 0 is;
    ``comment``: the TOML's first lines (default: the tolerance). Each file is whole or absent.
    Returns what was written: paths, keys and raw samples per joint, the largest error found."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    reduced = take.reduce(tolerance_deg if reduce_deg is None else reduce_deg, held=held)
    raw = take.write_raw_csv(directory / "raw.csv", origin_s=origin_s, overwrite=True)
    keys = reduced.write_csv(directory / "keys.csv", origin_s=origin_s, overwrite=True)
    lines = list(comment) or [
        f"# a take reduced within {tolerance_deg:g} deg; linear keys [[t_s, deg], ...]"
    ]
    lines.append("[clips.take]")
    for joint in reduced.keys_deg:
        pairs = ", ".join(f"[{t!r}, {d!r}]" for t, d in reduced.keys(joint, origin_s))
        lines.append(f'{joint} = {{ type = "keyframes", easing = "linear", keys = [{pairs}] }}')
    toml = write_text(directory / "take.toml", "\n".join(lines) + "\n")
    return {
        "raw_csv": str(raw),
        "keys_csv": str(keys),
        "take_toml": str(toml),
        "raw_samples": {j: len(take.raw(j)[0]) for j in reduced.keys_deg},
        "keys": {j: len(k) for j, k in reduced.keys_deg.items()},
        "max_error_deg": dict(reduced.max_error_deg),
    }


def write_text(path: Path, text: str) -> Path:
    """``text`` into ``path`` through ``<path>.tmp`` and a rename: whole or absent."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
