"""Third-party clients, unchanged but for the port, against ``hilsim emulate`` of each family.

* Feetech's own Python SDK (PyPI ``feetech-servo-sdk``, module ``scservo_sdk``) on STS3215
  (protocol 0) and SCS0009 (protocol 1: big-endian words);
* ``st3215`` (PyPI), an independent STS3215 library with its own packet code;
* dynamixel-sdk's ``PacketHandler(1.0)`` on AX-12A, and its ``GroupBulkRead`` on MX-28.

Each runs ``hilsim emulate`` in a subprocess and talks to its pseudo-terminal with the
client's own port code. Moves are checked by polling until the goal is read back (bounded
by a deadline; nothing asserts a speed).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator

import pytest

from tests.emulate_pty import emulated_pty

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="no pseudo-terminals")

BAUD = 1_000_000
DEADLINE_S = 20.0


@pytest.fixture
def emulate(request: pytest.FixtureRequest) -> Iterator[str]:
    """``hilsim emulate --ids IDS --model MODEL``; yields the pty path it prints first."""
    ids, model = request.param
    args = ("--ids", ids, "--model", model, "--baud", str(BAUD), "--rdt-us", "0")
    with emulated_pty(*args, timeout_s=10) as (_proc, path):
        yield path


def _until(check: object, what: str) -> None:
    end = time.monotonic() + DEADLINE_S
    while time.monotonic() < end:
        if check():  # type: ignore[operator]
            return
        time.sleep(0.02)
    pytest.fail(f"not within {DEADLINE_S} s: {what}")


@pytest.mark.parametrize("emulate", [("1-6", "STS3215")], indirect=True)
def test_feetech_sdk_drives_sts3215(emulate: str) -> None:
    sc = pytest.importorskip("scservo_sdk")
    port = sc.PortHandler(emulate)
    assert port.openPort() and port.setBaudRate(BAUD)
    ph = sc.PacketHandler(0)
    ids = range(1, 7)
    try:
        for i in ids:
            model, res, err = ph.ping(port, i)
            assert (model, res, err) == (777, sc.COMM_SUCCESS, 0), i
        for i in ids:
            assert ph.write1ByteTxRx(port, i, 40, 1) == (sc.COMM_SUCCESS, 0)  # torque on
        assert ph.read1ByteTxRx(port, 3, 40) == (1, sc.COMM_SUCCESS, 0)
        goals = {i: 1000 + 300 * i for i in ids}
        sw = sc.GroupSyncWrite(port, ph, 42, 2)
        for i in ids:
            assert sw.addParam(i, [sc.SCS_LOBYTE(goals[i]), sc.SCS_HIBYTE(goals[i])])
        assert sw.txPacket() == sc.COMM_SUCCESS
        sr = sc.GroupSyncRead(port, ph, 56, 2)
        for i in ids:
            assert sr.addParam(i)
        seen: dict[int, int] = {}

        def reached() -> bool:
            if sr.txRxPacket() != sc.COMM_SUCCESS:
                return False
            seen.update({i: sr.getData(i, 56, 2) for i in ids})
            return seen == goals

        _until(reached, f"Sync Read of {goals}, last {seen}")
        # Present Speed reads 0 and Moving 0 once there
        assert ph.read2ByteTxRx(port, 1, 58)[0] == 0
        assert ph.read1ByteTxRx(port, 1, 66)[0] == 0
    finally:
        port.closePort()


@pytest.mark.parametrize("emulate", [("1-2", "SCS0009")], indirect=True)
def test_feetech_sdk_speaks_big_endian_to_scs0009(emulate: str) -> None:
    sc = pytest.importorskip("scservo_sdk")
    port = sc.PortHandler(emulate)
    assert port.openPort() and port.setBaudRate(BAUD)
    ph = sc.PacketHandler(1)  # SCS_END = 1: the SDK swaps the bytes of every word
    try:
        assert ph.ping(port, 2) == (1284, sc.COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 2, 40, 1) == (sc.COMM_SUCCESS, 0)
        assert ph.write2ByteTxRx(port, 2, 42, 700) == (sc.COMM_SUCCESS, 0)
        _until(lambda: ph.read2ByteTxRx(port, 2, 56)[0] == 700, "SCS0009 at 700")
        # not a Sync Read servo: the SCS family does not answer 0x82
        sr = sc.GroupSyncRead(port, ph, 56, 2)
        sr.addParam(2)
        assert sr.txRxPacket() != sc.COMM_SUCCESS
    finally:
        port.closePort()
        sc.PacketHandler(0)  # the SDK's byte order is a module global: put it back


@pytest.mark.parametrize("emulate", [("1-3", "STS3215")], indirect=True)
def test_st3215_library_drives_sts3215(emulate: str) -> None:
    st = pytest.importorskip("st3215")
    bus = st.ST3215(emulate)
    try:
        assert all(bus.PingServo(i) for i in (1, 2, 3))
        assert not bus.PingServo(4)
        assert bus.ReadVoltage(1) is not None and bus.ReadTemperature(1) is not None
        for i in (1, 2, 3):
            assert bus.StartServo(i) == (0, 0)  # torque on
        # goals by Sync Write: the library's own group writer (Acceleration, Goal Position,
        # Goal Time, Goal Speed from address 41)
        goals = {1: 1500, 2: 2500, 3: 3000}
        for i, goal in goals.items():
            data = [50, goal & 0xFF, goal >> 8, 0, 0, 2400 & 0xFF, 2400 >> 8]
            assert bus.groupSyncWrite.addParam(i, data)
        assert bus.groupSyncWrite.txPacket() == 0
        # positions by Sync Read: the library's own group reader
        sr = st.group_sync_read.GroupSyncRead(bus, 56, 2)
        for i in goals:
            sr.addParam(i)
        seen: dict[int, int] = {}

        def reached() -> bool:
            if sr.txRxPacket() != 0:
                return False
            for i in goals:
                ok, _ = sr.isAvailable(i, 56, 2)
                if ok:
                    seen[i] = sr.getData(i, 56, 2)
            return seen == goals

        _until(reached, f"Sync Read of {goals}, last {seen}")
        assert bus.MoveTo(2, 1000) is True  # the library's single-servo move
        _until(lambda: bus.ReadPosition(2) == 1000, "MoveTo(2, 1000)")
        # the last half step reads 1000 while the horn still slows: Moving clears at rest
        _until(lambda: bus.IsMoving(2) is False, "IsMoving(2) after MoveTo")
    finally:
        bus.portHandler.closePort()


@pytest.mark.parametrize("emulate", [("1-2", "AX-12A")], indirect=True)
def test_dynamixel_sdk_protocol1_drives_ax12a(emulate: str) -> None:
    sdk = pytest.importorskip("dynamixel_sdk")
    port = sdk.PortHandler(emulate)
    assert port.openPort() and port.setBaudRate(BAUD)
    ph = sdk.PacketHandler(1.0)
    try:
        assert ph.ping(port, 1) == (12, sdk.COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 1, 24, 1) == (sdk.COMM_SUCCESS, 0)  # torque on
        assert ph.write2ByteTxRx(port, 1, 30, 800) == (sdk.COMM_SUCCESS, 0)
        _until(lambda: ph.read2ByteTxRx(port, 1, 36)[0] == 800, "AX-12A at 800")
        res, err = ph.write2ByteTxRx(port, 1, 30, 1024)  # above 1023
        assert res == sdk.COMM_SUCCESS and err & 0x08, err  # Range Error
        assert "Range" in ph.getRxPacketError(err) or err == 0x08
        assert ph.read2ByteTxRx(port, 1, 30)[0] == 800  # refused: the goal is unchanged
        # Sync Write works on P1; GroupSyncRead does not exist there (the SDK refuses it)
        sw = sdk.GroupSyncWrite(port, ph, 30, 2)
        for i, goal in ((1, 300), (2, 700)):
            sw.addParam(i, [sdk.DXL_LOBYTE(goal), sdk.DXL_HIBYTE(goal)])
        ph.write1ByteTxRx(port, 2, 24, 1)
        assert sw.txPacket() == sdk.COMM_SUCCESS
        _until(
            lambda: [ph.read2ByteTxRx(port, i, 36)[0] for i in (1, 2)] == [300, 700],
            "Sync Write goals 300, 700",
        )
    finally:
        port.closePort()


@pytest.mark.parametrize("emulate", [("1-3", "MX-28")], indirect=True)
def test_dynamixel_sdk_bulk_read_on_mx28(emulate: str) -> None:
    sdk = pytest.importorskip("dynamixel_sdk")
    port = sdk.PortHandler(emulate)
    assert port.openPort() and port.setBaudRate(BAUD)
    ph = sdk.PacketHandler(1.0)
    try:
        assert ph.ping(port, 3) == (29, sdk.COMM_SUCCESS, 0)
        br = sdk.GroupBulkRead(port, ph)
        for i in (1, 2, 3):
            assert br.addParam(i, 36, 2)
        assert br.addParam(1, 36, 2) is False  # once per ID
        # dynamixel-sdk 4.1.0's GroupBulkRead.txPacket passes P1's bulkReadTx one argument too
        # many (TypeError); its packet code is sound, so send the request through it directly.
        br.makeParam()
        assert ph.bulkReadTx(port, br.param, 9) == sdk.COMM_SUCCESS
        assert br.rxPacket() == sdk.COMM_SUCCESS
        assert [br.getData(i, 36, 2) for i in (1, 2, 3)] == [2048, 2048, 2048]
    finally:
        port.closePort()
