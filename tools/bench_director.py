"""What a show's director costs the tick (issue 14; a benchmark, not a test).

Runs the demo rig (``configs/demo.toml``) for 50 s of show in virtual time, once per show file
given, and times :meth:`hilsim.live.director.Director.tick` (every input polled, the show
runtime's cues and clips, the events) on every tick; the inputs are built but not opened, so
nothing arrives: this is the cost of a show that is listening::

    python tools/bench_director.py SHOW.toml [SHOW.toml ...]
    python tools/bench_director.py configs/shows/demo_show.toml

Prints p50 / p99 / max / mean in µs per tick. Give ``cat /proc/loadavg`` beside the numbers.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

from hilsim.rig import load_rig
from hilsim.show.parts import build_parts, with_show
from hilsim.show.session import open_bus, open_telemetry, port_for, run_show
from hilsim.show.stop import StopFlag

REPO = Path(__file__).resolve().parents[1]


def measure(show: str, seconds: float = 50.0) -> str:
    rig = load_rig(REPO / "configs" / "demo.toml")
    parts = with_show(build_parts(rig), show, False, virtual=True)
    director = parts.director
    real, times = director.tick, []

    def tick(k, t, present):
        a = time.perf_counter()
        real(k, t, present)
        times.append(time.perf_counter() - a)

    director.tick = tick
    bus = open_bus(rig, port_for(rig, True))
    tel = open_telemetry(rig, Path(tempfile.mkdtemp(prefix="bench-director-")) / "run", True)
    try:
        run_show(parts, bus, tel, duration_s=seconds, stop=StopFlag())
    finally:
        bus.close()
    us = sorted(x * 1e6 for x in times)
    return (
        f"{show}: {len(us)} ticks, Director.tick p50 {us[len(us) // 2]:.1f} us, "
        f"p99 {us[int(len(us) * 0.99)]:.1f} us, max {us[-1]:.0f} us, "
        f"mean {statistics.mean(us):.1f} us"
    )


def main() -> int:
    if len(sys.argv) < 2:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    print(f"load: {Path('/proc/loadavg').read_text().strip()}")
    for show in sys.argv[1:]:
        print(measure(show))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
