"""Telemetry at scale (issue 12, item 5; not a test): size, writer CPU and the loop's lateness.

Three parts, each format in turn (``csv``, ``csv.gz``, ``parquet``):

1. **Size and CPU.** A show's rows (default 10 minutes at 1 kHz, 16 joints) go through the real
   :class:`~hilsim.telemetry.TelemetryWriter` (``record`` as the loop calls it, ``overflow=
   "block"`` as in virtual time, so the writer runs flat out; an fsync point every 2 s of show,
   as the writer makes on the real clock, so Parquet parts are as small as in a real run).
   Printed: the rows' bytes on disk, the writer thread's CPU (its own thread CPU clock) per
   second of show, and the worst error of read-back values against what was recorded
   (``read_run``).
2. **Lateness.** A loop-like thread on the real clock (``MonotonicClock.wait_until`` with the
   writer's ``slack``, the GIL switch interval the loop sets, a tick of fixed Python work as
   long as scale16's measured host+bus time, ``record`` + ``amend`` every tick) for
   ``--seconds``, first with no writer at all (the host's own noise), then with each format.
   Printed: lateness p50 / p99 / max, and how far the tick's fixed work was stretched (the
   GIL taken away mid-tick) p99 / max, in µs, and overruns.
3. **GIL.** The writer unleashed (never waiting for the loop's sleep, as in virtual time), its
   thread under a profile hook: the longest C call it made (an upper bound on one hold of the
   GIL: numpy, zlib and pyarrow release it inside long calls) and the longest CSV formatting
   pass (one ``%`` over a chunk of rows, which holds it throughout), both in the thread's CPU
   time (waiting for the GIL or the OS does not count; waits - queue, event, sleep, fsync - are
   left out). Between calls the GIL changes hands within the switch interval the loop sets
   (100 µs). Timings under the hook are a little longer than without.

The signals are scale16's: each joint a 30° sine of its own period (0.5 Hz, 0.4444 Hz, ...)
through a 4 Hz spring (a phase lag), the command equal to the spring, the present position the
command a tick late in whole servo ticks, stage times and lateness with the spread a real-clock
scale16 run showed; ``--replay RUN_DIR`` uses a recorded run's rows instead (e.g. from
``hilsim run configs/scale16.toml --duration 12``, real clock), repeated to the show's length.

    python tools/bench_telemetry.py [--show-s 600] [--seconds 20] [--joints 16] [--rate 1000]
                                    [--formats csv,csv.gz,parquet] [--busy-us 700]
                                    [--replay RUN_DIR] [--skip-size] [--skip-lateness]
                                    [--skip-gil]
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.clock import MonotonicClock
from hilsim.show.realtime import REALTIME_SWITCH_INTERVAL_S
from hilsim.telemetry import TelemetryWriter, read_run
from hilsim.telemetry.format import STAGES, TelemetryFormat, TickRecord
from hilsim.telemetry.sinks import rows_path

TICK_RAD = 2 * math.pi / 4096


class Signals:
    """scale16-like rows, made a block at a time with numpy, handed out one tick at a time."""

    def __init__(self, n_joints: int, rate_hz: float, seed: int = 1) -> None:
        self.n, self.rate = n_joints, rate_hz
        self.freq = 0.5 * 0.9 ** np.arange(n_joints) + 0.05 * (np.arange(n_joints) % 3)
        self.rng = np.random.default_rng(seed)
        self.block = np.zeros(5 * n_joints)
        views = [self.block[k * n_joints : (k + 1) * n_joints] for k in range(5)]
        self.rec = TickRecord(*views, status=np.zeros(n_joints, dtype=np.uint8))
        self.rec.joint_block = self.block

    def chunk(self, k0: int, count: int) -> dict:
        k = np.arange(k0, k0 + count)
        t = k / self.rate
        w = 2 * math.pi * self.freq
        amp = math.radians(30)
        lag = np.arctan2(2 * 0.8 * w / (2 * math.pi * 4.0), 1 - (w / (2 * math.pi * 4.0)) ** 2)
        gain = 1 / np.hypot(1 - (w / 8 / math.pi) ** 2, 2 * 0.8 * w / 8 / math.pi)
        target = amp * np.sin(np.outer(t, w))
        sim_x = amp * gain * np.sin(np.outer(t, w) - lag)
        sim_v = amp * gain * w * np.cos(np.outer(t, w) - lag)
        prev = amp * gain * np.sin(np.outer(t - 1 / self.rate, w) - lag)
        present = np.round(prev / TICK_RAD) * TICK_RAD
        rng = self.rng
        late = np.where(rng.random(count) < 0.01, rng.exponential(300, count), 0.05)
        return {
            "k0": k0,
            "block": np.hstack([target, sim_x, sim_v, sim_x, present]),
            "t_actual": t + late * 1e-6,
            "stages": np.column_stack(
                [
                    rng.lognormal(math.log(37), 0.12, count),
                    rng.lognormal(math.log(15.5), 0.1, count),
                    rng.lognormal(math.log(733), 0.05, count),
                    rng.lognormal(math.log(12.4), 0.1, count),
                ]
            ),
        }

    def fill(self, c: dict, i: int, k: int) -> TickRecord:
        rec = self.rec
        self.block[:] = c["block"][i]
        rec.tick, rec.t_sched, rec.t_actual = k, k / self.rate, float(c["t_actual"][i])
        s = c["stages"][i]
        rec.t_sim_us, rec.t_safety_us, rec.t_bus_us, rec.t_telemetry_us = map(float, s)
        return rec


class Replay(Signals):
    """A recorded run's rows (``--replay RUN_DIR``: e.g. scale16 on the real clock), over and over,
    the tick and times continued."""

    def __init__(self, run_dir: str, rate_hz: float) -> None:
        run = read_run(run_dir)
        super().__init__(len(run.joint_names), rate_hz)
        self.names = run.joint_names
        fields = ("target", "sim_x", "sim_v", "cmd", "present")
        self.blocks = np.hstack([run.joint(f) for f in fields])
        self.status = run.joint("status").astype(np.uint8)
        self.late = run.columns["lateness_us"]
        self.stages = np.column_stack([run.stage_us(s) for s in STAGES])

    def chunk(self, k0: int, count: int) -> dict:
        at = np.arange(k0, k0 + count) % len(self.blocks)
        t = np.arange(k0, k0 + count) / self.rate
        return {
            "k0": k0,
            "block": self.blocks[at],
            "status": self.status[at],
            "t_actual": t + self.late[at] * 1e-6,
            "stages": self.stages[at],
        }

    def fill(self, c: dict, i: int, k: int) -> TickRecord:
        self.rec.status[:] = c["status"][i]
        return super().fill(c, i, k)


def _thread_cpu(thread: threading.Thread) -> float:
    assert thread.ident is not None
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


def _bytes(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir())
    return path.stat().st_size


def size_and_cpu(fmt: str, args: argparse.Namespace, root: Path) -> None:
    run = root / f"size-{fmt}"
    sig = Replay(args.replay, args.rate) if args.replay else Signals(args.joints, args.rate)
    n_rows = round(args.show_s * args.rate)
    names = getattr(sig, "names", [f"j{i:02d}" for i in range(1, sig.n + 1)])
    w = TelemetryWriter(run, names, overflow="block", format=fmt)
    keep_every = max(1, n_rows // 20_000)
    sync_rows = round(w.fsync_interval_s * args.rate)
    kept: list[tuple[int, np.ndarray]] = []
    t0 = time.perf_counter()
    for k0 in range(0, n_rows, 1000):
        c = sig.chunk(k0, min(1000, n_rows - k0))
        for i in range(len(c["block"])):
            w.record(sig.fill(c, i, k0 + i))
            if (k0 + i) % keep_every == 0:
                kept.append((k0 + i, c["block"][i].copy()))
            if (k0 + i + 1) % sync_rows == 0:
                w.flush(timeout_s=None)  # an fsync point, as a real-time run has every 2 s
    w.flush(timeout_s=None)
    cpu = _thread_cpu(w._thread)
    wall = time.perf_counter() - t0
    summary = w.close({})
    size = _bytes(rows_path(run, TelemetryFormat(fmt)))
    back = read_run(run)
    n = sig.n
    cols = np.column_stack([back.joint(q) for q in ("target", "sim_x", "sim_v", "cmd", "present")])
    ticks, want = zip(*kept, strict=True)
    err = np.abs(cols[list(ticks)] - np.array(want))
    ang = np.nanmax(np.delete(err, np.s_[2 * n : 3 * n], axis=1))
    vel = np.nanmax(err[:, 2 * n : 3 * n])
    t_err = np.abs(back.t_sched - np.arange(back.n_ticks) / args.rate).max()
    per_10 = size / args.show_s * 600 / 1e6
    print(
        f"{fmt:8s} {n_rows:>8,} rows  {size / 1e6:8.1f} MB ({per_10:7.1f} MB per 10 min, "
        f"{size / n_rows:6.1f} B/row)  writer CPU {cpu / args.show_s * 1e3:6.1f} ms per s of show"
        f" ({cpu / n_rows * 1e6:5.1f} us/row)  wall {wall:5.1f} s  rows written "
        f"{summary['telemetry']['rows_written']:,}  max error: angle {ang:.1e} rad, "
        f"velocity {vel:.1e} rad/s, t_sched {t_err:.1e} s",
        flush=True,
    )
    shutil.rmtree(run)


def _work(n: int) -> int:
    x = 0
    for i in range(n):
        x += i & 7
    return x


def lateness(fmt: str | None, args: argparse.Namespace, root: Path, iters: int) -> None:
    run = root / f"late-{fmt}"
    sig = Signals(args.joints, args.rate, seed=2)
    w = None
    if fmt is not None:
        names = [f"j{i:02d}" for i in range(1, args.joints + 1)]
        w = TelemetryWriter(run, names, format=fmt)
    slack = w.slack if w is not None else None
    clock = MonotonicClock()
    period = 1.0 / args.rate
    n = round(args.seconds * args.rate)
    late = np.empty(n)
    stretch = np.empty(n)
    overruns = 0
    switch = sys.getswitchinterval()
    sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)
    ticks = 0
    try:
        t0 = clock.now() + 0.01
        c = sig.chunk(0, 1000)
        k = 0
        while k < n:
            if k // 1000 != c["k0"] // 1000:
                c = sig.chunk(k - k % 1000, 1000)
            t_sched = t0 + k * period
            t_act = clock.wait_until(t_sched, slack)
            late[ticks] = t_act - t_sched
            a = time.perf_counter()
            _work(iters)  # the tick's host + bus time, as fixed Python work
            stretch[ticks] = time.perf_counter() - a
            ticks += 1
            over = time.perf_counter() > t_sched + period
            if w is not None:
                rec = sig.fill(c, k % 1000, k)
                w.record(rec)
                rec.overrun = over
                w.amend(rec)
            overruns += over
            # the loop's catch-up: the next tick is the next deadline still in the future
            k = max(k + 1, math.ceil((clock.now() - t0) / period))
    finally:
        sys.setswitchinterval(switch)
        cpu = ""
        if w is not None:
            cpu = f" | writer CPU {_thread_cpu(w._thread) / args.seconds * 1e3:5.1f} ms/s"
            w.close({})
            shutil.rmtree(run, ignore_errors=True)
    late, stretch = late[:ticks], stretch[:ticks]
    base = np.median(stretch)
    lat_us, st_us = late * 1e6, (stretch - base) * 1e6
    print(
        f"{fmt or 'none':8s} lateness p50 {np.median(lat_us):5.1f} p99 "
        f"{np.percentile(lat_us, 99):7.1f} max {lat_us.max():8.1f} us, > 200 us: "
        f"{(lat_us > 200).sum():5d} | tick work stretched "
        f"p99 {np.percentile(st_us, 99):6.1f} max {st_us.max():8.1f} us | overruns "
        f"{overruns} / {ticks}{cpu} | load {os.getloadavg()[0]:.2f}",
        flush=True,
    )


#: calls that wait with the GIL released (a queue, an event, a sleep, an fsync) or happen once
_WAITS = frozenset(
    {"get", "wait", "acquire", "sleep", "fsync", "sched_yield", "__import__", "exec"}
)


class _Longest:
    """A profile hook on the writer thread: the longest C call it made (numpy, pyarrow, zlib,
    str.join, file writes; the GIL is held for at most that long unless the call releases it)
    and the longest CSV formatting pass (the ``%`` of one chunk of rows: one bytecode, GIL held
    throughout)."""

    def __init__(self) -> None:
        self.c_call = (0.0, "")
        self.formats: list[float] = []
        self.active = True  # False once the show is over (close: the summary's statistics)
        self._c: dict = {}
        self._fmt_at = 0.0

    def __call__(self, frame, event: str, arg) -> None:
        if not self.active:
            return
        t = time.thread_time()  # the thread's CPU: waiting (for the GIL too) does not count
        if event == "c_call":
            self._c[id(arg)] = t
        elif event in ("c_return", "c_exception"):
            t0 = self._c.pop(id(arg), None)
            name = getattr(arg, "__name__", "")
            if t0 is not None and t - t0 > self.c_call[0] and name not in _WAITS:
                qual = getattr(arg, "__qualname__", None) or name
                self.c_call = (t - t0, f"{getattr(arg, '__module__', None) or ''}.{qual}")
        elif frame.f_code.co_name == "<listcomp>" and frame.f_code.co_filename.endswith("sinks.py"):
            if event == "call":
                self._fmt_at = t
            elif event == "return":
                self.formats.append(t - self._fmt_at)


def gil_holds(fmt: str, args: argparse.Namespace, root: Path) -> None:
    """The writer unleashed (its ``slack`` always set, as in virtual time) on ``--seconds`` of
    rows, its thread profiled (:class:`_Longest`)."""
    run = root / f"gil-{fmt}"
    sig = Signals(args.joints, args.rate, seed=3)
    probe = _Longest()
    threading.setprofile(probe)  # threads started from now on: the writer's
    try:
        names = [f"j{i:02d}" for i in range(1, args.joints + 1)]
        w = TelemetryWriter(run, names, format=fmt, overflow="block")
    finally:
        threading.setprofile(None)  # type: ignore[arg-type]
    w.slack.until = math.inf  # never gated: formats whenever it has rows
    n = round(args.seconds * args.rate)
    for k0 in range(0, n, 1000):
        c = sig.chunk(k0, 1000)
        for i in range(1000):
            w.record(sig.fill(c, i, k0 + i))
        if (k0 + 1000) % round(w.fsync_interval_s * args.rate) == 0:
            w.flush(timeout_s=None)  # an fsync point (a Parquet part), as every 2 s
    w.flush(timeout_s=None)
    probe.active = False
    w.close({})
    shutil.rmtree(run, ignore_errors=True)
    dt, name = probe.c_call
    fmt_text = ""
    if probe.formats:
        f_us = np.array(probe.formats) * 1e6
        fmt_text = (
            f"; CSV formatting passes: p50 {np.median(f_us):5.1f}, p99.9 "
            f"{np.percentile(f_us, 99.9):6.1f}, max {f_us.max():6.1f} us"
        )
    print(
        f"{fmt:8s} longest C call {dt * 1e6:7.1f} us ({name}){fmt_text}"
        f" | load {os.getloadavg()[0]:.2f}",
        flush=True,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--show-s", type=float, default=600.0, help="show length for part 1 (s)")
    ap.add_argument("--seconds", type=float, default=20.0, help="real time per format, part 2")
    ap.add_argument("--joints", type=int, default=16)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--formats", default="csv,csv.gz,parquet")
    ap.add_argument("--busy-us", type=float, default=700.0, help="the tick's work, part 2 (us)")
    ap.add_argument("--replay", metavar="RUN_DIR", help="part 1: a recorded run's rows instead")
    ap.add_argument("--skip-size", action="store_true")
    ap.add_argument("--skip-lateness", action="store_true")
    ap.add_argument("--skip-gil", action="store_true")
    args = ap.parse_args()
    formats = [f for f in args.formats.split(",") if f]
    for f in formats:
        TelemetryFormat(f)
    print(f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {args.joints} joints at "
          f"{args.rate:g} Hz")  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="bench_telemetry-") as tmp:
        root = Path(tmp)
        if not args.skip_size:
            print(f"-- size and writer CPU: {args.show_s:g} s of show through the writer")
            for f in formats:
                size_and_cpu(f, args, root)
        if not args.skip_lateness:
            iters, best = 20_000, math.inf
            for _ in range(20):  # the quickest of several: the work's own cost, not the noise
                a = time.perf_counter()
                _work(iters)
                best = min(best, time.perf_counter() - a)
            iters = max(1, round(iters * args.busy_us * 1e-6 / best))
            print(f"-- lateness: a {args.rate:g} Hz loop-like thread, {args.busy_us:g} us of "
                  f"work a tick, {args.seconds:g} s per line")  # fmt: skip
            for f in [None, *formats]:
                lateness(f, args, root, iters)
        if not args.skip_gil:
            print(f"-- GIL: the writer thread profiled on {args.seconds:g} s of rows")
            for f in formats:
                gil_holds(f, args, root)
    print(f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
