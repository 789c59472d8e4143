"""The steps of dynamixel-sdk's protocol 2.0 example programs, as programs of our own, on the
README's ``dxlsim://`` URL (virtual clock: nothing waits) and, for the baud behaviour, on a
``hilsim emulate`` pty in a subprocess (behaviour only, never speed)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import dynamixel_sdk as sdk
import pytest

from drivers.dynamixel.port import PortHandler

URL = "dxlsim://?ids=1-2&model=XM430-W350&rdt_us=0&clock=virtual"
GOAL, PRESENT, TORQUE, BAUD_RATE, OP_MODE = 116, 132, 64, 8, 11  # e-Manual x/xm430-w350.md


@pytest.fixture
def port():
    p = PortHandler(URL)
    assert p.openPort()
    assert p.setBaudRate(1_000_000)  # every SDK example: openPort() then setBaudRate()
    yield p
    p.closePort()


PH = sdk.PacketHandler(2.0)


def test_open_then_set_baud_rate_keeps_the_servos(port):
    """e-Manual protocol2.md, Ping; the SDK's setBaudRate re-opens the port: same servos."""
    assert PH.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)
    assert PH.write1ByteTxRx(port, 1, 65, 1) == (sdk.COMM_SUCCESS, 0)  # LED(65)
    assert port.setBaudRate(1_000_000)
    assert PH.read1ByteTxRx(port, 1, 65) == (1, sdk.COMM_SUCCESS, 0)
    assert sorted(PH.broadcastPing(port)[0]) == [1, 2]


def test_host_at_another_baud_gets_no_reply(port):
    """e-Manual x/xm430-w350.md Baud Rate(8): the servo listens at its own rate only."""
    assert port.setBaudRate(57_600)
    assert PH.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert port.setBaudRate(1_000_000)
    assert PH.ping(port, 1)[1] == sdk.COMM_SUCCESS


def test_write_read_sync_and_bulk(port):
    """e-Manual protocol2.md: Write, Read, Sync Write, Sync Read, Fast Sync Read, Bulk Read,
    Fast Bulk Read (the read_write, sync_read_write, fast_sync_read, bulk_read_write and
    fast_bulk_read examples)."""
    for i in (1, 2):
        assert PH.write1ByteTxRx(port, i, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)
    sw = sdk.GroupSyncWrite(port, PH, GOAL, 4)
    for i in (1, 2):
        sw.addParam(i, (3000).to_bytes(4, "little"))
    assert sw.txPacket() == sdk.COMM_SUCCESS
    port.clock.advance(3.0)  # the virtual clock: the move is over
    for fast in (False, True):
        sr = sdk.GroupSyncRead(port, PH, PRESENT, 4)
        for i in (1, 2):
            sr.addParam(i)
        assert (sr.fastSyncRead() if fast else sr.txRxPacket()) == sdk.COMM_SUCCESS
        assert all(abs(sr.getData(i, PRESENT, 4) - 3000) <= 20 for i in (1, 2))
        br = sdk.GroupBulkRead(port, PH)
        for i in (1, 2):
            br.addParam(i, PRESENT, 4)
        assert (br.fastBulkRead() if fast else br.txRxPacket()) == sdk.COMM_SUCCESS
        assert all(abs(br.getData(i, PRESENT, 4) - 3000) <= 20 for i in (1, 2))
    assert PH.read4ByteTxRx(port, 1, GOAL) == (3000, sdk.COMM_SUCCESS, 0)


def test_reboot_factory_reset_and_baud_rate(port):
    """e-Manual protocol2.md, Reboot and Factory Reset (0x01: all but ID); x/xm430-w350.md
    Baud Rate(8): after the reset the servo answers at 57 600 only (the factory_reset
    example switches the host there, writes Baud Rate 3 and comes back to 1 Mbit/s)."""
    assert PH.write1ByteTxRx(port, 1, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)
    assert PH.reboot(port, 1) == (sdk.COMM_SUCCESS, 0)
    assert PH.read1ByteTxRx(port, 1, TORQUE) == (0, sdk.COMM_SUCCESS, 0)  # RAM to defaults
    assert PH.factoryReset(port, 1, 0x01) == (sdk.COMM_SUCCESS, 0)
    port.clock.advance(2.0)
    assert PH.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT  # now at 57 600
    assert port.setBaudRate(57_600)
    assert PH.read1ByteTxRx(port, 1, BAUD_RATE) == (1, sdk.COMM_SUCCESS, 0)
    assert PH.write1ByteTxRx(port, 1, BAUD_RATE, 3) == (sdk.COMM_SUCCESS, 0)
    assert port.setBaudRate(1_000_000)
    assert PH.read1ByteTxRx(port, 1, BAUD_RATE) == (3, sdk.COMM_SUCCESS, 0)


def test_clear_multi_turn(port):
    """e-Manual protocol2.md, Clear (multi-turn): Extended Position Control Mode (4), stopped."""
    assert PH.write1ByteTxRx(port, 1, OP_MODE, 4) == (sdk.COMM_SUCCESS, 0)
    assert PH.write1ByteTxRx(port, 1, TORQUE, 1) == (sdk.COMM_SUCCESS, 0)
    assert PH.write4ByteTxRx(port, 1, GOAL, 4096 * 2 + 100) == (sdk.COMM_SUCCESS, 0)
    port.clock.advance(5.0)
    assert PH.read4ByteTxRx(port, 1, PRESENT)[0] > 4096
    assert PH.clearMultiTurn(port, 1) == (sdk.COMM_SUCCESS, 0)
    assert PH.read4ByteTxRx(port, 1, PRESENT)[0] < 4096


def test_scan_on_a_pty_finds_each_servo_at_the_bus_rate_only():
    """e-Manual x/xm430-w350.md Baud Rate(8): ``hilsim scan`` on a ``hilsim emulate`` pty
    served at 1 Mbit/s lists each servo at 1 Mbit/s and at no other rate."""
    emu = subprocess.Popen(
        [sys.executable, "-m", "hilsim", "emulate", "--ids", "1,2", "--baud", "1000000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        path = emu.stdout.readline().strip()
        assert path.startswith("/dev/")
        scan = subprocess.run(
            [sys.executable, "-m", "hilsim", "scan", "--port", path, "--ids", "1-3",
             "--baud", "57600", "--baud", "1M", "--baud", "4M", "--no-unicast"],
            capture_output=True,
            text=True,
            timeout=120,
        )  # fmt: skip
        lines = scan.stdout.splitlines()
        assert scan.returncode == 0, scan.stderr
        assert [line.split("@")[1].split()[0] for line in lines] == ["1000000", "1000000"]
    finally:
        os.kill(emu.pid, signal.SIGTERM)
        emu.wait(timeout=30)
