"""Live OSC input and its network guard (issue 14; not a test): what each costs, measured.

1. ``OscInput.feed`` per datagram, by what becomes of it: a joint value applied, a malformed
   packet, a flood drop (no token), a sender outside the allow-list, an oversized one, a bundle
   of 10 joint values (the receiver thread's side).
2. ``OscInput.poll`` with 10 joints: nothing new, 10 values + 8 cues, right after 10,000
   malformed packets (the loop's side).
3. A real UDP flood: a loop-like thread wakes every 4 ms (sleep, then spin the last 0.5 ms, as
   ``HilLoop`` does) and polls, for ``--seconds``, while another *process* sends 24-byte junk
   datagrams to 127.0.0.1 as fast as it can: quiet; the flood sent to a socket nobody reads (the
   control: the same CPU and kernel load, no receiver); the flood sent to the OSC receiver.
   Lateness (wake-up after the deadline) and poll time, p50 / p99 / max in µs.

    python tools/bench_live_osc.py [--seconds 5] [--cap 2000] [--fifo 50] [--switch 100e-6]

``--cap`` is ``UdpReceiver``'s ``max_rx_per_s`` (``0``: the default; ``1e7``, the most allowed,
is in effect uncapped), ``--fifo`` puts the polling thread in SCHED_FIFO at that priority as the
real loop asks (``0``: SCHED_OTHER), ``--switch`` is the GIL switch interval (the loop's is
100 µs). Give
``cat /proc/loadavg`` beside the numbers: the machine is shared and these are wall-clock figures.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import struct
import subprocess
import sys
import time

from hilsim.live.netguard import GuardConfig
from hilsim.live.osc import OscInput, listen

JOINTS = {f"j{i}": (0.0, 20.0) for i in range(10)}
LOCAL = ("127.0.0.1", 5)
PERIOD = 0.004


def _pad(b: bytes) -> bytes:
    b += b"\0"
    return b + b"\0" * (-len(b) % 4)


def osc(address: str, value: float | None = None) -> bytes:
    if value is None:
        return _pad(address.encode()) + _pad(b",")
    return _pad(address.encode()) + _pad(b",f") + struct.pack(">f", value)


def _per_call_us(fn, n: int) -> tuple[float, float]:
    runs = []
    for _ in range(5):
        t0 = time.perf_counter()
        fn(n)
        runs.append((time.perf_counter() - t0) / n * 1e6)
    return min(runs), statistics.median(runs)


def bench_feed() -> None:
    b = b"#bundle\0" + bytes(8)
    for i in range(10):
        m = osc(f"/hilsim/joint/j{i}", 0.5)
        b += struct.pack(">i", len(m)) + m
    cases = [
        ("joint value applied", osc("/hilsim/joint/j3", 0.5), LOCAL, False),
        ("malformed", b"\xff" * 24, LOCAL, False),
        ("flood drop (no token)", osc("/hilsim/joint/j3", 0.5), LOCAL, True),
        ("sender not allowed", osc("/hilsim/joint/j3", 0.5), ("10.1.1.1", 5), False),
        ("oversized (2000 B)", b"x" * 2000, LOCAL, False),
        ("bundle of 10 joints", b, LOCAL, False),
    ]
    for name, pkt, sender, flood in cases:
        guard = GuardConfig(rate_per_s=1.0, burst=1) if flood else GuardConfig(burst=1_000_000)
        inp = OscInput(JOINTS, guard=guard)

        def run(n, inp=inp, pkt=pkt, sender=sender, flood=flood):
            feed = inp.feed
            for i in range(n):
                feed(0.0 if flood else i * 1e-6, pkt, sender)

        lo, med = _per_call_us(run, 20000)
        print(f"feed {name:24s} {lo:7.2f} µs/datagram (best of 5 runs; median {med:.2f})")


def bench_poll() -> None:
    inp = OscInput(JOINTS, guard=GuardConfig(burst=1_000_000))

    def idle(n):
        for i in range(n):
            inp.poll(i * PERIOD)

    lo, med = _per_call_us(idle, 20000)
    print(f"poll, nothing new                 {lo:7.2f} µs (best of 5 runs; median {med:.2f})")
    pkts = [osc(f"/hilsim/joint/j{i}", 0.5) for i in range(10)]
    pkts += [osc(f"/hilsim/cue/c{i}") for i in range(8)]
    junk = [b"\xff" * 24] * 10_000
    for label, batch in (("10 values + 8 cues", pkts), ("10,000 malformed", junk)):
        us = []
        for k in range(200):
            for p in batch:
                inp.feed(k * PERIOD, p, LOCAL)
            t0 = time.perf_counter_ns()
            inp.poll(k * PERIOD + PERIOD)
            us.append((time.perf_counter_ns() - t0) / 1e3)
        us.sort()
        print(f"poll after {label:22s} p50 {us[100]:7.2f} µs, max {us[-1]:7.2f} µs")


def _loop(inp: OscInput, seconds: float, fifo: int) -> tuple:
    if fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(fifo))
    try:
        late, polls, t0, k = [], [], time.perf_counter(), 0
        while True:
            k += 1
            deadline = t0 + k * PERIOD
            if deadline - t0 > seconds:
                break
            while (r := deadline - time.perf_counter()) > 0.0005:
                time.sleep(r - 0.0005)
            while time.perf_counter() < deadline:
                pass
            late.append((time.perf_counter() - deadline) * 1e6)
            a = time.perf_counter()
            inp.poll(k * PERIOD)
            polls.append((time.perf_counter() - a) * 1e6)
    finally:
        if fifo:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    late.sort()
    polls.sort()

    def q(s, p):
        return s[min(len(s) - 1, int(p * len(s)))]

    n = len(late)
    return q(late, 0.5), q(late, 0.99), late[-1], q(polls, 0.5), q(polls, 0.99), polls[-1], n


_SENDER = """import socket, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
end, n = time.time() + {seconds}, 0
while time.time() < end:
    for _ in range(100):
        s.sendto(b"\\xff" * 24, ("127.0.0.1", {port}))
    n += 100
