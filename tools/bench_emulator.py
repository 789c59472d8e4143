"""Wall-clock throughput of the emulator in virtual time (issue 3 benchmark; not a test).

Each cycle is what the real-time loop does per tick: one Sync Write of goal positions
and one (Fast) Sync Read of present positions, through the unmodified dynamixel-sdk and
the dxlsim:// PortHandler, with servos moving. Prints cycles per wall-clock second and
how much faster than real time a show at RATE Hz would rehearse.

    python tools/bench_emulator.py [--servos 4] [--rate 500] [--cycles 5000] [--plain]
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import time

import dynamixel_sdk as sdk

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus
from drivers.dynamixel.port import PortHandler


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--servos", type=int, default=4)
    ap.add_argument("--rate", type=float, default=500.0, help="virtual loop rate, Hz")
    ap.add_argument("--cycles", type=int, default=5000)
    ap.add_argument("--baud", type=int, default=1_000_000)
    ap.add_argument("--plain", action="store_true", help="plain Sync Read instead of Fast")
    ap.add_argument("--profile", action="store_true", help="print the top cProfile entries")
    args = ap.parse_args(argv)

    clock = VirtualClock()
    ids = list(range(1, args.servos + 1))
    servos = [VirtualServo("XM430-W350", i, baud=args.baud, return_delay_us=0, t=0.0) for i in ids]
    bus = DxlBus(servos, baud=args.baud, clock=clock)
    port = PortHandler(register_bus("bench", bus), latency_timer_ms=1.0)
    port.setBaudRate(args.baud)
    port.openPort()
    ph = sdk.PacketHandler(2.0)
    for i in ids:
        ph.write1ByteTxRx(port, i, 64, 1)
    writer = sdk.GroupSyncWrite(port, ph, 116, 4)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in ids:
        writer.addParam(i, [0, 8, 0, 0])
        reader.addParam(i)
    period = 1.0 / args.rate

    def run(n: int) -> int:
        failures = 0
        deadline = clock.now()
        for k in range(n):
            deadline += period
            clock.wait_until(deadline)
            goal = int(2048 + 800 * math.sin(2 * math.pi * 0.5 * k * period))
            data = list(goal.to_bytes(4, "little"))
            for i in ids:
                writer.changeParam(i, data)
            writer.txPacket()
            result = reader.txRxPacket() if args.plain else reader.fastSyncRead()
            failures += result != sdk.COMM_SUCCESS
        return failures

    run(200)  # warm up
    profiler = cProfile.Profile() if args.profile else None
    t0 = time.perf_counter()
    if profiler:
        profiler.enable()
    failures = run(args.cycles)
    if profiler:
        profiler.disable()
    wall = time.perf_counter() - t0
    rate = args.cycles / wall
    mode = "plain Sync Read" if args.plain else "Fast Sync Read"
    print(f"{args.servos} servos, {mode}, {args.baud} bps, virtual loop at {args.rate:g} Hz")
    print(
        f"  {args.cycles} cycles in {wall:.3f} s wall: {rate:,.0f} cycles/s "
        f"({wall / args.cycles * 1e6:.1f} µs/cycle), {failures} failed"
    )
    print(f"  a {args.rate:g} Hz show rehearses {rate / args.rate:.1f}x faster than real time")
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(15)
    return 0 if failures == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
