"""Are two run directories the same show, tick for tick? (A refactor's check.)

    python tools/same_run.py RUN_A RUN_B

Compares telemetry.csv cell by cell as text (every float64 is written with %.17g, so equal
text is equal bits) except the columns that time the host (t_sim_us, t_safety_us, t_bus_us,
t_telemetry_us: CPU time, different on every run), and events.jsonl line by line without the
wall-clock ``wall`` field. Prints the first difference and exits 1, or prints what matched and
exits 0. Only virtual-time runs are deterministic; a real-time run differs in lateness.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

HOST_TIME_COLUMNS = {"t_sim_us", "t_safety_us", "t_bus_us", "t_telemetry_us"}


def _rows(run: Path) -> tuple[list[str], list[list[str]]]:
    with open(run / "telemetry.csv", newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def _events(run: Path) -> list[dict]:
    out = []
    for line in (run / "events.jsonl").read_text(encoding="utf-8").splitlines():
        ev = json.loads(line)
        ev.pop("wall", None)
        out.append(ev)
    return out


def compare(a: Path, b: Path) -> str | None:
    """None if the runs are the same show, else the first difference."""
    head_a, rows_a = _rows(a)
    head_b, rows_b = _rows(b)
    if head_a != head_b:
        return f"headers differ: {head_a} vs {head_b}"
    if len(rows_a) != len(rows_b):
        return f"{len(rows_a)} vs {len(rows_b)} ticks"
    keep = [i for i, name in enumerate(head_a) if name not in HOST_TIME_COLUMNS]
    for n, (ra, rb) in enumerate(zip(rows_a, rows_b, strict=True)):
        for i in keep:
            if ra[i] != rb[i]:
                return f"row {n + 1}, column {head_a[i]}: {ra[i]} vs {rb[i]}"
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
    _, rows = _rows(a)
    print(f"same show: {len(rows)} ticks, every column but the host's stage times, and every event")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
