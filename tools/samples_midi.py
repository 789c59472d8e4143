"""Write the sample Standard MIDI File into configs/animations/midi/, with mido (another
implementation than hilsim's reader, so the sample checks the reader against it).

``ramps.mid``, format 1, 480 ticks per quarter note:

* track 0 (the tempo map): 120 bpm (500000 µs per quarter) from tick 0, 60 bpm (1000000)
  from tick 1920 (2.0 s); End of Track at tick 5760 (2.0 + 3840/480 = 10.0 s);
* track 1, channel 1, controller 7 (volume): up 0 -> 127, value k at tick 30·k (the tempo
  changes at k = 64), then down, value 127 - k at tick 3840 + 15·k (k = 1..127);
* track 2, channel 10: note 60 from tick 480 to 720 (0.50-0.75 s) and from 2400 to 2640
  (3.0-3.5 s; the second note-off is a note-on of velocity 0, as running-status writers send).

    python tools/samples_midi.py [OUTPUT_DIR]

Deterministic. Tests import its functions (``ramps_file``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import mido

PPQN = 480
TEMPO_CHANGE_TICK = 1920
END_TICK = 5760


def _delta(events: list[tuple[int, mido.Message | mido.MetaMessage]]) -> mido.MidiTrack:
    """(absolute tick, message) -> a track of delta times, in tick order (stable)."""
    track = mido.MidiTrack()
    now = 0
    for tick, msg in sorted(events, key=lambda e: e[0]):
        track.append(msg.copy(time=tick - now))
        now = tick
    return track


def ramps_file() -> mido.MidiFile:
    """The sample (see the module docstring)."""
    tempo = [
        (0, mido.MetaMessage("set_tempo", tempo=500_000)),
        (TEMPO_CHANGE_TICK, mido.MetaMessage("set_tempo", tempo=1_000_000)),
        (END_TICK, mido.MetaMessage("end_of_track")),
    ]
    cc = [
        (30 * k, mido.Message("control_change", channel=0, control=7, value=k)) for k in range(128)
    ]
    cc += [
        (3840 + 15 * k, mido.Message("control_change", channel=0, control=7, value=127 - k))
        for k in range(1, 128)
    ]
    notes = []
    for on, off in ((480, 720), (2400, 2640)):
        notes.append((on, mido.Message("note_on", channel=9, note=60, velocity=100)))
        notes.append((off, mido.Message("note_on", channel=9, note=60, velocity=0)))
    notes[1] = (720, mido.Message("note_off", channel=9, note=60, velocity=64))
    mf = mido.MidiFile(type=1, ticks_per_beat=PPQN)
    mf.tracks += [_delta(tempo), _delta(cc), _delta(notes)]
    return mf


def write_samples(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "ramps.mid"
    ramps_file().save(str(path))
    return [path]


if __name__ == "__main__":
    root = Path(__file__).resolve().parents[1]
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else root / "configs" / "animations" / "midi"
    for p in write_samples(out):
        print(p)
