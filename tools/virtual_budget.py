"""Where a virtual-time rehearsal's wall time goes, and what the emulator's absence would
leave (issue 12, item 3; not a test).

Runs ``hilsim run RIG --virtual-time --no-plots`` (one bus) in this process ``--repeats``
times and prints, for each run, from its ``summary.json`` and the counters below:

* the show's wall time (``wall_s``: the loop's start, ticks and exit policy) and pace;
* the tick's stages, their mean times the ticks (wall time: the telemetry writer's turns
  on the interpreter lock, taken in the middle of a stage, are inside them);
* ``emulator``: the loop thread's own CPU inside the emulated bus (``DxlBus.write`` and
  ``read``: the servos, their replies, the adapter's timing), less what the counter itself
  adds inside its window (measured on a wrapped no-op); the port's calls around the bus
  (``visible_at``, the unplug check, the clock) are not in it;
* ``writer thread``: the telemetry writer's own CPU, the show's end (drain, fsync) included;
* an estimate of the pace with the emulator's CPU (and the counters' own wall time, measured
  on the no-op) taken out of the wall time, nothing else changed: a free emulator would
  also leave the caches warmer, which this does not count.

    python tools/virtual_budget.py [--rig configs/demo.toml] [--repeats 3] [--duration S]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _wrap(owner, name: str, book: list[int]) -> None:
    """Count the calling thread's CPU (ns) and the calls of ``owner.name`` in ``book``."""
    orig = getattr(owner, name)
    cpu = time.thread_time_ns

    def timed(*args, **kwargs):
        t = cpu()
        try:
            return orig(*args, **kwargs)
        finally:
            book[0] += cpu() - t
            book[1] += 1

    setattr(owner, name, timed)


def _counter_cost(n: int = 100_000) -> tuple[float, float]:
    """What the counter costs a call of a function that does nothing (medians of 5): the
    thread CPU it books inside its own window (ns), and the wall time it adds in all (s)."""

    class Plain:
        def f(self):
            return None

    class Counted(Plain):
        pass

    Counted.f = Plain.f
    _wrap(Counted, "f", book := [0, 0])
    inside, added = [], []
    for _ in range(5):
        book[:] = [0, 0]
        took = []
        for obj in (Plain(), Counted()):
            t = time.perf_counter()
            for _ in range(n):
                obj.f()
            took.append(time.perf_counter() - t)
        inside.append(book[0] / n)
        added.append((took[1] - took[0]) / n)
    return sorted(inside)[2], sorted(added)[2]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rig", default=str(REPO / "configs" / "demo.toml"))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--duration", help="seconds of show (default: the rig's own)")
    args = ap.parse_args(argv)
    per_call, added = _counter_cost()
    from drivers.dxlsim.bus import DxlBus
    from hilsim.cli import main as hilsim_main
    from hilsim.telemetry.writer import TelemetryWriter

    emu = [0, 0]
    _wrap(DxlBus, "write", emu)
    _wrap(DxlBus, "read", emu)
    writer = [0, 0]
    _wrap(TelemetryWriter, "_run", writer)  # the writer thread's target: its whole life
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"{args.rig} in virtual time, {args.repeats} runs; load average {load}")
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeats):
            emu[:], writer[:] = [0, 0], [0, 0]
            run_dir = Path(tmp) / f"run{k}"
            out = io.StringIO()
            with contextlib.redirect_stderr(out), contextlib.suppress(SystemExit):
                more = ["--duration", args.duration] if args.duration else []
                hilsim_main(
                    ["run", args.rig, "--virtual-time", "--no-plots", "--out", str(run_dir), *more]
                )
            try:
                summary = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
                ticks, wall, show_s = summary["ticks"], summary["wall_s"], summary["duration_s"]
                stages = {n: v["mean"] * ticks / 1e6 for n, v in summary["stage_us"].items()}
            except (OSError, ValueError, KeyError, TypeError):
                print(f"no single-bus summary in {run_dir}; the run said:\n{out.getvalue()[-800:]}")
                return 1
            us = 1e6 / ticks
            emulator = (emu[0] - emu[1] * per_call) / 1e9
            print(
                f"run {k + 1}: {ticks} ticks, {show_s:.2f} s of show in {wall:.3f} s "
                f"({show_s / wall:.1f}× real time, {wall * us:.0f} µs a tick)"
            )
            parts = ", ".join(f"{name} {t * us:.0f}" for name, t in stages.items())
            print(f"  tick stages, µs a tick (wall): {parts} (sum {sum(stages.values()) * us:.0f})")
            print(
                f"  emulator: {emulator * us:.0f} µs of the loop thread's CPU a tick "
                f"({emu[1] / ticks:.1f} calls, {per_call / 1e3:.2f} µs counter cost taken off "
                f"each; {added * 1e6:.2f} µs of wall a call in all); writer thread "
                f"{writer[0] / 1e9 * us:.0f} µs of CPU a tick"
            )
            counters = (emu[1] + writer[1]) * added  # the counters' own wall time
            rest = wall - counters - emulator
            print(
                f"  the counters' time and the emulator's CPU taken out (an estimate): {rest:.3f} "
                f"s, {show_s / rest:.1f}× real time"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
