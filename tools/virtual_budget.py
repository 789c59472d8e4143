"""Where a virtual-time rehearsal's wall time goes, and what each part's absence would
leave (issue 12, item 3; not a test).

Runs ``hilsim run RIG --virtual-time --no-plots`` in this process, ``--repeats`` times,
and for each run prints:

* the show's wall time and pace as ``hilsim run`` reports them (first tick to end);
* ``emulator``: wall time inside the emulated bus (:class:`drivers.dxlsim.bus.DxlBus`
  ``write`` and ``read``: the servos, their replies and the adapter's timing), less the
  wrapper's own cost, measured on a no-op beforehand;
* the tick's stages as the run's telemetry recorded them (``t_sim_us`` … summed: the bus
  stage holds the driver's packet code, the port and the emulator's share of it);
* ``writer thread``: the telemetry writer's own CPU (it runs beside the loop, sharing the
  interpreter's lock);
* estimates of the pace with a part taken out (its time subtracted; no interaction
  counted): no emulator, no bus stage at all.

    python tools/virtual_budget.py [--rig configs/demo.toml] [--repeats 3]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
import re
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

STAGES = ("t_sim_us", "t_safety_us", "t_bus_us", "t_telemetry_us")


def _wrap(owner, name: str, book: list[float]) -> None:
    orig = getattr(owner, name)
    clock = time.perf_counter

    def timed(*args, **kwargs):
        t = clock()
        try:
            return orig(*args, **kwargs)
        finally:
            book[0] += clock() - t
            book[1] += 1

    setattr(owner, name, timed)


def _wrapper_cost(n: int = 200_000) -> float:
    """Seconds one wrapped call adds over the plain one (median of 5)."""

    class Plain:
        def f(self):
            return None

    class Wrapped(Plain):
        pass

    Wrapped.f = Plain.f
    _wrap(Wrapped, "f", [0.0, 0])
    costs = []
    for _ in range(5):
        took = []
        for obj in (Plain(), Wrapped()):
            t = time.perf_counter()
            for _ in range(n):
                obj.f()
            took.append(time.perf_counter() - t)
        costs.append((took[1] - took[0]) / n)
    costs.sort()
    return costs[len(costs) // 2]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rig", default=str(REPO / "configs" / "demo.toml"))
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    per_call = _wrapper_cost()
    from drivers.dxlsim.bus import DxlBus
    from hilsim.cli import main as hilsim_main
    from hilsim.telemetry.writer import TelemetryWriter

    emu = [0.0, 0]
    _wrap(DxlBus, "write", emu)
    _wrap(DxlBus, "read", emu)
    writer_cpu = [0.0]
    run = TelemetryWriter._run

    def counted_run(self, *a, **k):
        c = time.thread_time()
        try:
            return run(self, *a, **k)
        finally:
            writer_cpu[0] += time.thread_time() - c

    TelemetryWriter._run = counted_run
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"{args.rig} in virtual time, {args.repeats} runs; load average {load}")
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeats):
            emu[:] = [0.0, 0]
            writer_cpu[0] = 0.0
            out = io.StringIO()
            with contextlib.redirect_stderr(out), contextlib.suppress(SystemExit):
                run_dir = Path(tmp) / f"run{k}"
                hilsim_main(
                    ["run", args.rig, "--virtual-time", "--no-plots", "--out", str(run_dir)]
                )
            text = out.getvalue()
            m = re.search(r"after (\d+) ticks \(([\d.]+) s of show in ([\d.]+) s", text)
            if m is None:
                print(text[-800:])
                return 1
            ticks, show_s, wall = int(m[1]), float(m[2]), float(m[3])
            for t in threading.enumerate():  # the writer has finished its books at close
                if t.name == "telemetry-writer":
                    t.join(5.0)
            sums = dict.fromkeys(STAGES, 0.0)
            with (run_dir / "telemetry.csv").open(newline="") as f:
                for row in csv.DictReader(f):
                    for s in STAGES:
                        sums[s] += float(row[s]) / 1e6
            emulator = emu[0] - emu[1] * per_call
            us = 1e6 / ticks
            print(
                f"run {k + 1}: {ticks} ticks, {show_s:g} s of show in {wall:.2f} s "
                f"({show_s / wall:.0f}× real time, {wall * us:.0f} µs a tick)"
            )
            stages = ", ".join(f"{s[2:-3]} {sums[s] * us:.0f}" for s in STAGES)
            print(f"  tick stages, µs a tick: {stages} (sum {sum(sums.values()) * us:.0f})")
            print(
                f"  emulator: {emulator * us:.0f} µs a tick ({emu[1] / ticks:.1f} calls, "
                f"{per_call * 1e6:.2f} µs wrapper cost taken off each); writer thread "
                f"{writer_cpu[0] * us:.0f} µs of CPU a tick"
            )
            rest = wall - emulator
            no_bus = wall - sums["t_bus_us"]
            print(
                f"  taken out (estimates): the emulator -> {rest:.2f} s, "
                f"{show_s / rest:.0f}×; the whole bus stage -> {no_bus:.2f} s, "
                f"{show_s / no_bus:.0f}×"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
