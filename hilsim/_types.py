"""Type aliases shared by the package's annotations (one definition for every module)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

#: a float64 ndarray (positions in rad, times in s, spring parameters, ...)
FloatArray = npt.NDArray[np.float64]
#: an int64 ndarray (counters)
IntArray = npt.NDArray[np.int64]
#: a JSON object as it is written or read (a summary, its sections, a status line's fields):
#: its values are whatever JSON holds, so they are Any
JsonDict = dict[str, Any]
