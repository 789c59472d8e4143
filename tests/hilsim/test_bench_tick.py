"""``hilsim bench``'s tick cost (hilsim.bench.tick): the instant fake port, the two cycles it
times, and the table's shape. Nothing here asserts a speed or sleeps."""

from __future__ import annotations

import json
import math

import dynamixel_sdk as sdk
import numpy as np
import pytest

from drivers.dxlsim.protocol import parse_fast_status
from drivers.dynamixel.tick_packets import sync_read_request
from drivers.protocol2 import control_table as ct
from drivers.servo_bus import ReadStatus
from hilsim.bench.tick import (
    STAGES,
    BareSdkCycle,
    HilsimTick,
    InstantSerial,
    TickCost,
    TickRow,
    hilsim_port,
    interleaved,
    measure_tick_cost,
    sdk_port,
)

PRESENT = ct.PRESENT_POSITION.addr


def request(ids) -> bytes:
    return sync_read_request(PRESENT, 4, ids, True)


# ------------------------------------------------------------------ the fake port
@pytest.mark.parametrize("ids", [(1,), (1, 2, 3, 4), (7, 3, 250, 0), tuple(range(1, 17))])
def test_the_instant_port_answers_a_fast_sync_read_correctly(ids):
    ser = InstantSerial()
    replies = []
    for _ in range(3):
        assert ser.write(request(ids)) == len(request(ids))
        reply = ser.read(10_000)
        assert ser.read(10) == b""  # one reply per request
        blocks = parse_fast_status(reply, [4] * len(ids))  # the emulator's own parser
        assert [(err, sid, ok) for err, sid, _, ok in blocks] == [(0, i, True) for i in ids]
        replies.append([int.from_bytes(d, "little", signed=True) for *_, d, _ in blocks])
    assert replies[0] != replies[1] != replies[2]  # the positions change
    assert all(abs(t - 2048) <= 20 for r in replies for t in r)
    assert ser.writes == 3 and ser.last_write == request(ids)


def test_the_sdk_takes_the_instant_ports_reply_whole():
    ser, ph = InstantSerial(), sdk.PacketHandler(2.0)
    port = sdk_port(ser)
    assert ph.syncReadTx(port, PRESENT, 4, [2, 5, 9], 3, True) == sdk.COMM_SUCCESS
    packet, result = ph.rxPacket(port, True)
    assert result == sdk.COMM_SUCCESS and len(packet) == 8 + 8 * 3
    assert bytes(packet) == ser.reply((2, 5, 9), 0)


def test_the_instant_port_reads_what_was_asked_and_answers_nothing_else():
    ser = InstantSerial(variants=2)
    ser.write(b"\xff\xff\xfd\x00\x01\x03\x00\x01\x19\x4e")  # a Ping: no reply
    assert ser.read(11) == b"" and ser.in_waiting == 0
    ser.write(request((1, 2)))
    assert len(ser.read(11)) == 11 and ser.in_waiting == 8 + 16 - 11
    ser.reset_input_buffer()
    assert ser.in_waiting == 0
    assert ser.reply((1, 2), 0) == ser.reply((1, 2), 2)  # variants taken in turn
    assert hilsim_port(ser).ser is ser and sdk_port(ser).is_open


# ------------------------------------------------------------------ the two cycles
def test_the_bare_cycle_writes_the_goals_and_reads_the_positions():
    bare = BareSdkCycle(4)
    for _ in range(3):
        bare()
    sent = bare.ser.last_write
    assert sent[7] == 0x8A  # the last packet: the Fast Sync Read
    ticks = [t - 2048 for t in bare.positions]
    assert len(ticks) == 4 and all(abs(t) <= 20 for t in ticks)
    assert bare.ser.writes == 6  # one Sync Write and one Fast Sync Read a cycle


def test_the_hilsim_tick_runs_the_loops_tick_on_the_instant_port(tmp_path):
    tick = HilsimTick(4, tmp_path)
    try:
        for _ in range(50):
            tick()
        loop = tick.loop
        assert loop.reading.status.tolist() == [int(ReadStatus.OK)] * 4
        assert np.all(np.abs(loop.present) < math.radians(3))  # the fake's ±20 ticks
        assert tick.telemetry.rows_recorded == 50 and tick.telemetry.stats.ticks == 50
        assert tick.ser.writes == 2 + 2 * 50  # start-up read and hold, then two a tick
        stages = tick.stages()
        assert list(stages) == list(STAGES)
        for call in stages.values():
            call()
        tick.between_rounds()
        assert tick.telemetry._ring.pending() == 0
    finally:
        tick.close()


# ------------------------------------------------------------------ measuring and the table
def test_interleaved_takes_each_calls_median_and_the_best_round():
    cost = {"a": iter([1, 1, 9, 2, 2, 2]), "b": iter([5, 5, 5, 1, 1, 1])}
    clock_now = [0.0]

    def clock() -> float:
        return clock_now[0]

    def call(name):
        def run():
            clock_now[0] += next(cost[name])

        return run

    best = interleaved({"a": call("a"), "b": call("b")}, rounds=2, reps=3, clock=clock)
    assert best == {"a": 1.0, "b": 1.0}  # medians (1, 2) and (5, 1): the least of each


def test_the_table_and_its_json(tmp_path):
    cost = measure_tick_cost((2, 3), rounds=1, reps=3)
    assert [r.servos for r in cost.rows] == [2, 3]
    for r in cost.rows:
        assert r.bare_sdk_us > 0 and r.tick_us > 0 and r.ratio == r.tick_us / r.bare_sdk_us
        assert set(r.stages_us) == {*STAGES, "rest"} and r.stages_us["rest"] >= 0
    text = cost.text()
    head = text.splitlines()[1].split()
    assert head == ["servos", "bare", "SDK", "µs", "hilsim", "tick", "µs", "ratio"]
    assert len(text.splitlines()[2].split()) == 4
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({"command": "hilsim bench"}))
    cost.add_to_json(path)
    d = json.loads(path.read_text())
    assert d["command"] == "hilsim bench"
    rows = d["tick_cost"]["rows"]
    assert [r["servos"] for r in rows] == [2, 3] and {"bare_sdk_us", "tick_us", "ratio"} <= set(
        rows[0]
    )


def test_the_table_has_no_internal_target_and_nan_becomes_null(tmp_path):
    cost = TickCost([TickRow(4, 10.0, 12.0), TickRow(16, 20.0, math.nan)], rounds=1, reps=1)
    lines = cost.text().splitlines()
    assert "target" not in cost.text() and lines[2].split() == ["4", "10.0", "12.0", "1.20"]
    assert "ratio: hilsim's whole tick" in lines[0] and "no servo" in lines[0]
    path = tmp_path / "b.json"
    path.write_text("{}")
    cost.add_to_json(path)
    rows = json.loads(path.read_text())["tick_cost"]["rows"]
    assert rows[1]["tick_us"] is None and "target_ratio" not in rows[0]
