"""Health in the tick's own read (X series): the tick block through indirect addresses.

Each servo's Torque Enable and Bus Watchdog come with its position in the tick's Fast Sync
Read (:mod:`drivers.dynamixel.tick_block`), so every servo is judged every tick and no
transaction of its own reads its health; a reset servo (Indirect Addresses at defaults)
never gives a reading, and the block is written again before a servo rejoins.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dynamixel import DynamixelBus
from drivers.dynamixel.startup import Expectation, ReadMode
from drivers.protocol2 import control_table as ct
from drivers.protocol2 import wire_time
from drivers.servo_bus import HealthProblem, PresentReading, ReadStatus
from hilsim.exit_codes import ExitCode
from hilsim.show.servo_check import use_tick_block
from tests.hilsim.test_fault_matrix import (
    INST,
    TORQUE_ENABLE,
    Wire,
    assert_safe_stop,
    assert_wire_is_telemetry,
)
from tests.hilsim.test_fault_matrix import emulated as emulated  # the fixture

DEMO = Path(__file__).resolve().parents[2] / "configs" / "demo.toml"
PERIOD = 0.004
INDIRECT_ADDRESS_1 = ct.INDIRECT_ADDRESS_1.addr


def _demo_rig() -> str:
    """configs/demo.toml on the fixture's emulated bus (its animation file by full path)."""
    lines = DEMO.read_text().replace(
        '"demo_animation.csv"', f'"{DEMO.with_name("demo_animation.csv")}"'
    )
    return "\n".join(
        'port = "dxlsim://unused"' if line.startswith("port =") else line
        for line in lines.splitlines()
    )


def _show_txs(wire: Wire) -> list:
    """The transactions from the first read of the tick block to the last Sync Write of
    goals: the show from torque on."""
    first = next(
        i for i, tx in enumerate(wire.txs) if tx.inst == INST.FAST_SYNC_READ and tx.addr == 224
    )
    return wire.txs[first : wire.last_sync_write + 2]  # (+ its read)


def test_a_20_s_demo_reads_no_health_of_its_own(emulated):
    emu = emulated(_demo_rig(), ids=(1, 2, 3, 4))
    assert emu.run(duration=20.0) == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    show = _show_txs(wire)
    reads = [tx for tx in show if tx.inst == INST.READ]
    # no read of torque, hardware error or Bus Watchdog: every tick's Fast Sync Read carries
    # them; what is left is temperature, voltage and load, each servo's about once a second
    assert {(tx.addr, tx.params[2]) for tx in reads} == {
        (ct.CONDITION_BLOCK.addr, ct.CONDITION_BLOCK.size)
    }
    per_servo = [sum(tx.id == sid for tx in reads) for sid in (1, 2, 3, 4)]
    assert all(15 <= c <= 21 for c in per_servo), per_servo
    ticks = [tx for tx in show if tx.inst == INST.FAST_SYNC_READ]
    assert len(ticks) == run.n_ticks  # (the first is tick 0's)
    assert {(tx.addr, tx.params[2]) for tx in ticks} == {(224, ct.TICK_BLOCK_SIZE)}
    assert {tx.inst for tx in show} == {INST.SYNC_WRITE, INST.FAST_SYNC_READ, INST.READ}
    assert_wire_is_telemetry(emu, run, wire)  # each reading is what its servo sent


def test_a_torque_cut_is_seen_within_two_ticks(emulated):
    emu = emulated(faults="torque_off:id=2,at=1.0")
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)", "torque off")
    cut = emu.show_time(run, 1.0)
    # the fault's tick is the last row: its read came after the cut, at most 2 ticks after
    assert cut <= run.columns["t_actual"][-1] + PERIOD
    assert run.t_sched[-1] - cut <= 2 * PERIOD
    # no read of torque before the fault: only the figures (temperature, voltage, load)
    reads = [tx for tx in _show_txs(wire)[:-1] if tx.inst == INST.READ]
    assert {tx.addr for tx in reads} <= {ct.CONDITION_BLOCK.addr}


