"""What every reader of another tool's animation file shares: its errors, the unit map from
the file's numbers to joint degrees, and the track of a sampled curve.

* :class:`FormatError` - a file that cannot be used; the message is ``file:where: what``,
  ``where`` naming the position (``line 12``, ``byte 40``, ``frame 7``, ``record 3``);
  :func:`read_bytes` and :func:`decode_text` read a text file with those errors.
* :class:`UnitMap` - the file's units to joint degrees, linear between two points the rig
  gives (e.g. 1000-2000 µs -> 0-40°). The files never say what their numbers mean (µs, PWM
  ticks, DMX values, Bottango's 0-8192): the rig does, and a missing or impossible mapping is
  an error, never a guess.
* :class:`SampledTrack` - a :class:`~hilsim.targets.tracks.Track` through samples, held
  (zero-order: the value of the last sample until the next) or linear between them; held
  before the first sample and after the last.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from hilsim._types import FloatArray
from hilsim.targets.tracks import Track, times_values

#: how a :class:`SampledTrack` goes from one sample to the next
INTERPOLATIONS = ("hold", "linear")


class FormatError(ValueError):
    """An animation file that cannot be used: ``"<file>:<where>: <what>"``.

    ``where`` names the position in the file's own terms (``line 3``, ``byte 17``,
    ``frame 12``); empty when the whole file is at fault (then ``"<file>: <what>"``).
    """

    def __init__(self, path: str | Path, where: str, message: str) -> None:
        at = f"{path}:{where}: " if where else f"{path}: "
        super().__init__(at + message)
        self.path, self.where, self.detail = str(path), where, message


def decode_text(data: bytes, path: str | Path, nul: str, encoding: str = "utf-8-sig") -> str:
    """A text file's bytes as text: a NUL byte (binary data; ``nul`` says what the reader
    expected instead) or bytes that are not UTF-8 are one FormatError naming the byte."""
    i = data.find(b"\0")
    if i >= 0:
        raise FormatError(path, f"byte {i}", nul)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"byte {exc.start}", "not UTF-8 text") from None


def read_bytes(path: str | Path) -> bytes:
    """The file's bytes; one FormatError if it cannot be read."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise FormatError(path, "", f"cannot read: {exc.strerror or exc}") from None


@dataclass(frozen=True)
class UnitMap:
    """A linear map from a file's units to joint degrees through two points:
    ``source[0] -> degrees[0]`` and ``source[1] -> degrees[1]``. Either pair may run
    downwards (a reversed servo). ``unit`` names the source unit for messages (``"us"``,
    ``"DMX 16-bit"``, ``"Bottango 0-8192"``).

    Raises ValueError (naming the problem) when a number is not finite or the two source
    points are equal.
    """

    source: tuple[float, float]
    degrees: tuple[float, float]
    unit: str = ""

    def __post_init__(self) -> None:
        for name, pair in (("source", self.source), ("degrees", self.degrees)):
            if len(pair) != 2 or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in pair
            ):
                raise ValueError(f"{name} must be two finite numbers, got {pair!r}")
        object.__setattr__(self, "source", (float(self.source[0]), float(self.source[1])))
        object.__setattr__(self, "degrees", (float(self.degrees[0]), float(self.degrees[1])))
        if self.source[0] == self.source[1]:
            raise ValueError(
                f"the two source points are equal ({self.source[0]:g}"
                f"{' ' + self.unit if self.unit else ''}): no angle can be told from another"
            )

    @property
    def deg_per_unit(self) -> float:
        (s0, s1), (d0, d1) = self.source, self.degrees
        return (d1 - d0) / (s1 - s0)

    def to_deg(self, x: npt.ArrayLike) -> FloatArray:
        """Source values (scalar or array) -> joint degrees."""
        return self.degrees[0] + (np.asarray(x, dtype=np.float64) - self.source[0]) * (
            self.deg_per_unit
        )

    def to_rad(self, x: npt.ArrayLike) -> FloatArray:
        """Source values -> joint radians (what tracks hold)."""
        return np.radians(self.to_deg(x))


#: how an audio jaw track's ``source`` ends (the load-time checks name its own knob)
AUDIO_JAW_SOURCE = "(audio -> jaw)"


@dataclass(frozen=True, eq=False, init=False)
class SampledTrack(Track):
    """Samples ``(times_s[i], values_rad[i])`` as a track.

    ``interpolation``: ``"hold"`` keeps each sample's value until the next (velocity 0; how a
    frame-based player such as the blender-servo-animation Arduino library or FPP plays
    them), ``"linear"`` goes straight from one to the next (velocity the slope). Before the
    first sample and after the last the value is held (velocity 0); :attr:`duration` is the
    last sample's time. ``source`` names where it came from, for messages.
    """

    times_s: FloatArray
    values_rad: FloatArray
    interpolation: str
    source: str
    _t: list[float] = field(init=False, repr=False)
    _v: list[float] = field(init=False, repr=False)
    _slope: list[float] = field(init=False, repr=False)

    def __init__(
        self,
        times_s: npt.ArrayLike,
        values_rad: npt.ArrayLike,
        interpolation: str = "hold",
        source: str = "",
    ) -> None:
        # written out (not generated) so the fields are typed as what they hold after it
        if interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}"
            )
        t, v = times_values(times_s, values_rad)
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "values_rad", v)
        object.__setattr__(self, "interpolation", interpolation)
        object.__setattr__(self, "source", source)
        object.__setattr__(self, "_t", t.tolist())
        object.__setattr__(self, "_v", v.tolist())
        slope = np.diff(v) / np.diff(t) if interpolation == "linear" else np.zeros(t.size - 1)
        object.__setattr__(self, "_slope", slope.tolist())

    def sample(self, t: float) -> tuple[float, float]:
        ts = self._t
        i = bisect_right(ts, t)
        if i == 0:
            return self._v[0], 0.0
        if i == len(ts):
            return self._v[-1], 0.0
        slope = self._slope[i - 1]
        return self._v[i - 1] + slope * (t - ts[i - 1]), slope

    def sample_array(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        times = np.asarray(t, dtype=np.float64)
        ts, vs = self.times_s, self.values_rad
        i = np.searchsorted(ts, times, side="right")
        inside = (i > 0) & (i < ts.size)
        k = np.clip(i - 1, 0, ts.size - 1)
        slope = np.zeros(max(ts.size - 1, 1))
        if ts.size > 1:
            slope[:] = self._slope
        s = np.where(inside, slope[np.clip(k, 0, slope.size - 1)], 0.0)
        pos = vs[k] + s * np.where(inside, times - ts[k], 0.0)
        pos = np.where(i == 0, vs[0], pos)
        return pos, s

    @property
    def duration(self) -> float:
        return float(self.times_s[-1])
