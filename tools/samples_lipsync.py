"""Write sample lip-sync files into configs/animations/lipsync/: one set of cues in every form.

The cues are the Rhubarb Lip Sync README's "Hi" (X 0.00, D 0.05, C 0.27, B 0.31, X 0.43,
recording ends 0.47 s), written by this script from the published formats:

* ``hi.tsv``, ``hi.json``, ``hi.xml``: Rhubarb's three outputs (times in seconds);
* ``hi.dat``: a Moho switch file at 100 fps with Rhubarb's letters (frame = 1 + int(fps·t));
* ``hi_blair.dat``: the same at 24 fps with Preston Blair names (``--datUsePrestonBlair``);
* ``hi.pgo``: a Papagayo document at 24 fps - one voice, one phrase, the word "Hi" from
  D's frame to the frame before the closing X, its phonemes AI, E, etc (Blair's names for
  D, C, B).

With a jaw table {X=0, A=0, B=0.2, C=0.5, D=1.0, ...} over 0-20° each gives 0° at 0.02 s,
20° at 0.10 s, 10° at 0.29 s, 4° at 0.35 s and 0° at 0.45 s (review R1.2).

    python tools/samples_lipsync.py [OUTPUT_DIR]

Deterministic. Tests import its functions.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

HI_CUES = [(0.00, "X"), (0.05, "D"), (0.27, "C"), (0.31, "B"), (0.43, "X")]
HI_END = 0.47
#: Rhubarb's DAT exporter's Preston Blair names
BLAIR = {"A": "MBP", "B": "etc", "C": "E", "D": "AI", "E": "O", "F": "U", "G": "FV", "H": "L",
         "X": "rest"}  # fmt: skip


def frame_of(t: float, fps: float) -> int:
    """The 0-based frame holding time t (int(fps·t), robust to 0.05·100 = 5.000000000000001)."""
    return math.floor(fps * t + 1e-9)


def rhubarb_tsv(cues=HI_CUES, end: float = HI_END) -> str:
    return "".join(f"{t:.2f}\t{s}\n" for t, s in [*cues, (end, "X")])


def rhubarb_json(cues=HI_CUES, end: float = HI_END) -> str:
    ends = [t for t, _ in cues[1:]] + [end]
    doc = {
        "metadata": {"soundFile": "hi.wav", "duration": end},
        "mouthCues": [
            {"start": t, "end": e, "value": s} for (t, s), e in zip(cues, ends, strict=True)
        ],
    }
    return json.dumps(doc, indent=2) + "\n"


def rhubarb_xml(cues=HI_CUES, end: float = HI_END) -> str:
    ends = [t for t, _ in cues[1:]] + [end]
    rows = "".join(
        f'    <mouthCue start="{t:.2f}" end="{e:.2f}">{s}</mouthCue>\n'
        for (t, s), e in zip(cues, ends, strict=True)
    )
    return (
        '<?xml version="1.0" encoding="utf-8"?>\n<rhubarbResult>\n  <metadata>\n'
        f"    <soundFile>hi.wav</soundFile>\n    <duration>{end:.2f}</duration>\n"
        f"  </metadata>\n  <mouthCues>\n{rows}  </mouthCues>\n</rhubarbResult>\n"
    )


def moho_dat(cues=HI_CUES, end: float = HI_END, fps: float = 100, blair: bool = False) -> str:
    lines = ["MohoSwitch1"]
    for t, s in [*cues, (end, "X")]:
        lines.append(f"{1 + frame_of(t, fps)} {BLAIR[s] if blair else s}")
    return "\n".join(lines) + "\n"


def papagayo_pgo(cues=HI_CUES, end: float = HI_END, fps: int = 24, word: str = "Hi") -> str:
    """One voice, one phrase, one word over the cues between the first and the last X."""
    inner = [(frame_of(t, fps), BLAIR[s]) for t, s in cues if s != "X"]
    close = next(frame_of(t, fps) for t, s in cues if s == "X" and frame_of(t, fps) > inner[0][0])
    start, stop = inner[0][0], close - 1
    lines = ["lipsync version 1", "hi.wav", str(fps), str(math.ceil(end * fps)), "1",
             "\tVoice 1", f"\t{word}", "\t1", f"\t\t{word}", f"\t\t{start}", f"\t\t{stop}", "\t\t1",
             f"\t\t\t{word} {start} {stop} {len(inner)}"]  # fmt: skip
    lines += [f"\t\t\t\t{f} {name}" for f, name in inner]
    return "\n".join(lines) + "\n"


def write_samples(out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "hi.tsv": rhubarb_tsv(),
        "hi.json": rhubarb_json(),
        "hi.xml": rhubarb_xml(),
        "hi.dat": moho_dat(fps=100),
        "hi_blair.dat": moho_dat(fps=24, blair=True),
        "hi.pgo": papagayo_pgo(fps=24),
    }
    written = []
    for name, text in files.items():
        (out / name).write_text(text, encoding="utf-8")
        written.append(out / name)
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parent.parent / "configs" / "animations" / "lipsync"
    parser.add_argument("out", nargs="?", type=Path, default=default)
    for path in write_samples(parser.parse_args().out):
        print(f"{path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
