"""A live show on the real clock under an OSC flood (issue 14; a benchmark, not a test).

Runs ``hilsim run RIG --show`` (OSC on 127.0.0.1) twice on the emulator's real clock: once
quiet, once while another process sends junk datagrams to its OSC port as fast as it can, for
the whole show with a real jaw value every 50 ms among them, or (``--count N``) N malformed
ones and nothing else (the issue's "10,000 malformed packets": no target may change). Prints,
for each run, the summary's lateness p50/p99/max, overruns, ticks, the drops counted by kind,
the live values taken, and the CPU the show's process used per tick (the in-process emulator's
included)::

    python tools/bench_live_show.py [--rig configs/demo.toml] [--seconds 20] [--count 10000]

Give ``cat /proc/loadavg`` beside the numbers: these are wall-clock figures on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def flood(port: int, seconds: float, count: int | None, values: bool) -> int:
    """Junk datagrams to 127.0.0.1:port for ``seconds`` (or ``count`` of them, as fast as the
    socket takes them); with ``values``, a real jaw value every 50 ms among them."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    junk = b"\x00junk" * 5
    value = b"/hilsim/joint/jaw\x00\x00\x00,f\x00\x00" + struct.pack(">f", 0.25)
    end = time.monotonic() + seconds
    n, next_value = 0, 0.0
    while (now := time.monotonic()) < end and (count is None or n < count):
        try:
            s.sendto(junk, ("127.0.0.1", port))
            n += 1
            if values and now >= next_value:
                s.sendto(value, ("127.0.0.1", port))
                next_value = now + 0.05
        except OSError:  # the buffer is full: the receiver is held back, keep sending
            pass
    return n


def run_show(rig: str, seconds: float, port: int, flooded: bool, count: int | None) -> dict:
    out = Path(tempfile.mkdtemp(prefix="live-bench-")) / "run"
    show = out.parent / "show.toml"
    show.write_text(f"[inputs.osc]\nport = {port}\nmax_rx_per_s = 2000\n")
    cmd = [sys.executable, "-m", "hilsim", "run", rig, "--show", str(show), "--duration",
           str(seconds), "--no-plots", "--out", str(out)]  # fmt: skip
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    sent = 0
    if flooded:
        time.sleep(1.0)  # the show is running: start-up takes ~0.4 s
        sent = flood(port, seconds - 1.5, count, values=count is None)
    _, err = proc.communicate()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = json.loads((out / "summary.json").read_text())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    ticks = summary["ticks"]
    return {
        "flooded": flooded,
        "exit": proc.returncode,
        "ticks": ticks,
        "overruns": summary["overruns"],
        "lateness_us": {k: summary["lateness_us"][k] for k in ("p50", "p99", "max")},
        "cpu_us_per_tick": round(cpu / ticks * 1e6, 1),
        "datagrams_sent": sent,
        "drops": {k: v for k, v in summary["live"]["osc_drops"].items() if v},
        "live_values": summary["live"]["live_values"],
        "stderr_tail": err.strip().splitlines()[-3:],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rig", default=str(REPO / "configs" / "demo.toml"))
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--port", type=int, default=9000)
    ap.add_argument(
        "--count",
        type=int,
        help="send this many malformed datagrams (as fast as possible) and no values, instead "
        "of flooding for the whole show with a value every 50 ms",
    )
    args = ap.parse_args()
    print(f"load: {Path('/proc/loadavg').read_text().strip()}  cpus: {os.cpu_count()}")
    for flooded in (False, True):
        r = run_show(args.rig, args.seconds, args.port, flooded, args.count)
        print(json.dumps(r))
    print(f"load: {Path('/proc/loadavg').read_text().strip()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
