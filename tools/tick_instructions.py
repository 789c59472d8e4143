"""Instructions per cycle: hilsim's tick against the bare dynamixel-sdk cycle (not a test).

Wall-clock medians on a shared 2-core machine vary by up to 2x from run to run; valgrind
counts instructions, which no other load disturbs. For each servo count and each side this
runs the same program twice under ``valgrind --tool=cachegrind --cache-sim=no``, with 0 and
with ``--cycles`` cycles after the same warm-up, and divides the difference by the cycles:
start-up, imports and warm-up cancel out. Both sides run on the instant in-process fake
port of :mod:`hilsim.bench.tick`.

    python tools/tick_instructions.py [--servos 4,16] [--cycles 2000] [--cache]

(about a minute per servo count and side; needs valgrind: apt-get install valgrind)

``--cache`` adds cachegrind's simulated first-level instruction and data cache misses and
branch mispredictions per cycle (twice as slow): why a tick of fewer instructions than the
bare cycle can still take longer on the clock.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

WARMUP = 200


def _child(which: str, n: int, cycles: int) -> None:
    from hilsim.bench.tick import BareSdkCycle, HilsimTick

    f = BareSdkCycle(n) if which == "sdk" else HilsimTick(n, Path(tempfile.mkdtemp()))
    drain = getattr(f, "between_rounds", lambda: None)
    for _ in range(WARMUP):
        f()
    drain()
    for i in range(cycles):
        f()
        if i % 300 == 299:
            drain()  # telemetry rows out of the ring, as between a bench's rounds


#: cachegrind's summary lines: what each column counts
COUNTS = {"I": r"I\s+refs", "I1 miss": r"I1\s+misses", "D1 miss": r"D1\s+misses",
          "mispredict": r"Mispredicts"}  # fmt: skip


def _counts(which: str, n: int, cycles: int, cache: bool) -> dict[str, int]:
    env = {**os.environ, "PYTHONHASHSEED": "0"}  # the same dict and set orders in every run
    sim = ["--cache-sim=yes", "--branch-sim=yes"] if cache else ["--cache-sim=no"]
    out = subprocess.run(
        ["valgrind", "--tool=cachegrind", *sim, "--cachegrind-out-file=/dev/null",
         sys.executable, __file__, "--child", which, str(n), str(cycles)],
        capture_output=True, text=True, check=True, env=env,
    )  # fmt: skip
    found = {}
    for name, pattern in COUNTS.items():
        m = re.search(pattern + r":\s+([\d,]+)", out.stderr)
        if m is not None:
            found[name] = int(m.group(1).replace(",", ""))
    if "I" not in found:
        raise RuntimeError(f"no instruction count in valgrind's output:\n{out.stderr[-500:]}")
    return found


def main() -> int:
    if sys.argv[1:2] == ["--child"]:
        _child(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--servos", default="4,16", help="servo counts, e.g. 4,8,16")
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--cache", action="store_true", help="also cache misses, mispredictions")
    args = ap.parse_args()
    head = f"{'servos':>6} {'count':>11} {'bare SDK':>12} {'hilsim tick':>12} {'ratio':>6}"
    print(head + "   (per cycle)")
    for n in (int(x) for x in args.servos.split(",")):
        per: dict[str, dict[str, float]] = {}
        for which in ("sdk", "tick"):
            full, base = (_counts(which, n, c, args.cache) for c in (args.cycles, 0))
            per[which] = {k: (full[k] - base[k]) / args.cycles for k in full}
        for k in per["sdk"]:
            a, b = per["sdk"][k], per["tick"][k]
            print(f"{n:>6} {k:>11} {a:>12,.0f} {b:>12,.0f} {b / a if a else math.nan:>6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
