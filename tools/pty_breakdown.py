"""Where the demo's loop thread spends its CPU over a pty, part by part (not a test).

``python -m hilsim.bench.cpu`` (which ``hilsim bench`` runs) gives the demo's CPU per tick
over a ``hilsim emulate`` pty as a whole, counted by the scheduler. This splits the loop
thread's share: it runs ``hilsim run configs/demo.toml --port PTY`` in this process with
each part wrapped in a thread-CPU counter (``time.thread_time_ns``, this thread only):

* ``tick``: :meth:`hilsim.show.loop.HilLoop._tick`, the port's reads and writes included;
* ``  port write`` / ``  port read``: the driver's descriptor writes and reads (a read
  blocks in ``select`` until its bytes are there: its wall time is the wire's);
* ``after tick``: the end of a tick (overrun books, a health read in the spare time,
  status line);
* ``clock wait``: the sleep to the next tick and the spin window before it (the clock's
  waits inside a tick are the tick's, those before the show are left out).

and, for scale, what one bare ``time.sleep`` and its wake-up cost this thread on this
host (nothing else running in it), and what hilsim's tick costs back to back and after a
sleep, and after the same time spun in a busy loop
(:class:`hilsim.bench.tick.HilsimTick`: the bench's 4-servo rig on an instant in-process
port, no I/O; not the demo's own tick): on some hosts it costs several times as much after
a sleep, and still several times as much after a spin in C, when the CPU never idled and
this process ran nothing else: its caches taken meanwhile, most likely by work outside the
process (on a shared VM, other guests on the same core; the spin's own footprint is a few
kB).
The wrappers cost ~1 µs a call.

    python tools/pty_breakdown.py [--seconds 6]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

PARTS = (  # (label, module, owner, attribute)
    ("tick", "hilsim.show.loop", "HilLoop", "_tick"),
    ("  port write", "drivers.dynamixel.port", None, "_write_fd"),
    ("  port read", "drivers.dynamixel.port", "PortHandler", "_read_fd"),
    ("after tick", "hilsim.show.loop", "HilLoop", "_after_tick"),
    ("clock wait", "drivers.clock", "MonotonicClock", "wait_until"),
)


#: [ticks begun, inside a tick or its end]: the clock's waits count only between ticks (its
#: waits inside one, after a failed read, are the tick's; those before the show, no part)
_STATE = [0, False]


def _wrap(owner, name: str, books: list[int], label: str) -> None:
    inner = getattr(owner, name)
    cpu, wall = time.thread_time_ns, time.perf_counter_ns
    part = label != "clock wait" and not label.startswith(" ")  # the tick or its end

    def counted(*args, **kwargs):
        if label == "clock wait" and (not _STATE[0] or _STATE[1]):
            return inner(*args, **kwargs)
        if part:
            _STATE[0] += label == "tick"
            _STATE[1] = True
        c, w = cpu(), wall()
        try:
            return inner(*args, **kwargs)
        finally:
            books[0] += 1
            books[1] += cpu() - c
            books[2] += wall() - w
            if part:
                _STATE[1] = False

    setattr(owner, name, counted)


def sleep_cost(n: int = 1000, sleep_s: float = 0.0035) -> tuple[float, float]:
    """CPU of one ``time.sleep(sleep_s)`` and how late it wakes (µs, medians), with the
    thread's timer slack at 1 ns as the loop sets it."""
    from drivers.clock import PRECISE_SLACK_NS, precise_timers

    cpu, late = [], []
    with precise_timers(PRECISE_SLACK_NS):
        for _ in range(n):
            c, w = time.thread_time(), time.perf_counter()
            time.sleep(sleep_s)
            cpu.append(time.thread_time() - c)
            late.append(time.perf_counter() - w - sleep_s)
    cpu.sort(), late.sort()
    return cpu[n // 2] * 1e6, late[n // 2] * 1e6


def _spin(seconds: float) -> None:
    """Busy for ``seconds`` in C: chunks of ~20 µs of ``sum`` over ``itertools.repeat`` (no
    Python code runs in a chunk and no memory is touched), the clock read between chunks."""
    end = time.perf_counter() + seconds
    zeros = itertools.repeat
    while time.perf_counter() < end:
        sum(zeros(0, 4096))


def tick_after_sleep(
    waits=(("", 0.0), ("sleep", 0.001), ("spin", 0.001), ("sleep", 0.0035), ("spin", 0.0035)),
    n: int = 600,
) -> list[tuple]:
    """(how, wait, p10, p50, p90 of the tick's thread CPU in µs): an instant-port tick of 4
    servos after each wait, timer slack 1 ns. ``sleep``: ``time.sleep`` (the CPU may idle);
    ``spin``: the same time spent busy in C (:func:`_spin`: the CPU never idles, this process
    runs nothing else - the bench rig keeps its rows in memory, no writer thread - and the
    spin itself runs no Python and touches no memory); ``""``: back to back. A tick slower
    after a spin than back to back lost its caches, or its branch predictors' training, in
    the meantime: to the spin's few kB, the timer's interrupts, or work outside the process."""
    import tempfile

    from drivers.clock import PRECISE_SLACK_NS, precise_timers
    from hilsim.bench.tick import HilsimTick

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tick = HilsimTick(4, Path(tmp))
        try:
            for _ in range(2000):  # warm, and the ring emptied as the bench does
                tick()
            tick.between_rounds()
            for how, wait_s in waits:
                pause = {"sleep": time.sleep, "spin": _spin}.get(how)
                cpu = []
                with precise_timers(PRECISE_SLACK_NS):
                    for i in range(n):
                        if pause is not None:
                            pause(wait_s)
                        c = time.thread_time_ns()
                        tick()
                        cpu.append(time.thread_time_ns() - c)
                        if i % 200 == 199:
                            tick.between_rounds()
                cpu.sort()
                rows.append((how, wait_s, *(cpu[n * q // 10] / 1e3 for q in (1, 5, 9))))
        finally:
            tick.close()
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=6.0, help="show length (s)")
    args = ap.parse_args(argv)
    import importlib

    books: dict[str, list[int]] = {}
    for label, module, owner, attr in PARTS:
        mod = importlib.import_module(module)
        books[label] = [0, 0, 0]
        _wrap(mod if owner is None else getattr(mod, owner), attr, books[label], label)
    from hilsim.bench.cpu import emulator
    from hilsim.cli import main as hilsim_main

    with emulator() as path:
        load = os.getloadavg()
        out = io.StringIO()
        with contextlib.redirect_stderr(out), contextlib.suppress(SystemExit):
            show = ["--duration", f"{args.seconds:g}", "--no-plots"]
            hilsim_main(["run", str(REPO / "configs" / "demo.toml"), "--port", path, *show])
    ended = [line for line in out.getvalue().splitlines() if "end of show" in line]
    print(ended[0] if ended else out.getvalue()[-600:])
    ticks = books["tick"][0]
    if not ticks:
        return 1
    print(f"The demo's loop thread over {path}, per part (thread CPU; load {load[0]:.2f}):")
    print(f"  {'part':<14}{'calls':>8}{'µs CPU/call':>13}{'µs CPU/tick':>13}{'µs wall/call':>14}")
    for label, (n, cpu, wall) in books.items():
        if n:
            print(
                f"  {label:<14}{n:>8}{cpu / n / 1e3:>13.1f}{cpu / ticks / 1e3:>13.1f}"
                f"{wall / n / 1e3:>14.1f}"
            )
    total = (books["tick"][1] + books["after tick"][1] + books["clock wait"][1]) / ticks / 1e3
    print(f"  tick + after tick + clock wait: {total:.0f} µs of CPU per tick")
    cpu, late = sleep_cost()
    print(
        f"A bare 3.5 ms sleep on this host: {cpu:.0f} µs of CPU, wakes {late:.0f} µs late "
        "(medians of 1,000; timer slack 1 ns)"
    )
    for how, wait_s, p10, p50, p90 in tick_after_sleep():
        when = f"after a {wait_s * 1e3:g} ms {how}" if how else "back to back"
        print(
            f"hilsim's tick (the bench's 4-servo rig, instant port, no I/O) {when}: "
            f"{p50:.0f} µs of CPU (p10 {p10:.0f}, p90 {p90:.0f}; 600 ticks)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
