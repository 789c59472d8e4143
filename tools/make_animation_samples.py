"""Write every sample animation file under ``configs/animations/`` (issue 13), from this
project's own generators - none is copied from another project:

    python tools/make_animation_samples.py

Each format's generator is its own script (``tools/samples_<format>.py``, which also has a
``--bench``); this runs them all with their defaults. The tests check that the shipped files
are what the generators write.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

TOOLS = Path(__file__).resolve().parent
FORMATS = ("bottango", "blender_servo", "fseq", "audio_jaw", "lipsync", "midi")


def main() -> int:
    for name in FORMATS:
        script = TOOLS / f"samples_{name}.py"
        saved = sys.argv
        sys.argv = [str(script)]
        try:
            runpy.run_path(str(script), run_name="__main__")
        finally:
            sys.argv = saved
    return 0


if __name__ == "__main__":
    sys.exit(main())
