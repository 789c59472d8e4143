"""Time from ``hilsim run`` to the show's first tick, imports included (not a test).

    python tools/bench_startup.py                    # the demo on its emulator, 7 runs
    python tools/bench_startup.py --runs 15 --port /dev/pts/3
    python tools/bench_startup.py --importtime       # also: the slowest imports of one run
    python tools/bench_startup.py --pycache /tmp/pyc # bytecode cached there (a normal install)

Each run starts ``python -m hilsim run configs/demo.toml --duration 0.02 --no-plots`` (real
time: the built-in emulator in-process, or ``--port``) and reads back the run's
``summary.json``: ``loop.clock_t0`` is the clock time of tick 0, and a real-time show's
clock is ``time.perf_counter`` - CLOCK_MONOTONIC on Linux, the same in every process - so
``clock_t0`` minus the moment just before the child was started is the time to the first
tick: interpreter start, imports, loading the rig, opening and checking the bus, opening
the telemetry. Prints every run, the median and the best, with the 1-minute load.

The child inherits the environment; where ``PYTHONDONTWRITEBYTECODE`` is set and the
source tree has no ``__pycache__``, every hilsim module is compiled at every start (~150 ms).
``--pycache DIR`` lets the children cache bytecode in DIR (``PYTHONPYCACHEPREFIX``; one
untimed run first), as an installed package has it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def one_run(rig: Path, port: str | None, out: Path, env: dict | None = None) -> float:
    """Seconds from starting ``hilsim run`` to its first tick."""
    cmd = [sys.executable, "-m", "hilsim", "run", str(rig), "--duration", "0.02", "--no-plots"]
    cmd += ["--out", str(out)] + (["--port", port] if port else [])
    t_start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env)
    summary_path = out / "summary.json"
    if not summary_path.exists():
        raise SystemExit(f"hilsim run exited {proc.returncode} without a summary:\n{proc.stderr}")
    summary = json.loads(summary_path.read_text())
    if summary.get("clock") != "real time":
        raise SystemExit("the show did not run in real time: clock_t0 is not comparable")
    return summary["loop"]["clock_t0"] - t_start


def slowest_imports(rig: Path, port: str | None, n: int = 15, env: dict | None = None) -> list[str]:
    """``-X importtime`` of one run: the ``n`` packages with the largest cumulative time."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-X", "importtime", "-m", "hilsim", "run", str(rig)]
        cmd += ["--duration", "0.02", "--no-plots", "--out", str(Path(tmp) / "run")]
        cmd += ["--port", port] if port else []
        err = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env).stderr
    rows = []
    for line in err.splitlines():
        if line.startswith("import time:") and "|" in line:
            _, cumulative, name = line[len("import time:") :].split("|")
            if cumulative.strip().isdigit():
                rows.append((int(cumulative), name.rstrip()))
    rows.sort(reverse=True)
    return [f"{us / 1e3:7.1f} ms  {name}" for us, name in rows[:n]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--rig", default=str(REPO / "configs" / "demo.toml"))
    ap.add_argument("--port", help="a pty or device instead of the rig's port")
    ap.add_argument("--importtime", action="store_true", help="print the slowest imports too")
    ap.add_argument("--pycache", metavar="DIR", help="let the children cache bytecode in DIR")
    args = ap.parse_args(argv)
    rig = Path(args.rig).resolve()
    env = None
    if args.pycache:
        env = {**os.environ, "PYTHONPYCACHEPREFIX": str(Path(args.pycache).resolve())}
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        if env is not None:
            one_run(rig, args.port, Path(tmp) / "warm-up", env)  # writes the bytecode
        for i in range(args.runs):
            t = one_run(rig, args.port, Path(tmp) / f"run{i}", env)
            times.append(t)
            print(f"run {i + 1}: {t * 1e3:.0f} ms to the first tick", flush=True)
    load = os.getloadavg()[0]
    cache = f"bytecode cached in {args.pycache}" if args.pycache else "environment as is"
    print(
        f"hilsim run -> first tick: median {statistics.median(times) * 1e3:.0f} ms, best "
        f"{min(times) * 1e3:.0f} ms over {len(times)} runs ({cache}; load {load:.2f})"
    )
    if args.importtime:
        print("slowest imports (cumulative, -X importtime inflates them):")
        for row in slowest_imports(rig, args.port, env=env):
            print("  " + row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