print(n)
"""


def bench_flood(seconds: float, cap: float, fifo: int) -> None:
    rx_kw = {"max_rx_per_s": cap} if cap else {}
    for case in ("quiet", "flood to a socket nobody reads", "flood to the OSC receiver"):
        inp = OscInput(JOINTS)
        rx = listen(inp, 0, clock=time.perf_counter, **rx_kw)
        sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sink.bind(("127.0.0.1", 0))
        port = rx.address[1] if case.endswith("receiver") else sink.getsockname()[1]
        proc = None
        if case != "quiet":  # started before the poller may turn SCHED_FIFO: it must not inherit it
            code = _SENDER.format(seconds=seconds + 0.5, port=port)
            proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
        r = _loop(inp, seconds, fifo)
        sent = int(proc.communicate()[0]) if proc else 0
        rx.close()
        sink.close()
        d = inp.guard.drops.snapshot()
        print(
            f"{case}: lateness p50 {r[0]:.0f} p99 {r[1]:.0f} max {r[2]:.0f} µs over {r[6]} ticks; "
            f"poll p50 {r[3]:.1f} p99 {r[4]:.1f} max {r[5]:.1f} µs; sent {sent}; counted "
            f"malformed {d['malformed']} flood {d['flood']} socket_overflow "
            f"{d['socket_overflow']} (total {inp.guard.drops.total})"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--cap", type=float, default=0.0)
    ap.add_argument("--fifo", type=int, default=0)
    ap.add_argument("--switch", type=float, default=100e-6)
    args = ap.parse_args()
    sys.setswitchinterval(args.switch)
    with open("/proc/loadavg") as f:
        print(f"load {f.read().strip()}; GIL switch interval {sys.getswitchinterval():g} s")
    bench_feed()
    bench_poll()
    bench_flood(args.seconds, args.cap, args.fifo)


if __name__ == "__main__":
    main()
