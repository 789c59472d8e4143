"""The scale rig on the real clock (issue 12, item 4; a benchmark, not a test).

Runs ``hilsim run RIG --duration N`` (default ``configs/scale16.toml``: 16 joints at 1 kHz on
one 4 Mbit/s bus, Fast Sync Read) as a child process on the emulator's real clock and prints,
with the load average before and after:

* overruns / ticks, lateness p50 / p99 / max (µs), host stalls (count, max ms);
* the child's CPU (user + sys from ``os.wait4``'s rusage): µs per tick and % of one core;
* the stage p50s of ``summary.json`` (sim, safety, bus, telemetry; µs);
* in ``pty`` mode the emulator is ``hilsim emulate`` on a pseudo-terminal, another process
  (as a real adapter would be): its CPU is read from ``/proc/PID/stat`` and printed apart;
* overrun episodes: runs of consecutive overruns counted once (one late wake-up of ~0.5 ms
  makes several: a tick leaves ~0.25 ms of its period to catch up with);
* ``--host-check``: then ``cyclictest`` (Debian's rt-tests; C, memory locked, SCHED_FIFO at
  ``--set loop.realtime_priority`` or 80, on ``--set loop.cpu`` or the last CPU) for as long,
  on the same host: how often the host itself wakes a real-time thread later than this rig's
  spare time (the runs are not at the same time: the host's noise comes and goes).
* ``--alongside SPARE_US``: ``cyclictest`` in the same minute, beside the run: one thread
  per CPU (``-S -d 0``, 1 kHz, SCHED_FIFO 80, memory locked, ``--default-system``: the host's
  power settings left as the show has them), each wake-up at least SPARE_US late recorded
  with its time (``--spike``, CLOCK_MONOTONIC, the loop's clock too). Printed beside the
  loop's overrun episodes: how many began within a tick of such a wake-up (on the loop's
  CPU when ``loop.cpu`` pins it, else on any) and how many did not: the loop's own, or the
  host's on a CPU where no cyclictest thread was waiting. Alongside rather than interleaved:
  the host's noise comes and goes within a minute (counts taken a minute apart disagreed by
  2-10x), so only the same instants answer whether an episode was the host's; the cost is
  two threads that preempt whatever runs for a few µs a millisecond each.

Diagnosis knobs (each run is one child; nothing in the shipped code changes):

* ``--gc freeze|disable|gen0=N``: the child runs ``gc.freeze()`` / ``gc.disable()`` /
  ``gc.set_threshold(N)`` before ``hilsim.cli.main`` (a garbage collection of a big heap in a
  tick is one suspect for a late tick);
* ``--set loop.spin_us=500`` (repeatable): the rig with that key changed, in a copy.

    python tools/bench_scale.py [--seconds 60] [--mode inproc|pty|both] [--repeat 2]
        [--gc freeze] [--set loop.spin_us=300] [--rig configs/scale16.toml] [--json FILE]
        [--alongside 250]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PRELUDE = {
    "none": "",
    "freeze": "import gc; gc.collect(); gc.freeze()",
    "disable": "import gc; gc.disable()",
}
#: diagnosis only: take a suspect out of the child (the shipped code is unchanged)
DIAG = {
    # the telemetry writer takes its rows from the ring and discards them (no %.17g formatting)
    "no-format": """
import hilsim.telemetry.writer as _w
def _drain(self):
    while self._ring.pending() > 0:
        self.rows_written += len(self._ring.take(self._chunk_rows))
_w.TelemetryWriter._drain_rows = _drain
""",
    # the writer takes no rows at all while the show runs (they are dropped, counted): is
    # its work in the loop's free time what makes a tick late?
    "writer-idle": """
import hilsim.telemetry.writer as _w
_w.TelemetryWriter._drain_rows = lambda self: False
""",
    # no health reads in the ticks' spare time
    "no-health": """
