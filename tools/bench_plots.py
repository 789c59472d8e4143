"""How long the figures of one run take in a fresh process, as `hilsim plot` pays for them
(issue 12; not a test). `hilsim run --virtual-time` has a process import matplotlib while the show
runs (plots.prestart) and waits only for the drawing: time it end to end, with and without
``--no-plots``.

Each sample is a fresh ``python`` process (interpreter start excluded, imports included): import
:mod:`hilsim.telemetry.plots`, :func:`read_run` the directory, then :func:`plot_run` on the loaded
run, which imports matplotlib and writes the three PNGs. Prints the median and the best of N
samples of each phase, the whole process's wall time, and ``/proc/loadavg`` before and after (the
machine is shared: compare best-of-N taken at a similar load; the CPU seconds of each child, its
forked helper's included, vary less with the load than wall time).

    python tools/bench_plots.py [RUN_DIR] [-n 7] [--serial] [--out DIR] [--json FILE]
    python tools/bench_plots.py [RUN_DIR] --prestarted 3   # as `hilsim run --virtual-time`

``--prestarted S`` times what `hilsim run --virtual-time` waits for after its show instead: a
plotting process prestarted (plots.prestart, plots.prepare) S seconds before ``plot_run`` of
the run directory (phase "plot" is that wait; "import" and "read" are then 0).

Without RUN_DIR, the demo is run once first (``hilsim run configs/demo.toml --virtual-time
--no-plots``) into a temporary directory.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: runs in the child: phases in seconds, one JSON line on stdout
CHILD = """
import json, sys, time
t0 = time.perf_counter()
from hilsim.telemetry.plots import plot_run
from hilsim.telemetry.reader import read_run
t1 = time.perf_counter()
run = read_run(sys.argv[1])
t2 = time.perf_counter()
paths = plot_run(run, sys.argv[2], **({} if sys.argv[3] == "auto" else {"parallel": False}))
t3 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "read": t2 - t1, "plot": t3 - t2, "total": t3 - t0,
                  "pngs": [str(p) for p in paths]}))
"""

#: the same, through a prestarted process told the run's shape, given argv[3] seconds first
PRESTARTED = """
import json, sys, time
from hilsim.telemetry import plots
from hilsim.telemetry.reader import read_run
run = read_run(sys.argv[1])
plots.prestart()
plots.prepare(len(run.joint_names), virtual=plots.is_virtual_time(run))
time.sleep(float(sys.argv[3]))
t0 = time.perf_counter()
paths = plots.plot_run(sys.argv[1], sys.argv[2])
t1 = time.perf_counter()
print(json.dumps({"import": 0.0, "read": 0.0, "plot": t1 - t0, "total": t1 - t0,
                  "pngs": [str(p) for p in paths]}))
"""

PHASES = ("import", "read", "plot", "total", "process", "cpu")


def loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def demo_run(where: Path) -> Path:
    run_dir = where / "demo"
    cmd = [sys.executable, "-m", "hilsim", "run", str(ROOT / "configs" / "demo.toml"),
           "--virtual-time", "--no-plots", "--out", str(run_dir)]  # fmt: skip
    subprocess.run(cmd, check=True, cwd=where, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return run_dir


def _cpu() -> float:
    """CPU seconds of this process's children that have ended (their own children included)."""
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def sample(run_dir: Path, out: Path, mode: str) -> dict[str, float]:
    cpu = _cpu()
    start = time.perf_counter()
    code, arg = (CHILD, mode) if not mode.startswith("prestarted:") else (PRESTARTED, mode[11:])
    proc = subprocess.run(
        [sys.executable, "-c", code, str(run_dir), str(out), arg],
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - start
    cpu = _cpu() - cpu
    if proc.returncode != 0:
        sys.exit(f"bench_plots: the child failed:\n{proc.stderr}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["process"] = wall
    result["cpu"] = cpu
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", nargs="?", help="a run directory (default: run the demo once)")
    ap.add_argument("-n", type=int, default=7, help="fresh processes (default 7)")
    ap.add_argument("--out", help="where the PNGs go (default: a temporary directory)")
    ap.add_argument("--json", metavar="FILE", help="also write the samples as JSON")
    ap.add_argument(
        "--serial", action="store_true", help="all figures in one process (no forked helper)"
    )
    ap.add_argument(
        "--prestarted",
        type=float,
        metavar="S",
        help="time plot_run through a process prestarted S seconds before (hilsim run's way)",
    )
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_plots_") as tmp:
        run_dir = Path(args.run_dir) if args.run_dir else demo_run(Path(tmp))
        out = Path(args.out) if args.out else Path(tmp) / "plots"
        before = loadavg()
        mode = "serial" if args.serial else "auto"
        if args.prestarted is not None:
            mode = f"prestarted:{args.prestarted}"
        samples = [sample(run_dir, out, mode) for _ in range(args.n)]
        after = loadavg()
    print(f"plot_run on {run_dir}: {args.n} fresh processes{' (serial)' if args.serial else ''}")
    print(f"  loadavg before {before}, after {after}")
    print(f"  {'phase':<8} {'median':>8} {'best':>8}   (s)")
    for phase in PHASES:
        values = [s[phase] for s in samples]
        print(f"  {phase:<8} {statistics.median(values):8.3f} {min(values):8.3f}")
    print("  import: hilsim.telemetry.plots and reader (not matplotlib); read: read_run;")
    print("  plot: plot_run on the loaded run, matplotlib's import included; process: the whole")
    print("  child, interpreter start-up included; cpu: its CPU seconds (user + sys, a forked")
    print("  helper's included): steadier than wall time when the machine is busy")
    if args.json:
        doc = {"run_dir": str(run_dir), "loadavg": [before, after], "samples": samples}
        Path(args.json).write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
