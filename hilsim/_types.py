"""Array type aliases shared by the package's annotations (one definition for every module)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: a float64 ndarray (positions in rad, times in s, spring parameters, ...)
FloatArray = npt.NDArray[np.float64]
#: an int64 ndarray (counters)
IntArray = npt.NDArray[np.int64]
