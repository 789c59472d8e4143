"""Stop a real-time demo run for a while (SIGSTOP ... SIGCONT) and check the show went on.

    python tools/host_stall.py                       # 20, 60, 200, 600 ms x 5 runs each
    python tools/host_stall.py --stalls 200 --runs 2 --hogs 2

Each run is ``hilsim run configs/demo.toml`` on the real clock (the emulator in-process), frozen
once at a random moment between 2 s and 15 s of show. Afterwards the run directory is read
back and a table row printed: exit code, the stall events, whether any servo was blamed
(comm errors, a fault naming a servo), watchdog recoveries, and how far the present positions
were from the commands over the last second of the show (a frozen figure shows tens of degrees).
``--hogs N`` runs N busy loops beside it. Prints the 1-minute load before and after each run.
Not a test: it needs the real clock and takes about 25 s per run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hilsim.telemetry.reader import read_run  # noqa: E402
from hilsim.telemetry.stats import comm_errors  # noqa: E402


def _load() -> float:
    return os.getloadavg()[0]


def one_run(stall_ms: float, seed: int, out: Path, rig: Path) -> dict:
    rng = random.Random(seed)
    at = rng.uniform(2.0, 15.0)
    proc = subprocess.Popen(
        [sys.executable, "-m", "hilsim", "run", str(rig), "--no-plots", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    load0 = _load()
    line = proc.stderr.readline()  # "hilsim run: demo: ... -> DIR": the show is starting
    time.sleep(at)
    if stall_ms > 0:
        proc.send_signal(signal.SIGSTOP)
        time.sleep(stall_ms / 1e3)
        proc.send_signal(signal.SIGCONT)
    err = line + proc.stderr.read()
    code = proc.wait(timeout=120)
    run = read_run(out)
    summary = run.summary or {}
    stalls = [e for e in run.events if e["kind"] == "host_stall"]
    recovered = [e for e in run.events if e["kind"] == "recovered"]
    faults = [e for e in run.events if e["kind"] == "fault"]
    t = run.columns["t_sched"]
    last = t >= t[-1] - 1.0
    worst = 0.0
    for name in run.joint_names:
        cmd = run.columns[f"cmd_{name}"][last]
        present = run.columns[f"present_{name}"][last]
        ok = np.isfinite(present)
        if ok.any():
            worst = max(worst, float(np.max(np.abs(present[ok] - cmd[ok]))))
    return {
        "stall_ms": stall_ms,
        "at_s": round(at, 2),
        "exit": code,
        "reason": summary.get("exit_reason", err.strip().splitlines()[-1:]),
        "stall_events": [round(e.get("stall_ms", 0)) for e in stalls],
        "recoveries": len(recovered),
        "comm_errors": comm_errors(summary) if summary else None,
        "servo_blamed": any("servo" in f["message"] for f in faults),
        "last_second_max_error_deg": round(math.degrees(worst), 2),
        "overruns": summary.get("overruns"),
        "load": (round(load0, 2), round(_load(), 2)),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--stalls", default="20,60,200,600", help="stall lengths in ms")
    p.add_argument("--runs", type=int, default=5, help="runs per stall length")
    p.add_argument("--hogs", type=int, default=0, help="busy loops beside the run")
    p.add_argument("--rig", default=str(REPO / "configs" / "demo.toml"))
    p.add_argument("--json", help="also write the rows to this file")
    args = p.parse_args()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.hogs)]
    rows = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for stall in [float(s) for s in args.stalls.split(",")]:
                for r in range(args.runs):
                    row = one_run(stall, r, Path(tmp) / f"s{stall:g}-{r}", Path(args.rig))
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    finally:
        for h in hogs:
            h.kill()
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