def test_a_reboot_mid_show_stops_it_and_the_next_start_sets_the_block_first(emulated):
    emu = emulated(faults="brownout:id=2,at=1.0,duration=0.03")
    assert emu.run() == ExitCode.FAULT
    run, wire = emu.read(), Wire.of(emu.bus)
    assert_safe_stop(emu, run, wire, "servo 2 (tail)", "reset")
    assert "Indirect Addresses are back at their defaults" in run.summary["exit_reason"]
    # the reset block's zeros (tick 0: -180 deg) are never a reading
    present, status = run.joint("present"), run.joint("status")
    back = run.columns["t_actual"] >= emu.show_time(run, 1.03)
    assert np.isnan(present[back, 1]).all() and (status[back, 1] != ReadStatus.OK).all()
    assert_wire_is_telemetry(emu, run, wire)
    first = len(wire.txs)

    # the next start: the servo's Indirect Addresses are written and read back before its
    # torque goes on, and the show runs with its health in every read
    emu.out = emu.out.with_name(emu.out.name + "-again")
    assert emu.run() == ExitCode.OK
    txs = Wire.of(emu.bus).txs[first:]
    sets = [
        i
        for i, tx in enumerate(txs)
        if tx.inst == INST.WRITE and tx.addr == INDIRECT_ADDRESS_1 and tx.id == 2
    ]
    torque_on = next(i for i, tx in enumerate(txs) if tx.write() == (2, TORQUE_ENABLE, 1))
    assert len(sets) == 1 and sets[0] < torque_on
    assert txs[sets[0]].params[2:] == ct.tick_block_targets()
    again = [
        tx
        for tx in txs[sets[0] + 1 : torque_on]
        if tx.inst == INST.READ and tx.id == 2 and tx.addr == INDIRECT_ADDRESS_1
    ]
    assert again  # read back
    assert (
        not [  # the others' were the block's already: read, not written
            tx
            for tx in txs
            if tx.inst == INST.WRITE and tx.addr == INDIRECT_ADDRESS_1 and tx.id != 2
        ]
    )


# ============================================================================ the bus alone
@pytest.fixture
def block_bus():
    """A DynamixelBus on three emulated XM430s, checked, tick block planned."""
    name = "tickhealth"
    servos = [
        VirtualServo("XM430-W350", i, baud=1_000_000, return_delay_us=0, t=0.0) for i in (1, 2, 3)
    ]
    register_bus(name, DxlBus(servos, baud=1_000_000, clock=VirtualClock(), trace=True))
    bus = DynamixelBus.open(f"dxlsim://{name}", baud=1_000_000, ids=(1, 2, 3))
    try:
        bus.check([Expectation(i) for i in (1, 2, 3)])
        bus.use_tick_block()
        yield bus
    finally:
        bus.close()
        unregister_bus(name)


def test_the_block_carries_what_the_registers_hold(block_bus):
    bus, link = block_bus, block_bus.link
    reading = PresentReading.empty(bus.ids)
    bus.read_present(reading)
    assert bus.tick_health is None  # before torque on: positions alone
    bus.set_torque(True)
    bus.arm_watchdog(0.1)
    bus.read_present(reading)
    assert reading.all_ok and bus.tick_health == bus.tick_health_ok
    for k, sid in enumerate(bus.ids):
        tick = link.read_item(sid, ct.PRESENT_POSITION)
        assert math.isclose(reading.positions[k], (tick - 2048) * 2 * math.pi / 4096)
        assert link.read(sid, 224, 7) == (
            link.read(sid, 132, 4)
            + link.read(sid, 64, 1)
            + link.read(sid, 98, 1)
            + link.read(sid, 68, 1)
        )
    link.write_item(3, ct.TORQUE_ENABLE, 0)  # torque cut behind the show's back
    bus.read_present(reading)
    assert reading.all_ok  # a valid reading, and the cut seen in the same read
    assert bus.tick_health_of(2).problem is HealthProblem.TORQUE_OFF
    assert bus.tick_health_of(0).problem is None


def test_a_rebooted_servo_gives_no_reading_until_its_recovery_restores_the_block(block_bus):
    bus, link = block_bus, block_bus.link
    reading = PresentReading.empty(bus.ids)
    bus.set_torque(True)
    bus.arm_watchdog(0.1)
    link.reboot(2)  # RAM at defaults: torque off, watchdog 0, Indirect Addresses their own
    bus.clock.wait_until(bus.clock.now() + 0.01)
    bus.read_present(reading)
    assert reading.status.tolist() == [ReadStatus.OK, ReadStatus.STALE, ReadStatus.OK]
    assert math.isnan(reading.positions[1])
    health = bus.tick_health_of(1)
    assert health.problem is HealthProblem.RESET and "Indirect Addresses" in health.detail
    bus.recover_watchdog(2, 0.0)  # the recovery path: the block is set again first
    assert link.read(2, INDIRECT_ADDRESS_1, 14) == ct.tick_block_targets()
    bus.read_present(reading)
    assert reading.status[1] == ReadStatus.OK and bus.tick_health is not None
    assert bus.tick_health_of(1).problem is HealthProblem.TORQUE_OFF  # (torque not back)


# ============================================================================ the bus's room
def _fake_bus(baud: int) -> SimpleNamespace:
    calls: list[str] = []
    return SimpleNamespace(
        read_mode=ReadMode.FAST,
        link=SimpleNamespace(baud=baud),
        tick_block_possible=lambda: True,
        use_tick_block=lambda: calls.append("use"),
        calls=calls,
    )