import hilsim.show.servo_watch as _sw
_sw.ServoWatch.maybe_read_health = lambda self, *a: None
""",
}
#: the child: the prelude, a timer on every garbage collection (printed at exit), hilsim run
CHILD = """import sys; {prelude}
import atexit, gc, json, time
_gc, _t = {{}}, [0.0]
def _cb(phase, info):
    if phase == "start":
        _t[0] = time.perf_counter()
    else:
        n, worst, total = _gc.get(info["generation"], (0, 0.0, 0.0))
        dt = time.perf_counter() - _t[0]
        _gc[info["generation"]] = (n + 1, max(worst, dt), total + dt)
gc.callbacks.append(_cb)
atexit.register(lambda: print("GC " + json.dumps(_gc), file=sys.stderr))
from hilsim.cli import main
sys.exit(main(sys.argv[1:]))
"""


def loadavg() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def proc_cpu_s(pid: int) -> float:
    """user + sys CPU seconds of a running process (``/proc/PID/stat`` fields 14, 15)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def tuned_rig(rig: Path, sets: list[str], out: Path) -> Path:
    """A copy of the rig with ``section.key=value`` lines set (added under ``[section]``)."""
    if not sets:
        return rig
    text = rig.read_text()
    for item in sets:
        dotted, value = item.split("=", 1)
        section, key = dotted.split(".", 1)
        pattern = re.compile(rf"^{re.escape(key)}\s*=.*$", re.M)
        head = text.index(f"[{section}]")
        end = text.find("\n[", head + 1)
        end = len(text) if end < 0 else end
        block = text[head:end]
        if pattern.search(block):
            block = pattern.sub(f"{key} = {value}", block, count=1)
        else:
            block = block.replace(f"[{section}]", f"[{section}]\n{key} = {value}", 1)
        text = text[:head] + block + text[end:]
    copy = out / rig.name
    copy.write_text(text.replace('"demo_animation.csv"', f'"{rig.parent}/demo_animation.csv"'))
    return copy


def start_emulator(rig_text: str) -> tuple[subprocess.Popen, str]:
    """``hilsim emulate`` with the rig's ids, model and baud; returns (process, pty path)."""
    port = re.search(r'port\s*=\s*"dxlsim://\?([^"]*)"', rig_text)
    if port is None:
        raise SystemExit("--mode pty needs a rig whose bus.port is a dxlsim:// URL")
    keys = dict(kv.split("=", 1) for kv in port.group(1).split("&"))
    cmd = [sys.executable, "-m", "hilsim", "emulate", "--ids", keys.get("ids", "1-4")]
    for key, flag in (("model", "--model"), ("baud", "--baud"), ("rdt_us", "--rdt-us")):
        if key in keys:
            cmd += [flag, keys[key]]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20.0)
    line = proc.stdout.readline().strip() if ready else ""
    if not line.startswith("/dev/"):
        proc.terminate()
        raise SystemExit(f"hilsim emulate did not print a pty path: {line!r}")
    return proc, line


