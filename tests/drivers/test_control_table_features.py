"""Control-table features and instructions of issue 11 (part 3), each against its e-Manual page.

Sources (ROBOTIS-GIT/emanual):

- ``_includes/en/dxl/control_table_indirect_data.md`` and the X-series tables
  (``docs/en/dxl/x/xm430-w350.md``, ``xl430-w250.md``): Indirect Address 1-56 / Indirect
  Data 1-56;
- ``docs/en/dxl/protocol2.md``: the error table (Action without Reg Write), Control Table
  Backup (0x20), the Factory Reset broadcast rule;
- ``_includes/en/dxl/control_table_shadowid.md``: Secondary (Shadow) ID;
- ``_includes/en/dxl/control_table_drivemode.md`` and the XL430-W250 table: Drive Mode range;
- ``control_table_60_startup_configuration.md``, ``control_table_backup_ready.md``.

Every test runs on the virtual clock; nothing sleeps.
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

import drivers.protocol2.control_table as ct
from drivers.dxlsim import VirtualServo, unregister_bus
from drivers.dxlsim.models import MODELS
from drivers.dxlsim.protocol import Instruction, encode_instruction, split_status_stream
from drivers.protocol2.control_table import StatusError
from tests.drivers.conftest import make_bus, open_session
from tests.drivers.test_servo import le

OK = StatusError.NONE
LED, TORQUE, RDT, PROFILE_VELOCITY, GOAL_POSITION = 65, 64, 9, 112, 116
PRESENT_VELOCITY, PRESENT_POSITION = 128, 132
DRIVE_MODE, STARTUP_CONFIGURATION, BACKUP_READY = 10, 60, 147
BACKUP_STORE = b"\x01CTRL"  # P1 0x01, P2-P5 43 54 52 4C
BACKUP_RESTORE = b"\x02CTRL"


def value(servo: VirtualServo, addr: int, size: int, t: float = 0.0) -> int:
    err, data = servo.read(addr, size, t)
    assert err == OK, (addr, err)
    return int.from_bytes(data, "little", signed=size == 4)


def map_indirect(servo: VirtualServo, first: int, targets, t: float = 0.0) -> None:
    """Indirect Address first, first+1, ... := targets (one byte address each)."""
    for k, target in enumerate(targets):
        item = ct.indirect_address(first + k)
        assert servo.write(item.addr, le(target, 2), t) == OK


def transact(bus, packet_id: int, inst: int, params: bytes = b"", wait_s: float = 0.05):
    """One raw instruction on the bus; the status packets it produced (maybe none)."""
    bus.write(encode_instruction(packet_id, inst, params))
    bus.clock.advance(wait_s)
    return split_status_stream(bus.read(100_000))


# --- Indirect Address / Indirect Data ------------------------------------------------------
X430_X540 = sorted(n for n in MODELS if not n.startswith(("XL330", "XC330")))


@pytest.mark.parametrize("name", X430_X540)
def test_indirect_rows_as_the_tables_give_them(name):
    """xm430-w350.md / xl430-w250.md: Indirect Address n (2 bytes, RW, default = Indirect
    Data n's address, range 64-661) at 168.. and 578..; Indirect Data n (1 byte, RW, 0) at
    224.. and 634..; all in the RAM area."""
    m = MODELS[name]
    for n, (addr_at, data_at) in {
        1: (168, 224),
        28: (222, 251),
        29: (578, 634),
        56: (632, 661),
    }.items():
        a, d = m.field(f"indirect_address_{n}"), m.field(f"indirect_data_{n}")
        assert (a.addr, a.size, a.access, a.default, a.lo, a.hi) == (
            addr_at,
            2,
            "RW",
            data_at,
            64,
            661,
        )
        assert (d.addr, d.size, d.access, d.default, d.lo, d.hi) == (data_at, 1, "RW", 0, 0, 255)
        assert not a.eeprom and not d.eeprom
        assert (ct.indirect_address(n).addr, ct.indirect_data(n).addr) == (addr_at, data_at)
    servo = VirtualServo(name, 1)
    assert [value(servo, 168 + 2 * k, 2) for k in range(28)] == list(range(224, 252))
    assert [value(servo, 578 + 2 * k, 2) for k in range(28)] == list(range(634, 662))


def test_a_read_across_field_boundaries_returns_the_default_indirect_addresses():
    """Hardware log, DynamixelSDK issue #148 (XM430-W350): a 4-byte read at 611 returned
    -1,945,990,398 = 02 8B 02 8C, the bytes of the default Indirect Address 45-47."""
    servo = VirtualServo("XM430-W350", 1)
    err, data = servo.read(611, 4, 0.0)
    assert (err, data) == (OK, bytes((0x02, 0x8B, 0x02, 0x8C)))
    assert int.from_bytes(data, "little", signed=True) == -1_945_990_398


def test_indirect_data_stands_for_led_example_1():
    """control_table_indirect_data.md Example 1: Indirect Address 1 := 65 (LED); writing
    Indirect Data 1 turns the LED on and off."""
    servo = VirtualServo("XM430-W350", 1)
    map_indirect(servo, 1, [LED])
    assert servo.write(224, b"\x01", 0.0) == OK
    assert value(servo, LED, 1) == 1 and servo.read(224, 1, 0.0) == (OK, b"\x01")
    assert servo.write(224, b"\x00", 0.0) == OK
    assert value(servo, LED, 1) == 0
    assert servo.write(224, b"\x02", 0.0) == StatusError.DATA_RANGE  # LED's own range 0-1


def test_indirect_goal_position_example_2_and_inherited_properties():
    """Example 2: Indirect Address 2-5 := 116-119 and a 4-byte write of 1024 at Indirect
    Data 2 sets Goal Position; the NOTE: a longer item must have every byte mapped.
    Indirect Data inherits size, range and access of what it stands for."""
    servo = VirtualServo("XM430-W350", 1)
    map_indirect(servo, 2, [116, 117, 118, 119])
    assert servo.write(225, le(1024, 4), 0.0) == OK
    assert value(servo, GOAL_POSITION, 4) == 1024
    assert value(servo, 225, 4) == 1024
    assert servo.write(225, le(4096, 4), 0.0) == StatusError.DATA_LIMIT  # Max Position Limit
    assert servo.write(225, b"\x00", 0.0) == StatusError.DATA_LENGTH  # 1 of Goal Position's 4
    map_indirect(servo, 6, [PRESENT_POSITION])
    assert servo.write(229, b"\x00", 0.0) == StatusError.ACCESS  # Present Position is R
    map_indirect(servo, 7, [66])
    assert servo.read(230, 1, 0.0) == (OK, b"\x00")  # a gap reads 0 ...
    assert servo.write(230, b"\x01", 0.0) == StatusError.ACCESS  # ... and takes nothing
    # Indirect Address accepts only the RAM area (64-661): EEPROM cannot be assigned
    assert servo.write(168, le(63, 2), 0.0) == StatusError.DATA_RANGE
    assert servo.write(168, le(662, 2), 0.0) == StatusError.DATA_RANGE
    # by default Indirect Data n stands for itself: a plain byte
    assert servo.write(634, b"\x7f", 0.0) == OK and servo.read(634, 1, 0.0) == (OK, b"\x7f")


def test_indirect_addresses_are_ram_reboot_restores_the_defaults():
    """Indirect Address is in the RAM area of the table: Reboot puts the defaults back."""
    servo = VirtualServo("XM430-W350", 1)
    map_indirect(servo, 1, [LED])
    assert servo.reboot(0.1) == OK
    assert value(servo, 168, 2, 0.1) == 224


def _moving_bus_with_indirect_present_values():
    bus = make_bus((1, 2, 3))
    for s in bus.servos:
        # Indirect Data 1-8 := Present Position (132-135), Present Velocity (128-131)
        map_indirect(s, 1, [*range(132, 136), *range(128, 132)])
        assert s.write(TORQUE, b"\x01", 0.0) == OK
        assert s.write(GOAL_POSITION, le(500 * s.id, 4), 0.0) == OK
    bus.clock.advance(0.05)  # mid-move
    return bus


def test_indirect_sync_read_matches_the_direct_read_through_the_sdk():
    """protocol2.md Sync Read: "If the Address of the data is not continual, an Indirect
    Address can be used." The SDK's GroupSyncRead over Present Position + Present Velocity
    mapped to Indirect Data 1-8 (224..) reads what the direct addresses hold: one Sync Read
    from 128 to 231 samples both at the same instant while the horns move."""
    bus = _moving_bus_with_indirect_present_values()
    session = open_session(bus, "indirect-bus")
    try:
        reader = sdk.GroupSyncRead(session.port, session.ph, PRESENT_VELOCITY, 224 + 8 - 128)
        for i in (1, 2, 3):
            assert reader.addParam(i)
        assert reader.txRxPacket() == sdk.COMM_SUCCESS
        for i in (1, 2, 3):
            direct = (
                reader.getData(i, PRESENT_POSITION, 4),
                reader.getData(i, PRESENT_VELOCITY, 4),
            )
            indirect = (reader.getData(i, 224, 4), reader.getData(i, 228, 4))
            assert indirect == direct, i
            assert direct[1] != 0  # moving: a real comparison
        # the indirect block alone, plain and fast, once the horns stand still
        bus.clock.advance(2.0)
        direct = sdk.GroupSyncRead(session.port, session.ph, PRESENT_VELOCITY, 8)
        indirect = sdk.GroupSyncRead(session.port, session.ph, 224, 8)
        for i in (1, 2, 3):
            direct.addParam(i)
            indirect.addParam(i)
        assert direct.txRxPacket() == sdk.COMM_SUCCESS
        want = {i: (direct.getData(i, 132, 4), direct.getData(i, 128, 4)) for i in (1, 2, 3)}
        assert want == {1: (500, 0), 2: (1000, 0), 3: (1500, 0)}
        for run in (indirect.txRxPacket, indirect.fastSyncRead):
            assert run() == sdk.COMM_SUCCESS
            got = {i: (indirect.getData(i, 224, 4), indirect.getData(i, 228, 4)) for i in (1, 2, 3)}
            assert got == want, run
        bulk = sdk.GroupBulkRead(session.port, session.ph)
        for i in (1, 2, 3):
            assert bulk.addParam(i, 224, 8)
        for run in (bulk.txRxPacket, bulk.fastBulkRead):
            assert run() == sdk.COMM_SUCCESS
            got = {i: (bulk.getData(i, 224, 4), bulk.getData(i, 228, 4)) for i in (1, 2, 3)}
            assert got == want, run
    finally:
        session.port.closePort()
        unregister_bus("indirect-bus")


def test_sync_write_through_indirect_data_moves_the_servos():
    """protocol2.md Sync Write: "If the Address of the data is not continual, an Indirect
    Address can be used." A Sync Write of Goal Position mapped to Indirect Data 1-4."""
    bus = make_bus((1, 2))
    for s in bus.servos:
        map_indirect(s, 1, range(116, 120))
        assert s.write(TORQUE, b"\x01", 0.0) == OK
    body = b"".join(bytes((i,)) + le(700 * i, 4) for i in (1, 2))
    assert transact(bus, 0xFE, Instruction.SYNC_WRITE, le(224, 2) + le(4, 2) + body) == []
    bus.clock.advance(2.0)
    t = bus.clock.now()
    assert [value(s, PRESENT_POSITION, 4, t) for s in bus.servos] == [700, 1400]


# --- Action without Reg Write -----------------------------------------------------------------
def test_action_without_reg_write_is_an_instruction_error():
    """protocol2.md error table: 0x02 Instruction Error, "Action has been used without Reg
    Write"."""
    bus = make_bus((1,))
    (status,) = transact(bus, 1, Instruction.ACTION)
    assert (status.id, status.error) == (1, StatusError.INSTRUCTION)
    (status,) = transact(bus, 1, Instruction.REG_WRITE, bytes((LED, 0, 1)))
    assert status.error == OK
    (status,) = transact(bus, 1, Instruction.ACTION)
    assert status.error == OK and value(bus.servo(1), LED, 1, bus.clock.now()) == 1


# --- Control Table Backup (0x20), Backup Ready, Startup Configuration -----------------------
def test_backup_example_packets_byte_for_byte():
    """protocol2.md Control Table Backup, Example 1: the instruction packet and the ID 1
    status packet ``FF FF FD 00 01 04 00 55 00 A1 0C``. Example 2 (restore) prints CRC
    ``92 F5``, but CRC-16 of its bytes is ``9E F5`` (an e-Manual typo: the same algorithm
    gives Example 1's ``16 F5`` and every golden packet); a servo takes the printed packet
    for a damaged one (CRC Error) and executes the correct one."""
    store = bytes.fromhex("FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5")
    printed_restore = bytes.fromhex("FF FF FD 00 01 08 00 20 02 43 54 52 4C 92 F5")
    assert encode_instruction(1, Instruction.BACKUP, BACKUP_STORE) == store
    assert encode_instruction(1, Instruction.BACKUP, BACKUP_RESTORE) == (
        printed_restore[:-2] + bytes.fromhex("9E F5")
    )
    status_ok = bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C")
    bus = make_bus((1,))
    for packet, error in (
        (store, OK),
        (printed_restore, StatusError.CRC),
        (encode_instruction(1, Instruction.BACKUP, BACKUP_RESTORE), OK),
    ):
        bus.write(packet)
        bus.clock.advance(0.05)
        reply = bus.read(100)
        assert split_status_stream(reply)[0].error == error
        if error == OK:
            assert reply == status_ok


def test_backup_needs_torque_off_and_firmware_45():
    """protocol2.md: works only with Torque Enable 0, else Result Fail; supported on
    X430/540 from firmware 45, X330 from 46 (older firmware: an undefined instruction)."""
    servo = VirtualServo("XM430-W350", 1)
    assert servo.backup(BACKUP_STORE, 0.0) == OK
    assert servo.write(TORQUE, b"\x01", 0.0) == OK
    assert servo.backup(BACKUP_STORE, 0.0) == StatusError.RESULT_FAIL
    assert servo.backup(BACKUP_RESTORE, 0.0) == StatusError.RESULT_FAIL
    assert VirtualServo("XM430-W350", 1, firmware=44).backup(BACKUP_STORE, 0.0) == (
        StatusError.INSTRUCTION
    )
    assert VirtualServo("XL330-M288", 1, firmware=45).backup(BACKUP_STORE, 0.0) == (
        StatusError.INSTRUCTION
    )
    assert VirtualServo("XL330-M288", 1, firmware=46).backup(BACKUP_STORE, 0.0) == OK
    fresh = VirtualServo("XM430-W350", 1)
    assert fresh.backup(b"\x03CTRL", 0.0) == StatusError.DATA_RANGE  # P1 0x03.. reserved
    assert fresh.backup(b"\x01CTRX", 0.0) == StatusError.DATA_RANGE
    assert fresh.backup(b"\x01", 0.0) == StatusError.DATA_LENGTH
    assert fresh.backup(BACKUP_RESTORE, 0.0) == StatusError.RESULT_FAIL  # nothing stored


def test_restore_puts_the_eeprom_back_and_reboots():
    """protocol2.md: 0x02 "Restore EEPROM data from Backup area. After processing packets,
    DYNAMIXEL reboots itself." (RAM comes back at its defaults.)"""
    servo = VirtualServo("XM430-W350", 1)
    assert servo.write(RDT, b"\x0a", 0.0) == OK
    assert servo.backup(BACKUP_STORE, 0.0) == OK
    assert servo.write(RDT, b"\x64", 0.1) == OK and servo.write(LED, b"\x01", 0.1) == OK
    assert servo.backup(BACKUP_RESTORE, 0.2) == OK
    assert value(servo, RDT, 1, 0.2) == 10 and value(servo, LED, 1, 0.2) == 0
    assert value(servo, 120, 2, 0.25) == 50  # Realtime Tick restarted at the reboot


def test_xl430_startup_configuration_and_backup_ready_rows():
    """xl430-w250.md: Startup Configuration(60) EEPROM RW 0, range 0-3; Backup Ready(147)
    RAM R: 0 "The backup data doesn't exist", 1 "A saved backup data exists"."""
    m = MODELS["XL430-W250"]
    sc, br = m.field(STARTUP_CONFIGURATION), m.field(BACKUP_READY)
    assert (sc.size, sc.access, sc.default, sc.lo, sc.hi, sc.eeprom) == (1, "RW", 0, 0, 3, True)
    assert (br.size, br.access, br.lo, br.hi, br.eeprom) == (1, "R", 0, 1, False)
    servo = VirtualServo("XL430-W250", 1)
    assert value(servo, BACKUP_READY, 1) == 0
    assert servo.write(BACKUP_READY, b"\x01", 0.0) == StatusError.ACCESS
    assert servo.write(STARTUP_CONFIGURATION, b"\x04", 0.0) == StatusError.DATA_RANGE
    assert servo.backup(BACKUP_STORE, 0.0) == OK
    assert value(servo, BACKUP_READY, 1) == 1
    assert servo.reboot(0.1) == OK and value(servo, BACKUP_READY, 1, 0.1) == 1  # kept in flash
    assert servo.write(TORQUE, b"\x01", 0.1) == OK
    assert servo.write(STARTUP_CONFIGURATION, b"\x01", 0.1) == StatusError.ACCESS  # EEPROM


#: The current XH430 pages list both rows, as the XL430's does: ``docs/en/dxl/x/xh430-w350.md``
#: and ``xh430-w210.md`` @ 028a13d2, ``xh430-v350.md`` @ 7f0be97a, ``docs/kr/dxl/x/
#: xh430-v210.md`` @ 01ba9719 (no English page in that layout is stored for the V210).
XH430 = ("XH430-W350", "XH430-W210", "XH430-V350", "XH430-V210")


@pytest.mark.parametrize("name", XH430)
def test_xh430_startup_configuration_and_backup_ready(name):
    """Startup Configuration(60): EEPROM, RW, initial 0, range 3 (bits 0-1); Backup Ready(147):
    RAM, R, 0-1. On the wire: a write of 60 is taken (not an Access Error), Backup Ready
    follows the Control Table Backup, and a Reboot applies RAM Restore and Startup Torque On."""
    bus = make_bus((1,), model=name)

    def reply(inst: int, params: bytes = b""):
        (status,) = transact(bus, 1, inst, params)
        return status.error, status.params

    assert reply(Instruction.WRITE, bytes((STARTUP_CONFIGURATION, 0, 3))) == (OK, b"")
    assert reply(Instruction.WRITE, bytes((STARTUP_CONFIGURATION, 0, 4)))[0] == (
        StatusError.DATA_RANGE
    )
    assert reply(Instruction.WRITE, bytes((BACKUP_READY, 0, 1)))[0] == StatusError.ACCESS
    assert reply(Instruction.WRITE, bytes((PROFILE_VELOCITY, 0)) + le(77, 4)) == (OK, b"")
    read_ready = bytes((BACKUP_READY, 0, 1, 0))
    assert reply(Instruction.READ, read_ready) == (OK, b"\x00")
    assert reply(Instruction.BACKUP, BACKUP_STORE) == (OK, b"")
    assert reply(Instruction.READ, read_ready) == (OK, b"\x01")
    assert reply(Instruction.REBOOT) == (OK, b"")
    bus.clock.advance(1.0)
    assert reply(Instruction.READ, read_ready) == (OK, b"\x01")  # the backup is in flash
    assert reply(Instruction.READ, bytes((PROFILE_VELOCITY, 0, 4, 0))) == (OK, le(77, 4))
    assert reply(Instruction.READ, bytes((TORQUE, 0, 1, 0))) == (OK, b"\x01")
    m = MODELS[name]
    sc, br = m.field(STARTUP_CONFIGURATION), m.field(BACKUP_READY)
    assert (sc.size, sc.access, sc.default, sc.lo, sc.hi, sc.eeprom) == (1, "RW", 0, 0, 3, True)
    assert (br.size, br.access, br.lo, br.hi, br.eeprom) == (1, "R", 0, 1, False)


def test_startup_configuration_restores_ram_and_turns_torque_on_at_boot():
    """control_table_60_startup_configuration.md: bit 1 RAM Restore (RAM area restored
    from the backup on boot), bit 0 Startup Torque On; protocol2.md lists what the backup
    keeps (gains, Profile Acceleration/Velocity, Indirect Addresses)."""
    servo = VirtualServo("XL430-W250", 1)
    assert servo.write(PROFILE_VELOCITY, le(123, 4), 0.0) == OK
    map_indirect(servo, 1, [LED])
    assert servo.write(LED, b"\x01", 0.0) == OK  # not a backed-up item
    assert servo.backup(BACKUP_STORE, 0.0) == OK
    assert servo.reboot(0.1) == OK  # Startup Configuration 0: plain defaults
    assert (value(servo, PROFILE_VELOCITY, 4, 0.1), value(servo, 168, 2, 0.1)) == (0, 224)
    assert servo.write(STARTUP_CONFIGURATION, b"\x03", 0.1) == OK
    assert servo.reboot(0.2) == OK
    t = 0.2
    assert (value(servo, PROFILE_VELOCITY, 4, t), value(servo, 168, 2, t)) == (123, LED)
    assert value(servo, LED, 1, t) == 0 and servo.torque_enabled


# --- Secondary (Shadow) ID ------------------------------------------------------------------
def test_secondary_id_example_from_the_manual():
    """control_table_shadowid.md, the five-servo example: ID(7) first and answered; every
    servo with that Secondary ID executes; "If Instruction Packet ID is the same as
    Secondary ID(12), the Status Packet will not be returned"."""
    bus = make_bus((1, 2, 3, 4, 5))
    for s in bus.servos:
        assert s.write(12, b"\x05", 0.0) == OK
    leds = lambda: [value(s, LED, 1, bus.clock.now()) for s in bus.servos]  # noqa: E731
    replies = transact(bus, 1, Instruction.WRITE, bytes((LED, 0, 1)))
    assert [(p.id, p.error) for p in replies] == [(1, OK)] and leds() == [1, 0, 0, 0, 0]
    replies = transact(bus, 5, Instruction.WRITE, bytes((LED, 0, 1)))
    assert [(p.id, p.error) for p in replies] == [(5, OK)] and leds() == [1, 1, 1, 1, 1]
    for s in bus.servos:
        assert s.write(12, b"\x64", bus.clock.now()) == OK  # Secondary ID 100
    assert transact(bus, 100, Instruction.WRITE, bytes((LED, 0, 0))) == []
    assert leds() == [0, 0, 0, 0, 0]
    assert transact(bus, 100, Instruction.READ, bytes((LED, 0, 1, 0))) == []  # never answered


def test_secondary_id_cannot_change_the_eeprom_and_253_turns_it_off():
    """control_table_shadowid.md rules 3 and 5: only the RAM area can be modified with the
    Secondary ID; 253-255 deactivate it."""
    bus = make_bus((1, 2))
    for s in bus.servos:
        assert s.write(12, b"\x14", 0.0) == OK  # Secondary ID 20
    assert transact(bus, 20, Instruction.WRITE, bytes((RDT, 0, 7))) == []
    assert transact(bus, 20, Instruction.FACTORY_RESET, b"\x02") == []
    t = bus.clock.now()
    assert [value(s, RDT, 1, t) for s in bus.servos] == [0, 0]  # make_bus: 0 µs, unchanged
    assert transact(bus, 20, Instruction.REG_WRITE, bytes((LED, 0, 1))) == []
    assert transact(bus, 20, Instruction.ACTION) == []
    t = bus.clock.now()
    assert [value(s, LED, 1, t) for s in bus.servos] == [1, 1]
    bus.servo(2).write(12, bytes((253,)), t)
    assert transact(bus, 20, Instruction.WRITE, bytes((LED, 0, 0))) == []
    t = bus.clock.now()
    assert [value(s, LED, 1, t) for s in bus.servos] == [0, 1]


# --- Factory Reset broadcast with Reset All -------------------------------------------------
def test_broadcast_reset_all_is_not_executed_from_firmware_42():
    """protocol2.md Factory Reset: with Packet ID 0xFE and option 0xFF the instruction "will
    NOT be activated" (MX(2.0)/X-series FW42 or above). Broadcast: no status either way."""
    bus = make_bus((1, 2))
    for s in bus.servos:
        assert s.write(RDT, b"\x0a", 0.0) == OK
    assert transact(bus, 0xFE, Instruction.FACTORY_RESET, b"\xff") == []
    t = bus.clock.now()
    assert [value(s, RDT, 1, t) for s in bus.servos] == [10, 10]
    assert [s.id for s in bus.servos] == [1, 2] and all(s.baud == bus.baud for s in bus.servos)
    # the options that keep the ID still work by broadcast
    assert transact(bus, 0xFE, Instruction.FACTORY_RESET, b"\x02") == []
    t = bus.clock.now()
    assert [value(s, RDT, 1, t) for s in bus.servos] == [250, 250]


def test_broadcast_reset_all_still_resets_firmware_41():
    bus = make_bus((3,), firmware=41)
    assert transact(bus, 0xFE, Instruction.FACTORY_RESET, b"\xff") == []
    servo = bus.servos[0]
    assert servo.id == 1 and servo.baud == 57_600  # factory ID and Baud Rate


# --- Drive Mode range ----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["XL430-W250", "XM430-W350", "XM430-W210"])
def test_drive_mode_range_0_to_13_on_the_x430s(name):
    """xl430-w250.md: Drive Mode 0-13; control_table_drivemode.md: bit 2 Profile
    Configuration (firmware 42), bit 3 Torque On by Goal Update (firmware 45) on X430."""
    servo = VirtualServo(name, 1)
    for mode in (0, 1, 4, 5, 8, 12, 13):
        assert servo.write(DRIVE_MODE, bytes((mode,)), 0.0) == OK, mode
    assert servo.write(DRIVE_MODE, bytes((14,)), 0.0) == StatusError.DATA_RANGE
    fw44 = VirtualServo(name, 1, firmware=44)
    assert fw44.write(DRIVE_MODE, b"\x04", 0.0) == OK
    assert fw44.write(DRIVE_MODE, b"\x08", 0.0) == StatusError.DATA_RANGE
    fw41 = VirtualServo(name, 1, firmware=41)
    assert fw41.write(DRIVE_MODE, b"\x04", 0.0) == StatusError.DATA_RANGE
    assert fw41.write(DRIVE_MODE, b"\x01", 0.0) == OK


def test_x330_has_twenty_indirect_pairs_at_its_own_addresses():
    """e-Manual docs/en/dxl/x/xl330-m288.md control table: Indirect Address 1-20 at 168-206
    (default: Indirect Data n's address, 64-227), Indirect Data 1-20 at 208-227; nothing
    beyond 227 (the X430's second block at 578.../634... does not exist on X330)."""
    servo = VirtualServo("XL330-M288", 1)
    assert value(servo, 168, 2) == 208 and value(servo, 206, 2) == 227
    map_indirect_at = 168  # Indirect Address 1 -> Present Position's low byte
    assert servo.write(map_indirect_at, le(PRESENT_POSITION, 2), 0.0) == OK
    err, data = servo.read(208, 1, 0.0)
    assert err == OK and data[0] == value(servo, PRESENT_POSITION, 4) & 0xFF
    assert servo.read(250, 1, 0.0)[0] == StatusError.ACCESS  # X430's Indirect Data 27
    assert servo.read(634, 1, 0.0)[0] == StatusError.ACCESS  # X430's second block
    assert servo.write(168, le(228, 2), 0.0) == StatusError.DATA_RANGE  # beyond 64-227