def test_the_block_is_used_only_where_the_tick_has_room_for_it():
    # 16 servos at 4 Mbit/s, Return Delay 0, no latency: 670 us a cycle, 790 us with the block
    n, baud = 16, 4_000_000
    report = SimpleNamespace(servos=[SimpleNamespace(return_delay_us=0.0)] * n)
    cycle = wire_time.cycle_time_s(n, baud, True)
    with_block = wire_time.cycle_time_s(n, baud, True, read_data_bytes=ct.TICK_BLOCK_SIZE)
    assert round(cycle * 1e6) == 670 and round(with_block * 1e6) == 790
    roomy, tight = _fake_bus(baud), _fake_bus(baud)
    rig = SimpleNamespace(bus=SimpleNamespace(health_in_tick=True))
    assert use_tick_block(rig, roomy, report, 0.8e-3, 0.0) == []  # type: ignore[arg-type]
    assert roomy.calls == ["use"]
    notes = use_tick_block(rig, tight, report, 0.75e-3, 0.0)  # type: ignore[arg-type]
    assert tight.calls == []
    assert len(notes) == 1 and notes[0].startswith("health read between ticks")
    assert "0.79 ms" in notes[0]


def test_a_rig_may_keep_the_health_out_of_the_tick(emulated, capsys):
    """`bus.health_in_tick = false`: positions only in the tick, the health between ticks
    (the host keeps the 3 bytes a servo's wire time), and the start-up says so."""
    rig = _demo_rig().replace("[bus]", "[bus]\nhealth_in_tick = false", 1)
    assert "health_in_tick = false" in rig
    emu = emulated(rig, ids=(1, 2, 3, 4))
    assert emu.run(duration=2.0) == ExitCode.OK
    run, wire = emu.read(), Wire.of(emu.bus)
    fast = [tx for tx in wire.txs if tx.inst == INST.FAST_SYNC_READ]
    assert fast and {(tx.addr, tx.params[2]) for tx in fast} == {
        (ct.PRESENT_POSITION.addr, ct.PRESENT_POSITION.size)
    }
    assert run.summary["loop"]["health_every_tick"] is False
    assert run.summary["loop"]["health_reads"] > 0
    assert (
        "note: health read between ticks: `bus.health_in_tick = false`" in capsys.readouterr().err
    )


def test_the_wire_model_counts_the_blocks_bytes():
    # write 14 + 5N, request 14 + N, reply 8 + 11N: 36 + 17N
    assert wire_time.cycle_bytes(4, True, 4, ct.TICK_BLOCK_SIZE) == 36 + 17 * 4
    assert wire_time.cycle_bytes(4, True) == 36 + 14 * 4


# ============================================================================ the parser
def _reply(blocks: list[tuple[int, int, int, int, int, int]]) -> bytes:
    """A Fast Sync Read reply of tick blocks (ERR, ID, position, torque, watchdog, marker),
    each block's CRC running over the packet up to it, as the servos send it."""
    from drivers.protocol2.crc import crc16

    size = len(blocks) * 11 + 3
    out = bytearray(b"\xff\xff\xfd\x00\xfe" + size.to_bytes(2, "little") + b"\x55")
    for err, sid, position, torque, wd, marker in blocks:
        out += bytes((err, sid)) + position.to_bytes(4, "little", signed=True)
        out += bytes((torque, wd & 0xFF, marker))
        out += crc16(bytes(out)).to_bytes(2, "little")
    return bytes(out)


def test_the_parser_keeps_blocks_while_each_is_whole_and_never_a_reset_ones_position():
    from drivers.dynamixel import tick_block

    n = 4
    blocks = [
        (0, 1, 2048, 1, 5, 2),
        (0, 2, 1000, 0, -1, 2),
        (0, 3, 0, 0, 0, 0),
        (0x80, 4, 7, 1, 5, 2),
    ]
    packet = _reply(blocks)
    pos, status, errors, state = [math.nan] * n, [1] * n, [0] * n, [-1] * n
    assert (
        tick_block.parse_block_reply(packet, [1, 2, 3, 4], [0, 1, 2, 3], pos, status, errors, state)
        == 4
    )
    assert pos[0] == 0.0 and math.isclose(pos[1], (1000 - 2048) * 2 * math.pi / 4096)
    assert math.isnan(pos[2]) and status == [0, 0, 1, 3]  # the reset block: no reading
    assert [tick_block.unpack(s) for s in state] == [(1, 5, 2), (0, -1, 2), (0, 0, 0), (1, 5, 2)]
    assert errors[3] == 0x80  # Alert: a hardware error, the reading valid
    # a flipped bit in the third block: it and the blocks after it are no reading
    bad = bytearray(packet)
    bad[8 + 2 * 11 + 4] ^= 1
    pos, status, errors, state = [math.nan] * n, [1] * n, [0] * n, [-1] * n
    assert (
        tick_block.parse_block_reply(
            bytes(bad), [1, 2, 3, 4], [0, 1, 2, 3], pos, status, errors, state
        )
        == 2
    )
    assert status[2:] == [1, 1] and state[2:] == [-1, -1]
    # another order asked: the first block's ID is not the one asked first
    assert (
        tick_block.parse_block_reply(packet, [2, 1, 3, 4], [1, 0, 2, 3], pos, status, errors, state)
        == 0
    )