def run_once(
    rig: Path,
    seconds: float,
    mode: str,
    gc_mode: str,
    diag: list[str],
    tmp: Path,
    n: int,
    alongside: float | None = None,
) -> dict:
    run_dir = tmp / f"run-{mode}-{n}"
    if gc_mode.startswith("gen0="):
        prelude = f"import gc; gc.set_threshold({int(gc_mode[5:])})"
    else:
        prelude = PRELUDE[gc_mode]
    prelude += "".join(DIAG[d] for d in diag)
    argv = ["run", str(rig), "--duration", str(seconds), "--out", str(run_dir), "--no-plots"]
    emu, emu_cpu0 = None, 0.0
    if mode == "pty":
        emu, pty = start_emulator(rig.read_text())
        emu_cpu0 = proc_cpu_s(emu.pid)
        argv += ["--port", pty]
    load_before = loadavg()
    code_text = CHILD.format(prelude=prelude)
    beside = None if alongside is None else start_alongside(seconds + 5.0, alongside)
    t0 = time.perf_counter()
    try:
        child = subprocess.Popen(
            [sys.executable, "-c", code_text, *argv],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        err = child.stderr.read().decode()
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - t0
        emu_cpu = proc_cpu_s(emu.pid) - emu_cpu0 if emu is not None else None
    finally:
        if emu is not None:
            emu.terminate()
            emu.wait(10)
        spikes = None if beside is None else stop_alongside(beside)
    code = os.waitstatus_to_exitcode(status)
    gc_line = [ln for ln in err.splitlines() if ln.startswith("GC ")]
    gc_stats = json.loads(gc_line[-1][3:]) if gc_line else {}
    group = run_dir / "buses.json"  # several buses: one child process each, RUN/<bus>/
    buses = [b["bus"] for b in json.loads(group.read_text())["buses"]] if group.exists() else [""]
    if group.exists():  # the timer ran in the parent only: its numbers are not the loops'
        gc_stats = {}
    summaries = {}
    for bus in buses:
        path = run_dir / bus / "summary.json"
        if not path.exists():
            raise SystemExit(f"hilsim run exited {code} without {path}:\n{err}")
        summaries[bus] = json.loads(path.read_text())
    episodes = {bus: overrun_episodes(run_dir / bus) for bus in buses}
    same_minute = {
        bus: None if spikes is None else coincide(run_dir / bus, summaries[bus], spikes, rig)
        for bus in buses
    }
    cpu = usage.ru_utime + usage.ru_stime  # the child and every process it waited for
    most_ticks = max(int(s.get("ticks") or 0) for s in summaries.values())
    rows = []
    for bus, s in summaries.items():
        stalls = (s.get("loop") or {}).get("host_stalls") or {}
        rows.append(
            {
                "mode": mode,
                "bus": bus,
                "gc": gc_mode,
                "diag": diag,
                "exit_code": code,
                "ticks": int(s.get("ticks") or 0),
                "overruns": s.get("overruns"),
                "overrun_episodes": episodes[bus],
                "skipped_ticks": (s.get("loop") or {}).get("skipped_ticks"),
                "lateness_us": {
                    k: (s.get("lateness_us") or {}).get(k) for k in ("p50", "p99", "max")
                },
                "host_stalls": stalls.get("count", 0),
                "host_stall_max_ms": stalls.get("max_ms", 0.0),
                "comm_errors": comm_errors(s),
                # telemetry rows not written: dropped (no room) and lost (the writer failed)
                "rows_dropped": (s.get("telemetry") or {}).get("rows_dropped"),
                "rows_lost": (s.get("telemetry") or {}).get("rows_lost"),
                # every process of the run (start-up, check, exit policy included) over the
                # show's ticks: with several buses, all of them together
                "cpu_us_per_tick": 1e6 * cpu / max(most_ticks, 1),
                "cpu_percent": 100.0 * cpu / wall,
                "show_wall_s": float(s.get("wall_s") or wall),
                "emulator_cpu_percent": None if emu_cpu is None else 100.0 * emu_cpu / wall,
                "stage_p50_us": {
                    st: ((s.get("stage_us") or {}).get(st) or {}).get("p50")
                    for st in ("sim", "safety", "bus", "telemetry")
                },
                # per generation: collections, the longest and their total (ms), the process's
                # (one-bus rigs only: a group's children run without the timer)
                "gc_collections": {
                    g: [n, round(w * 1e3, 2), round(t * 1e3, 1)]
                    for g, (n, w, t) in gc_stats.items()
                },
                "load_before": load_before,
                "load_after": loadavg(),
                "alongside": same_minute[bus],
            }
        )
    return rows


#: how an overrun episode began (µs): a wake-up at least this late, else a bus stage at least
#: this much longer than its median on a tick that woke on time
_LATE_WAKE_US, _LONG_BUS_US = 50.0, 150.0


def overrun_episodes(run_dir: Path) -> dict | str:
    """Runs of consecutive overrun ticks in the run's telemetry, and how many began at a late
    wake-up or inside a long bus stage (consecutive rows taken as consecutive ticks: rows
    dropped, counted in the line, can merge two); or why they could not be counted."""
    from hilsim.telemetry.reader import read_run

    try:
        run = read_run(run_dir)
        over, late, bus = run.overrun.astype(bool), run.lateness_us, run.stage_us("bus")
    except Exception as exc:  # a benchmark's extra: the summary's figures stand without it
        return f"{type(exc).__name__}: {exc}"
    if not len(over):
        return "no telemetry rows"
    starts = np.flatnonzero(over & ~np.r_[False, over[:-1]])
    woke_late = late[starts] >= _LATE_WAKE_US
    long_bus = ~woke_late & (bus[starts] - np.median(bus) >= _LONG_BUS_US)
    return {
        "episodes": len(starts),
        "at_late_wake": int(woke_late.sum()),
        "in_long_bus_stage": int(long_bus.sum()),
    }


_SPIKE = re.compile(r"T:\s*(\d+)\s+Spike:\s*(\d+):\s*TS:\s*(\d+)")
_THREAD = re.compile(r"T:\s*(\d+)\s*\(\s*\d+\)\s*P:\s*\d+\s*I:\s*\d+\s*C:\s*(\d+).*Max:\s*(\d+)")


def start_alongside(seconds: float, spare_us: float) -> subprocess.Popen | str:
    """cyclictest beside the run (see ``--alongside``), or why it could not start."""
    cmd = ["cyclictest", "-m", "-q", "-S", "-d", "0", "-i", "1000", "-p", "80"]
    cmd += ["--default-system", f"--spike={max(0, round(spare_us) - 1)}", "--spike-nodes=1000000"]
    cmd += ["-D", str(max(1, round(seconds)))]
    try:
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    except OSError as exc:
        return f"cyclictest not run: {exc} (Debian's rt-tests)"


def stop_alongside(proc: subprocess.Popen | str) -> dict:
    """Stop cyclictest (SIGINT: it prints its summary); its wake-ups' counts and spikes."""
    if isinstance(proc, str):
        return {"error": proc}
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    threads = {int(m[1]): (int(m[2]), int(m[3])) for m in _THREAD.finditer(out)}
    if not threads:
        return {"error": f"cyclictest printed no summary (exit {proc.returncode}): {err[:200]}"}
    spikes = [(int(m[1]), int(m[2]), int(m[3]) * 1e-6) for m in _SPIKE.finditer(out)]
    return {"threads": threads, "spikes": spikes}


def coincide(run_dir: Path, summary: dict, beside: dict, rig: Path) -> dict | str:
    """The run's overrun episodes against cyclictest's late wake-ups in the show's span: how
    many began within [-1, +3] ticks of one (on the loop's pinned CPU, else any CPU)."""
    if "error" in beside:
        return beside["error"]
    from hilsim.rig import load_rig
    from hilsim.telemetry.reader import read_run

    try:
        t0 = float(summary["loop"]["clock_t0"])
        end = t0 + float(summary.get("duration_s") or 0.0)
        run = read_run(run_dir)
        over = run.overrun.astype(bool)
        loop = load_rig(rig).loop
        pinned, period = loop.cpu, 1.0 / float(loop.rate_hz)
    except Exception as exc:  # a benchmark's extra: the run's own figures stand without it
        return f"{type(exc).__name__}: {exc}"
    spikes = [(c, us, ts) for c, us, ts in beside["spikes"] if t0 <= ts <= end]
    mine = np.array([ts for c, _, ts in spikes if pinned is None or c == pinned])
    starts = np.flatnonzero(over & ~np.r_[False, over[:-1]])
    at = t0 + run.t_sched[starts]
    near = np.zeros(len(at), dtype=bool)
    if len(mine):
        mine.sort()
        lo = np.searchsorted(mine, at - period)
        hi = np.searchsorted(mine, at + 3 * period, side="right")
        near = hi > lo
    cpus = sorted(beside["threads"])
    return {
        "episodes": len(starts),
        "episodes_at_host_wakeup": int(near.sum()),
        "episodes_without": int((~near).sum()),
        "late_wakeups": {c: sum(1 for x, _, _ in spikes if x == c) for c in cpus},
        "late_wakeups_1ms": sum(1 for _, us, _ in spikes if us >= 1000),
        "max_us": max((us for _, us, _ in spikes), default=0),
        "cpu_matched": "any" if pinned is None else pinned,
        "loop_sched": (summary.get("loop") or {}).get("sched"),
    }


def alongside_line(a: dict | str | None, spare_us: float) -> str:
    if a is None:
        return ""
    if isinstance(a, str):
        return f"  same minute: cyclictest alongside not counted: {a}"
    per_cpu = ", ".join(f"CPU {c} {n}" for c, n in a["late_wakeups"].items())
    where = "any CPU" if a["cpu_matched"] == "any" else f"CPU {a['cpu_matched']}"
    return (
        f"  same minute: {a['episodes']} overrun episodes of the loop; cyclictest alongside "
        f"woke {spare_us:g} us or more late {sum(a['late_wakeups'].values())} times "
        f"({per_cpu}; {a['late_wakeups_1ms']} of 1 ms or more, max {a['max_us']} us); "
        f"{a['episodes_at_host_wakeup']} episodes began within [-1, +3] ticks of such a "
        f"wake-up on {where}, {a['episodes_without']} did not (the loop's own, or the host's "
        "where no cyclictest thread waited)"
        + (
            "; the loop ran SCHED_OTHER: other processes' work delays it and not cyclictest "
            "(SCHED_FIFO): --set loop.realtime_priority=50 --set loop.cpu=1 for like with like"
            if a.get("loop_sched") == "SCHED_OTHER"
            else f"; the loop ran {a.get('loop_sched')}"
        )
    )


def host_check(seconds: float, spare_us: float, cpu: int | None, priority: int | None) -> str:
    """cyclictest on this host for ``seconds`` (on ``cpu``, else the last one; SCHED_FIFO at
    ``priority``, else 80): wake-ups later than ``spare_us`` and 1 ms."""
    cpu = max(os.sched_getaffinity(0)) if cpu is None else cpu
    prio = 80 if priority is None else priority
    secs = max(1, round(seconds))
    cmd = ["cyclictest", "-m", "-q", "-i", "1000", "-p", str(prio), "-a", str(cpu)]
    cmd += ["-D", str(secs), "-h", "20000"]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=secs + 30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"host check not run: {exc} (cyclictest is in Debian's rt-tests)"
    hist = [ln.split() for ln in out.stdout.splitlines() if ln[:1].isdigit()]
    hist = [(int(h[0]), int(h[1])) for h in hist if len(h) >= 2]
    worst = re.search(r"Max Latencies:\s*(\d+)", out.stdout)
    over = re.search(r"Histogram Overflows:\s*(\d+)", out.stdout)  # 20 ms or later
    if out.returncode or not hist or worst is None:
        return f"host check failed (exit {out.returncode}): {out.stderr.strip()[:200]}"
    beyond = int(over.group(1)) if over else 0
    n = sum(c for _, c in hist) + beyond
    late = sum(c for us, c in hist if us >= spare_us) + beyond
    ms = sum(c for us, c in hist if us >= 1000) + beyond
    return (
        f"host (cyclictest, SCHED_FIFO {prio}, CPU {cpu}, {n} wake-ups at 1 kHz over "
        f"{secs} s): {late} woke {spare_us:g} us or more late, {ms} 1 ms or more, max "
        f"{int(worst.group(1))} us; load {loadavg()}"
    )


def comm_errors(s: dict) -> int:
    """stale + error + alert reads (``docs/summary.md``)."""
    return sum(
        sum((s.get(key) or {}).values()) for key in ("stale_reads", "error_reads", "alert_reads")
    )


def line(r: dict) -> str:
    lat, st = r["lateness_us"], r["stage_p50_us"]
    e = r["overrun_episodes"]
    episodes = (
        f" in {e['episodes']} episodes ({e['at_late_wake']} began at a wake-up "
        f"{_LATE_WAKE_US:g} us late or more, {e['in_long_bus_stage']} in a bus stage "
        f"{_LONG_BUS_US:g} us over its median)"
        if isinstance(e, dict)
        else f" (episodes not counted: {e})"
    )
    emu = (
        f"; emulator process {r['emulator_cpu_percent']:.0f} % of a core"
        if r["emulator_cpu_percent"] is not None
        else ""
    )
    return (
        f"{r['mode']:6s}{' bus ' + r['bus'] if r['bus'] else ''} gc={r['gc']:7s} "
        f"{'+'.join(r['diag'] + r['set']) or 'as shipped'}: exit "
        f"{r['exit_code']}: overruns {r['overruns']}/{r['ticks']}{episodes} (skipped "
        f"{r['skipped_ticks']}); lateness p50 "
        f"{lat['p50']:.1f} p99 "
        f"{lat['p99']:.1f} max {lat['max']:.0f} us; host stalls {r['host_stalls']} (max "
        f"{r['host_stall_max_ms']:.1f} ms); comm errors {r['comm_errors']}; telemetry rows "
        f"dropped {r['rows_dropped']}, lost {r['rows_lost']}; CPU "
        f"{r['cpu_us_per_tick']:.0f} us/tick = "
        f"{r['cpu_percent']:.0f} % of a core{emu}; stage p50 us "
        + ", ".join(f"{k} {v:.0f}" for k, v in st.items() if v is not None)
        + "; GC (n, max ms, total ms) "
        + " ".join(f"gen{g} {v}" for g, v in sorted(r["gc_collections"].items()))
        + f"; load {r['load_before']} -> {r['load_after']}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", type=Path, default=REPO / "configs" / "scale16.toml")
    ap.add_argument("--seconds", type=float, default=60.0, help="show length per run (s)")
    ap.add_argument("--mode", choices=("inproc", "pty", "both"), default="inproc")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--gc", default="none", help="none | freeze | disable | gen0=N")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    ap.add_argument("--diag", action="append", default=[], choices=sorted(DIAG))
    ap.add_argument("--json", type=Path, help="append the results here (JSON lines)")
    ap.add_argument(
        "--host-check",
        type=float,
        metavar="SPARE_US",
        help="then run cyclictest as long and count its wake-ups at least SPARE_US late "
        "(scale16: ~250, its period less its tick)",
    )
    ap.add_argument(
        "--alongside",
        type=float,
        metavar="SPARE_US",
        help="cyclictest in the same minute, beside each run (one thread a CPU): its wake-ups "
        "at least SPARE_US late beside the loop's overrun episodes, matched in time",
    )
    args = ap.parse_args(argv)
    if args.gc not in PRELUDE and not re.fullmatch(r"gen0=\d+", args.gc):
        ap.error(f"--gc: none, freeze, disable or gen0=N, got {args.gc!r}")
    modes = ("inproc", "pty") if args.mode == "both" else (args.mode,)
    changed = " ".join(args.set) or "rig as shipped"
    print(f"{args.rig} for {args.seconds:g} s, {changed}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        rig = tuned_rig(args.rig.resolve(), args.set, Path(tmp))
        for n in range(args.repeat):
            for mode in modes:
                runs = run_once(
                    rig, args.seconds, mode, args.gc, args.diag, Path(tmp), n, args.alongside
                )
                for r in runs:
                    r["set"] = args.set
                    print(line(r), flush=True)
                    if args.alongside is not None:
                        print(alongside_line(r["alongside"], args.alongside), flush=True)
                    if args.json:
                        with args.json.open("a") as f:
                            f.write(json.dumps(r) + "\n")
            if args.host_check is not None:
                keys = dict(item.split("=", 1) for item in args.set)
                cpu, prio = keys.get("loop.cpu"), keys.get("loop.realtime_priority")
                cpu, prio = (None if v is None else int(v) for v in (cpu, prio))
                print(host_check(args.seconds, args.host_check, cpu, prio), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
