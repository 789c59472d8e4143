"""Are two run directories the same show, tick for tick? (A refactor's check.)

    python tools/same_run.py RUN_A RUN_B

Compares the telemetry (read with read_run, whatever its format: csv, csv.gz, parquet) cell by
cell, bit for bit (a CSV's %.17g text is the float64's bits; Parquet's fixed-point integers read
back the same way every time) except the columns that time the host (t_sim_us, t_safety_us,
t_bus_us, t_telemetry_us: CPU time, different on every run), and events.jsonl line by line
without the wall-clock ``wall`` field. Prints the first difference and exits 1, or prints what
matched and exits 0. Only virtual-time runs are deterministic; a real-time run differs in lateness.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hilsim.telemetry.reader import read_run

HOST_TIME_COLUMNS = {"t_sim_us", "t_safety_us", "t_bus_us", "t_telemetry_us"}


def _columns(run: Path) -> dict[str, np.ndarray]:
    return read_run(run).columns


def _events(run: Path) -> list[dict]:
    out = []
    for line in (run / "events.jsonl").read_text(encoding="utf-8").splitlines():
        ev = json.loads(line)
        ev.pop("wall", None)
        out.append(ev)
    return out


def compare(a: Path, b: Path) -> str | None:
    """None if the runs are the same show, else the first difference."""
    cols_a, cols_b = _columns(a), _columns(b)
    if list(cols_a) != list(cols_b):
        return f"headers differ: {list(cols_a)} vs {list(cols_b)}"
    if cols_a["tick"].size != cols_b["tick"].size:
        return f"{cols_a['tick'].size} vs {cols_b['tick'].size} ticks"
    for name, xa in cols_a.items():
        if name in HOST_TIME_COLUMNS:
            continue
        xb = cols_b[name]
        same = xa.view(np.int64) == xb.view(np.int64)  # bits: -0.0 is not 0.0, NaN is NaN
        if not same.all():
            n = int(np.argmin(same))
            return f"row {n + 1}, column {name}: {xa[n]!r} vs {xb[n]!r}"
    ev_a, ev_b = _events(a), _events(b)
    if ev_a != ev_b:
        for x, y in zip(ev_a, ev_b, strict=False):
            if x != y:
                return f"events differ: {x} vs {y}"
        return f"{len(ev_a)} vs {len(ev_b)} events"
    return None


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    a, b = map(Path, argv)
    diff = compare(a, b)
    if diff:
        print(f"different: {diff}")
        return 1
    ticks = _columns(a)["tick"].size
    print(f"same show: {ticks} ticks, every column but the host's stage times, and every event")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
