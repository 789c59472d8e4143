"""The bus time per tick of 12 Feetech STS3215 at 250 Hz, 1 Mbit/s, against the wire model
(not a test): ``hilsim bench``'s Protocol 1.0 measurement (:mod:`hilsim.bench.p1rate`) on a
rig of 12 joints, in-process (``dxlsim://``, real clock, no USB latency) and over a
``hilsim emulate`` pty, best of ``--repeats`` runs each.

Each run prints the time per cycle (one Sync Write of goals + one Sync Read of 12 present
positions), split into the **bus time** (transmit to the last reply byte in hand, the
device's own delays included) and the **host's** (packets built and parsed), beside the
wire model (1.84 ms: Sync Write 0.44 ms + Sync Read 1.40 ms with Return Delay 0 and 20 µs
turnaround a reply). Over the pty the model adds the 1 ms latency the driver allows a pty,
and the bus time includes the pty's delivery between two processes and the emulator
process's scheduling: not a servo bus (``tools/pty_breakdown.py`` splits that for the X
series). The machine's load is printed first: the figures are wall-clock ones.

    python tools/p1_rate.py [--cycles 2000] [--repeats 3] [--no-pty]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

IN_PROCESS = "dxlsim://?ids=1-12&model=STS3215&rdt_us=0&latency_ms=0&clock=real"

EMULATE = (sys.executable, "-m", "hilsim", "emulate", "--ids", "1-12", "--model", "STS3215")

RIG_HEAD = """name = "sts12"
[bus]
port = "PORT"
baud = 1000000
[loop]
rate_hz = 250
[safety]
exit_policy = "relax"
"""


def rig_text(port: str) -> str:
    text = RIG_HEAD.replace("PORT", port)
    for i in range(1, 13):
        text += (
            f'[[joints]]\nname = "j{i}"\nservo_id = {i}\nmodel = "STS3215"\nmin_deg = -50\n'
            "max_deg = 50\nspring = { frequency_hz = 2.0, damping_ratio = 0.8 }\n"
            'target = { type = "hold", value_deg = 0 }\n'
        )
    return text


def run(port: str, cycles: int, repeats: int, label: str) -> None:
    from hilsim.bench.p1rate import measure
    from hilsim.rig import load_rig

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sts12.toml"
        path.write_text(rig_text(port))
        rig = load_rig(path)
        results = [measure(rig, port, cycles) for _ in range(repeats)]
    best = min(results, key=lambda r: r.achieved_s)
    print(f"{label}: best of {repeats} (by the whole cycle)")
    print("  " + best.text().replace("\n", "\n  ").rstrip())
    for r in results:
        print(
            f"    run: cycle {r.achieved_s * 1e3:.3f} ms, bus {r.bus_s * 1e3:.3f} ms "
            f"({(r.bus_ratio - 1) * 100:+.1f} %; host stalls {r.stall_s * 1e3:.3f} ms), "
            f"host {(r.achieved_s - r.bus_s) * 1e3:.3f} ms"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-pty", action="store_true")
    args = ap.parse_args()
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}, {os.cpu_count()} CPUs")
    run(IN_PROCESS, args.cycles, args.repeats, "in-process (dxlsim://, real clock)")
    if args.no_pty:
        return
    emu = subprocess.Popen(
        [*EMULATE, "--baud", "1000000", "--rdt-us", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    try:
        assert emu.stdout is not None
        pty = emu.stdout.readline().strip()
        run(pty, args.cycles, args.repeats, f"over a hilsim emulate pty ({pty})")
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.wait(30)


if __name__ == "__main__":
    main()
