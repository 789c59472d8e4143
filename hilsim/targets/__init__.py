"""Animation targets: where each joint should be at show time t.

==============  ===================================================================
``tracks``      :class:`Track`, the generators, :class:`Keyframes`, :class:`Layered`,
                :class:`TargetSet`
``csv_file``    :class:`CsvAnimation`, :class:`CsvCurve` (a CSV file of degrees per joint)
``spec``        :func:`track_from_spec`: a rig file's target table → a track
``formats``     other tools' animation files (Bottango, Blender, FSEQ, audio, lip-sync)
==============  ===================================================================

``spec`` imports the other two and neither imports it, so the package has no import circle.
"""

from hilsim._types import FloatArray
from hilsim.targets.csv_file import CsvAnimation, CsvCurve, CsvFormatError
from hilsim.targets.spec import SPEC_KEYS, SpecError, track_from_spec
from hilsim.targets.tracks import (
    EASINGS,
    Hold,
    Keyframes,
    Layered,
    Sine,
    Step,
    TargetSet,
    Track,
)

__all__ = [
    "EASINGS",
    "SPEC_KEYS",
    "CsvAnimation",
    "CsvCurve",
    "CsvFormatError",
    "FloatArray",
    "Hold",
    "Keyframes",
    "Layered",
    "Sine",
    "SpecError",
    "Step",
    "TargetSet",
    "Track",
    "track_from_spec",
]
