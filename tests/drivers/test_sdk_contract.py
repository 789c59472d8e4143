"""The unmodified dynamixel-sdk against the emulator: one contract, two ways in.

``dxlsim``: ``dxlsim://`` through :class:`drivers.dynamixel.port.PortHandler` (virtual clock).
``pty``:    ``hilsim emulate`` in a subprocess, through the SDK's own ``PortHandler``.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import dynamixel_sdk as sdk
import pytest

from drivers.dxlsim.protocol import ErrorCode, Instruction, encode_instruction

OK = sdk.COMM_SUCCESS
ADDR_MODEL, ADDR_RDT, ADDR_OPERATING_MODE = 0, 9, 11
ADDR_VELOCITY_LIMIT, ADDR_MAX_POS = 44, 48
ADDR_TORQUE, ADDR_LED, ADDR_REGISTERED = 64, 65, 69
ADDR_GOAL_PWM, ADDR_PROFILE_VEL, ADDR_GOAL_POS, ADDR_PRESENT_POS = 100, 112, 116, 132
ADDR_VOLTAGE, ADDR_TEMPERATURE = 144, 146
XM430_W350 = 1020


def err_number(error: int) -> int:
    return error & 0x7F


def test_ping_each_servo(session):
    for dxl_id in (1, 2, 3, 4):
        model, result, error = session.ph.ping(session.port, dxl_id)
        assert (model, result, error) == (XM430_W350, OK, 0)


def test_broadcast_ping_finds_everyone(session):
    found, result = session.ph.broadcastPing(session.port)
    assert result == OK
    assert sorted(found) == [1, 2, 3, 4]
    assert all(model == XM430_W350 for model, _fw in found.values())


def test_absent_id_times_out(session):
    _, result, _ = session.ph.ping(session.port, 9)
    assert result == sdk.COMM_RX_TIMEOUT


def test_one_two_four_byte_reads_and_writes(session):
    ph, port = session.ph, session.port
    assert ph.write1ByteTxRx(port, 2, ADDR_LED, 1) == (OK, 0)
    assert ph.read1ByteTxRx(port, 2, ADDR_LED) == (1, OK, 0)
    assert ph.write2ByteTxRx(port, 2, ADDR_GOAL_PWM, 300) == (OK, 0)
    assert ph.read2ByteTxRx(port, 2, ADDR_GOAL_PWM) == (300, OK, 0)
    assert ph.write4ByteTxRx(port, 2, ADDR_PROFILE_VEL, 77) == (OK, 0)
    assert ph.read4ByteTxRx(port, 2, ADDR_PROFILE_VEL) == (77, OK, 0)
    assert ph.read2ByteTxRx(port, 2, ADDR_MODEL) == (XM430_W350, OK, 0)
    volts, result, _ = ph.read2ByteTxRx(port, 2, ADDR_VOLTAGE)
    assert result == OK and 90 <= volts <= 160  # 0.1 V units
    # other servos untouched
    assert ph.read1ByteTxRx(port, 3, ADDR_LED) == (0, OK, 0)


def test_eeprom_write_with_torque_on_is_access_error(session):
    ph, port = session.ph, session.port
    assert ph.write1ByteTxRx(port, 1, ADDR_TORQUE, 1) == (OK, 0)
    result, error = ph.write4ByteTxRx(port, 1, ADDR_VELOCITY_LIMIT, 100)
    assert result == OK and err_number(error) == ErrorCode.ACCESS
    assert ph.read4ByteTxRx(port, 1, ADDR_VELOCITY_LIMIT)[0] != 100
    assert ph.write1ByteTxRx(port, 1, ADDR_TORQUE, 0) == (OK, 0)
    assert ph.write4ByteTxRx(port, 1, ADDR_VELOCITY_LIMIT, 100) == (OK, 0)


def test_goal_beyond_position_limit_is_refused(session):
    ph, port = session.ph, session.port
    assert ph.write4ByteTxRx(port, 1, ADDR_MAX_POS, 3000) == (OK, 0)
    assert ph.write1ByteTxRx(port, 1, ADDR_TORQUE, 1) == (OK, 0)
    before = ph.read4ByteTxRx(port, 1, ADDR_GOAL_POS)[0]
    result, error = ph.write4ByteTxRx(port, 1, ADDR_GOAL_POS, 3500)
    assert result == OK and err_number(error) == ErrorCode.DATA_LIMIT
    assert ph.read4ByteTxRx(port, 1, ADDR_GOAL_POS)[0] == before
    assert ph.write4ByteTxRx(port, 1, ADDR_GOAL_POS, 2900) == (OK, 0)


def test_reg_write_waits_for_action(session):
    ph, port = session.ph, session.port
    assert ph.regWriteTxRx(port, 3, ADDR_LED, 1, [1]) == (OK, 0)
    assert ph.read1ByteTxRx(port, 3, ADDR_REGISTERED) == (1, OK, 0)
    assert ph.read1ByteTxRx(port, 3, ADDR_LED) == (0, OK, 0)
    assert ph.action(port, 3) == OK
    # A servo at Status Return Level 2 answers a unicast Action, but the SDK's action()
    # does not wait for that status: collect it here, or the next request receives it.
    port.setPacketTimeout(11)
    status, result = ph.rxPacket(port, False)
    assert result == OK and status[4] == 3 and status[8] == 0
    assert ph.read1ByteTxRx(port, 3, ADDR_LED) == (1, OK, 0)
    assert ph.read1ByteTxRx(port, 3, ADDR_REGISTERED) == (0, OK, 0)


def test_sdk_action_leaves_its_status_for_the_next_request(dxl):
    """A trap in dynamixel-sdk 4.1: action() returns before the servo's status arrives,
    and the next read takes that empty status as its answer (the "data" is its CRC byte)."""
    ph, port = dxl.ph, dxl.port
    assert ph.regWriteTxRx(port, 3, ADDR_LED, 1, [1]) == (OK, 0)
    assert ph.action(port, 3) == OK
    value, result, _ = ph.read1ByteTxRx(port, 3, ADDR_LED)
    assert result == OK and value != 1


def _torque_all(session, value=1):
    for dxl_id in (1, 2, 3, 4):
        assert session.ph.write1ByteTxRx(session.port, dxl_id, ADDR_TORQUE, value) == (OK, 0)


def test_sync_write_then_sync_read(session):
    _torque_all(session)
    goals = {1: 1000, 2: 1500, 3: 2500, 4: 3000}
    writer = sdk.GroupSyncWrite(session.port, session.ph, ADDR_GOAL_POS, 4)
    for dxl_id, goal in goals.items():
        assert writer.addParam(dxl_id, list(goal.to_bytes(4, "little")))
    assert writer.txPacket() == OK
    reader = sdk.GroupSyncRead(session.port, session.ph, ADDR_GOAL_POS, 4)
    for dxl_id in goals:
        reader.addParam(dxl_id)
    assert reader.txRxPacket() == OK
    assert {i: reader.getData(i, ADDR_GOAL_POS, 4) for i in goals} == goals


def test_fast_sync_read(session):
    _torque_all(session)
    writer = sdk.GroupSyncWrite(session.port, session.ph, ADDR_PROFILE_VEL, 4)
    for dxl_id in (1, 2, 3, 4):
        writer.addParam(dxl_id, list((10 * dxl_id).to_bytes(4, "little")))
    assert writer.txPacket() == OK
    reader = sdk.GroupSyncRead(session.port, session.ph, ADDR_PROFILE_VEL, 4)
    for dxl_id in (3, 1, 4, 2):
        reader.addParam(dxl_id)
    assert reader.fastSyncRead() == OK
    assert {i: reader.getData(i, ADDR_PROFILE_VEL, 4) for i in (1, 2, 3, 4)} == {
        1: 10,
        2: 20,
        3: 30,
        4: 40,
    }


def test_bulk_read_and_bulk_write(session):
    writer = sdk.GroupBulkWrite(session.port, session.ph)
    assert writer.addParam(1, ADDR_LED, 1, [1])
    assert writer.addParam(2, ADDR_PROFILE_VEL, 4, list((123).to_bytes(4, "little")))
    assert writer.txPacket() == OK
    reader = sdk.GroupBulkRead(session.port, session.ph)
    assert reader.addParam(1, ADDR_LED, 1)
    assert reader.addParam(2, ADDR_PROFILE_VEL, 4)
    assert reader.addParam(3, ADDR_MODEL, 2)
    assert reader.txRxPacket() == OK
    assert reader.getData(1, ADDR_LED, 1) == 1
    assert reader.getData(2, ADDR_PROFILE_VEL, 4) == 123
    assert reader.getData(3, ADDR_MODEL, 2) == XM430_W350


def test_reboot_resets_ram(session):
    ph, port = session.ph, session.port
    assert ph.write1ByteTxRx(port, 4, ADDR_TORQUE, 1) == (OK, 0)
    assert ph.write1ByteTxRx(port, 4, ADDR_LED, 1) == (OK, 0)
    assert ph.reboot(port, 4) == (OK, 0)
    assert ph.read1ByteTxRx(port, 4, ADDR_TORQUE) == (0, OK, 0)
    assert ph.read1ByteTxRx(port, 4, ADDR_LED) == (0, OK, 0)


def test_factory_reset_keeps_id_and_baud_with_option_2(session):
    ph, port = session.ph, session.port
    assert ph.write1ByteTxRx(port, 2, ADDR_RDT, 10) == (OK, 0)
    assert ph.factoryReset(port, 2, 0x02) == (OK, 0)
    assert ph.read1ByteTxRx(port, 2, ADDR_RDT) == (250, OK, 0)  # factory 500 µs
    assert ph.ping(port, 2)[1] == OK  # still ID 2, still 1 Mbps


def test_corrupted_instruction_is_not_executed(session):
    ph, port = session.ph, session.port
    frame = bytearray(encode_instruction(1, Instruction.WRITE, bytes([ADDR_LED, 0, 1])))
    frame[-1] ^= 0x5A  # break the CRC
    port.clearPort()
    port.writePort(list(frame))
    port.setPacketTimeout(11)
    status, result = ph.rxPacket(port, False)
    assert result == OK
    assert err_number(status[8]) == ErrorCode.CRC
    assert ph.read1ByteTxRx(port, 1, ADDR_LED) == (0, OK, 0)


def test_status_return_level_zero_answers_only_ping(session):
    ph, port = session.ph, session.port
    assert ph.write1ByteTxOnly(port, 3, 68, 0) == OK
    assert ph.write1ByteTxOnly(port, 3, ADDR_LED, 1) == OK
    assert ph.ping(port, 3)[1] == OK
    _, result, _ = ph.read1ByteTxRx(port, 3, ADDR_LED)
    assert result == sdk.COMM_RX_TIMEOUT


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_emulate_serves_until_signalled_and_writes_its_trace(tmp_path, signum):
    trace = tmp_path / "trace.jsonl"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hilsim",
            "emulate",
            "--ids",
            "1",
            "--rdt-us",
            "0",
            "--trace",
            str(trace),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        port = sdk.PortHandler(path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        assert sdk.PacketHandler(2.0).ping(port, 1)[1] == OK
        port.closePort()
        proc.send_signal(signum)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    records = [json.loads(line) for line in trace.read_text().splitlines()]
    assert [r["dir"] for r in records] == ["tx", "rx"]
    assert records[0]["hex"].startswith("ff ff fd 00 01 03 00 01")
    assert records[1]["t_start"] >= records[0]["t_end"]
