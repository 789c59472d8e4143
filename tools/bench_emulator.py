"""Wall-clock throughput of the emulator in virtual time (issue 3 benchmark; not a test).

Each cycle is what the real-time loop does per tick: one Sync Write of goal positions
and one (Fast) Sync Read of present positions, through the unmodified dynamixel-sdk and
the dxlsim:// PortHandler, with servos moving. Prints cycles per wall-clock second and
how much faster than real time a show at RATE Hz would rehearse.

    python tools/bench_emulator.py [--servos 4] [--rate 500] [--cycles 5000] [--plain]

``--direct`` measures the emulator alone: no SDK, no PortHandler. It drives a
:class:`~drivers.dxlsim.DxlBus` with precomputed packet bytes as a host would (per cycle
one Sync Write of 4-byte goals that change every cycle, the servos moving, and one Fast
Sync Read of Present Position; the virtual clock jumps to the cycle's deadline, then to
when the whole reply is readable through a USB adapter with ``--latency-ms``, and every
reply byte is read) and prints µs per emulated Sync Write + Fast Sync Read, best of
``--repeats`` runs, for 4 and 16 servos at 1 and 4 Mbit/s (or ``--servos``/``--baud``
when given):

    python tools/bench_emulator.py --direct [--repeats 7] [--cycles 2000] [--rate 250]

``--block`` (with ``--direct``) reads what a show's tick reads on X series: each servo's
Indirect Address 1..7 pointed at the tick block (Present Position, Torque Enable, Bus
Watchdog, Status Return Level) once, then a Fast Sync Read of Indirect Data 1..7 per cycle.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import os
import pstats
import time

import dynamixel_sdk as sdk

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus
from drivers.dxlsim.protocol import Instruction, encode_instruction
from drivers.protocol2 import control_table as ct

GOAL_POSITION, PRESENT_POSITION, TORQUE_ENABLE = 116, 132, 64


def _goal(k: int, period: float) -> int:
    return int(2048 + 800 * math.sin(2 * math.pi * 0.5 * k * period))


def direct_cycles(
    n_servos: int, baud: int, rate: float, cycles: int, latency_ms: float, block: bool = False
) -> tuple:
    """One run of the emulator alone: returns (wall s per cycle, failed cycles, bus); with
    ``block`` the read is the tick block's, through Indirect Data."""
    clock = VirtualClock()
    ids = list(range(1, n_servos + 1))
    servos = [VirtualServo("XM430-W350", i, baud=baud, return_delay_us=0, t=0.0) for i in ids]
    bus = DxlBus(servos, baud=baud, clock=clock, latency_timer_ms=latency_ms)
    period = 1.0 / rate
    setup = [bytes((TORQUE_ENABLE, 0, 1))]  # torque on (and the block), one Write each
    if block:
        at = ct.INDIRECT_ADDRESS_1.addr
        setup.insert(0, bytes((at & 0xFF, at >> 8)) + ct.tick_block_targets())
    for i in ids:
        for params in setup:  # each reply read like any other
            bus.write(encode_instruction(i, Instruction.WRITE, params))
            clock.wait_until(bus.visible_at(bus.pending_rx))
            bus.read(bus.pending_rx)
    # Precomputed host bytes: a Sync Write per cycle of one period of the 0.5 Hz sine (the
    # goals move every cycle) ...
    head = bytes((GOAL_POSITION & 0xFF, GOAL_POSITION >> 8, 4, 0))
    writes = []
    for k in range(min(cycles, max(1, round(2.0 * rate)))):
        goal = _goal(k, period).to_bytes(4, "little")
        body = b"".join(bytes((i,)) + goal for i in ids)
        writes.append(encode_instruction(0xFE, Instruction.SYNC_WRITE, head + body))
    # ... and the same Fast Sync Read of Present Position (or the block) every cycle.
    addr, size = (ct.INDIRECT_DATA_1.addr, ct.TICK_BLOCK_SIZE) if block else (PRESENT_POSITION, 4)
    fast_read = encode_instruction(
        0xFE, Instruction.FAST_SYNC_READ, bytes((addr & 0xFF, addr >> 8, size, 0, *ids))
    )
    reply = 8 + (4 + size) * n_servos  # header, ID, LEN, INST + per servo ERR ID data CRC(2)
    failures = 0
    deadline = clock.now()
    n_writes = len(writes)
    t0 = time.perf_counter()
    for k in range(cycles):
        packet = writes[k % n_writes]
        deadline += period
        clock.wait_until(deadline)
        bus.write(packet)
        bus.write(fast_read)
        due = bus.visible_at(reply)
        if due is None:
            failures += 1
            continue
        clock.wait_until(due)
        failures += len(bus.read(reply)) != reply
    wall = time.perf_counter() - t0
    return wall / cycles, failures, bus


def direct(args) -> int:
    combos = [
        (n, b)
        for n in ([args.servos] if args.servos_given else [4, 16])
        for b in ([args.baud] if args.baud_given else [1_000_000, 4_000_000])
    ]
    print(
        f"emulator alone (DxlBus, no SDK): Sync Write + Fast Sync Read"
        f"{' of the tick block' if args.block else ''} per cycle, "
        f"{args.cycles} cycles at {args.rate:g} Hz virtual, latency timer {args.latency_ms:g} "
        f"ms, best of {args.repeats}; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    failed = 0
    for n, baud in combos:
        runs = []
        for _ in range(args.repeats):
            per_cycle, failures, bus = direct_cycles(
                n, baud, args.rate, args.cycles, args.latency_ms, args.block
            )
            runs.append(per_cycle)
            failed += failures
        moved = [s.now for s in bus.servos]
        print(
            f"  {n:2d} servos {baud / 1e6:g} Mbit/s: best {min(runs) * 1e6:7.1f} µs/cycle, "
            f"median {sorted(runs)[len(runs) // 2] * 1e6:7.1f}, "
            f"{bus.stats['instructions']} instructions, {failures} failed, "
            f"servo time {min(moved):.3f} s"
        )
    return 0 if failed == 0 else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--servos", type=int, default=None)
    ap.add_argument("--rate", type=float, default=None, help="virtual loop rate, Hz")
    ap.add_argument("--cycles", type=int, default=None)
    ap.add_argument("--baud", type=int, default=None)
    ap.add_argument("--plain", action="store_true", help="plain Sync Read instead of Fast")
    ap.add_argument("--profile", action="store_true", help="print the top cProfile entries (SDK)")
    ap.add_argument("--direct", action="store_true", help="the emulator alone, no SDK")
    ap.add_argument("--repeats", type=int, default=7, help="--direct: runs per case")
    ap.add_argument("--block", action="store_true", help="--direct: read the tick block")
    ap.add_argument("--latency-ms", type=float, default=1.0, help="--direct: USB latency timer")
    args = ap.parse_args(argv)
    args.servos_given, args.baud_given = args.servos is not None, args.baud is not None
    if args.direct:
        args.servos = args.servos or 4
        args.baud = args.baud or 1_000_000
        args.rate = args.rate or 250.0
        args.cycles = args.cycles or 2000
        return direct(args)
    args.servos = args.servos or 4
    args.baud = args.baud or 1_000_000
    args.rate = args.rate or 500.0
    args.cycles = args.cycles or 5000
    from drivers.dynamixel.port import PortHandler  # the SDK path only

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
