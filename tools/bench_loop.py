"""Real-time loop benchmark on the emulator (issue 4; not a test).

For each rate (500 Hz, 1 kHz) and joint count (4, 8), writes a rig whose joints follow sine
targets, runs ``hilsim run`` on the real clock as a child process, and reports tick lateness
(p50/p99/max), overruns, the child's CPU use (rusage user+sys over wall time) and the
per-tick host time split into simulation, safety, bus and telemetry (p50/p99, µs).

The emulated bus runs at 4 Mbit/s with Return Delay 0 and no USB latency timer (a native
UART or a high-speed adapter): at 1 Mbit/s, or with an FTDI adapter's 1 ms timer, 8 servos
cannot be read at 1 kHz at all, and ``hilsim run`` refuses such a rig before it starts.
The "bus" stage is wall time inside write_goals + read_present: the bytes' wire time (the
port sleeps on the emulator's clock while they are on the wire, spinning its last 100 µs)
plus the driver's packet code plus the emulator, which runs in the same process. On
hardware the emulator's share disappears.

    python tools/bench_loop.py [--seconds 20] [--fifo] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

JOINT = """
[[joints]]
name = "j{i}"
servo_id = {i}
min_deg = -60
max_deg = 60
max_speed_deg_s = 270
max_accel_deg_s2 = 6000
spring = {{ frequency_hz = {f:.2f}, damping_ratio = 0.7, response = 0.3 }}
target = {{ type = "sine", amplitude_deg = 30, frequency_hz = {s:.2f} }}
"""

RIG = """
name = "bench-{rate}hz-{n}j"
[bus]
port = "dxlsim://?ids=1-{n}&model=XM430-W350&rdt_us=0&latency_ms=0"
baud = 4000000
[loop]
rate_hz = {rate}
{fifo}
[safety]
soft_start_s = 0.2
"""


def run_one(rate: int, n: int, seconds: float, fifo: bool, out: Path) -> dict:
    text = RIG.format(rate=rate, n=n, fifo="realtime_priority = 50" if fifo else "")
    text += "".join(JOINT.format(i=i, f=2.0 + 0.5 * i, s=0.2 + 0.1 * i) for i in range(1, n + 1))
    rig = out / f"rig-{rate}-{n}.toml"
    rig.write_text(text)
    run_dir = out / f"run-{rate}-{n}"
    cmd = [
        sys.executable,
        "-m",
        "hilsim",
        "run",
        str(rig),
        "--duration",
        str(seconds),
        "--out",
        str(run_dir),
        "--no-plots",
    ]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode()
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise SystemExit(f"{rig.name}: hilsim run exited {code}:\n{err}")
    s = json.loads((run_dir / "summary.json").read_text())
    stages = s.get("stage_us", {})
    return {
        "rate_hz": rate,
        "joints": n,
        "sched": s.get("loop", {}).get("sched"),
        "ticks": s.get("ticks"),
        "achieved_hz": s.get("rate_hz"),
        "lateness_us": {k: s["lateness_us"][k] for k in ("p50", "p99", "max")},
        "overruns": s.get("overruns"),
        "cpu_percent": 100.0 * (usage.ru_utime + usage.ru_stime) / wall,
        "stage_us": {
            st: {k: stages.get(st, {}).get(k) for k in ("p50", "p99")}
            for st in ("sim", "safety", "bus", "telemetry")
        },
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="show length per run (s)")
    ap.add_argument("--fifo", action="store_true", help="ask for SCHED_FIFO (realtime_priority 50)")
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (500, 1000):
            for n in (4, 8):
                rows.append(run_one(rate, n, args.seconds, args.fifo, Path(tmp)))
                r = rows[-1]
                st = r["stage_us"]
                print(
                    f"{rate:5d} Hz {n} joints [{r['sched']}]: lateness p50 "
                    f"{r['lateness_us']['p50']:.1f} p99 {r['lateness_us']['p99']:.1f} max "
                    f"{r['lateness_us']['max']:.0f} us; overruns {r['overruns']}/{r['ticks']}; "
                    f"CPU {r['cpu_percent']:.0f} %; per tick p50/p99 us: "
                    + ", ".join(f"{k} {st[k]['p50']:.0f}/{st[k]['p99']:.0f}" for k in st),
                    flush=True,
                )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
