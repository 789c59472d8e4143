"""Live MIDI, MTC and takes (issue 14; not a test): what each costs the loop's tick, measured.

1. ``MidiCcInput.poll`` with 8 mapped joints: nothing due (most ticks), 1, 4 and 256 messages
   due (256 = a full default inbox, the most one poll can ever get); ``Inbox.put`` (the receiver
   thread's side).
2. ``MtcChase.poll``: nothing due, 1 quarter frame, 8 (a full code and its re-anchor).
3. ``Take.record`` per sample, and ``Take.reduce`` on 10-minute takes: a puppeteer-like curve
   (sum of sines, 7-bit MIDI steps, a sample per change of value as a fader sends them, from a
   250 Hz grid) and white noise at 250 Hz (150,001 samples; the worst case for
   Ramer-Douglas-Peucker), keys kept and time taken.

Per-call times are ``time.perf_counter_ns`` around single calls, p50 / p99 / max in µs over
``--reps`` calls, on the machine as it is (give ``cat /proc/loadavg`` beside the numbers).

    python tools/bench_live_midi.py [--reps 20000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hilsim.live.midi import CcMapping, MidiCcInput
from hilsim.live.takes import Take
from hilsim.live.timecode import MtcChase


class Msg:
    """A mido-like message without mido's per-message checks (the receiver hands mido's)."""

    __slots__ = ("channel", "control", "frame_type", "frame_value", "type", "value")

    def __init__(self, type, **kw):
        self.type = type
        for k, v in kw.items():
            setattr(self, k, v)


def stats(ns: list[int]) -> str:
    a = np.array(ns) / 1000
    return (
        f"p50 {np.percentile(a, 50):7.2f}  p99 {np.percentile(a, 99):7.2f}  max {a.max():8.2f} µs"
    )


def bench_midi(reps: int) -> None:
    maps = [CcMapping(f"j{i}", 1, i, -90, 90) for i in range(8)]
    for due in (0, 1, 4, 256):
        midi = MidiCcInput(maps, lost_after_s=1.0)
        ns, t = [], 0.0
        n = reps if due < 256 else max(reps // 50, 200)
        for k in range(n):
            for i in range(due):
                midi.feed(Msg("control_change", channel=0, control=i % 8, value=k % 128), t)
            t0 = time.perf_counter_ns()
            midi.poll(t)
            ns.append(time.perf_counter_ns() - t0)
            t += 0.004
        print(f"MidiCcInput.poll, {due:3d} due : {stats(ns)}  ({n} polls)")
    midi, ns = MidiCcInput(maps, capacity=reps + 1), []
    msg = Msg("control_change", channel=0, control=0, value=1)
    for k in range(reps):
        t0 = time.perf_counter_ns()
        midi.feed(msg, k * 1e-4)
        ns.append(time.perf_counter_ns() - t0)
    print(f"Inbox.put (receiver side) : {stats(ns)}")


def bench_mtc(reps: int) -> None:
    nibbles = [15, 0, 2, 0, 0, 0, 0, 6]  # 00:00:02:15 at 30 fps
    for due in (0, 1, 8):
        chase, ns, t, piece = MtcChase(), [], 0.0, 0
        for _ in range(reps):
            for _ in range(due):
                chase.feed(Msg("quarter_frame", frame_type=piece, frame_value=nibbles[piece]), t)
                piece = (piece + 1) % 8
            t0 = time.perf_counter_ns()
            chase.poll(t)
            ns.append(time.perf_counter_ns() - t0)
            t += 1 / 120
        print(f"MtcChase.poll, {due} due      : {stats(ns)}")


def bench_takes() -> None:
    rate, seconds = 250, 600
    t = np.arange(rate * seconds + 1) / rate
    smooth = 30 * np.sin(0.7 * t) + 12 * np.sin(2.3 * t + 1) + 5 * np.sin(5.1 * t)
    midi7 = np.round((smooth + 47) / 94 * 127) / 127 * 94 - 47  # 7-bit fader steps
    noise = np.random.default_rng(1).uniform(-30, 30, len(t))
    take = Take(["a"])
    t0 = time.perf_counter()
    for ti, v in zip(t.tolist(), midi7.tolist(), strict=True):
        take.record(ti, "a", v)
    per = (time.perf_counter() - t0) / len(t) * 1e6
    print(f"Take.record               : {per:.2f} µs per sample (mean of {len(t)})")
    sent = np.flatnonzero(np.diff(midi7, prepend=np.inf))  # a fader sends on change only
    cases = (
        ("puppeteer-like, 7-bit", t[sent], midi7[sent]),
        ("white noise +-30 deg", t, noise),
    )
    for name, ts, v in cases:
        take = Take(["a"])
        take.record_samples(zip(ts.tolist(), ["a"] * len(ts), v.tolist(), strict=True))
        for tol in (0.5, 0.1):
            t0 = time.perf_counter()
            reduced = take.reduce(tol)
            dt = time.perf_counter() - t0
            n_keys = len(reduced.keys("a"))
            err = reduced.max_error_deg["a"]
            print(
                f"Take.reduce {name:22s} tol {tol}: {dt:6.2f} s, {len(ts)} samples -> "
                f"{n_keys} keys, max error {err:.3f} deg"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=20000)
    args = ap.parse_args()
    with open("/proc/loadavg") as f:
        print("load:", f.read().strip())
    bench_midi(args.reps)
    bench_mtc(args.reps)
    bench_takes()
    with open("/proc/loadavg") as f:
        print("load:", f.read().strip())


if __name__ == "__main__":
    main()
