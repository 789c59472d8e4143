"""A Read span compiled once (``RegisterFile._plan``) reads what the byte-by-byte definition
reads, and a plan never outlives the Indirect Addresses it was built on.

The tick's Fast Sync Read of Indirect Data 1..7 is compiled into which field's bytes land
where; the e-Manual (``control_table_indirect_data.md``) says Indirect Data n stands for the
address in Indirect Address n, that Indirect Address is in RAM (a reboot, brownout or factory
reset puts the defaults back: each Indirect Data then stands for itself, 0) and that a
Control Table Backup keeps it. Each test reads once (the plan is built), moves the Indirect
Addresses by one of those paths, and reads again.

Every test runs on the virtual clock; nothing sleeps.
"""

from __future__ import annotations

import random

import pytest

import drivers.protocol2.control_table as ct
from drivers.dxlsim import VirtualServo
from drivers.protocol2.control_table import StatusError
from tests.drivers.test_servo import le

OK = StatusError.NONE
TORQUE, GOAL_POSITION, PRESENT_VELOCITY, PRESENT_POSITION = 64, 116, 128, 132
STARTUP_CONFIGURATION, RAM_RESTORE = 60, 0x02
BLOCK_AT, BLOCK = ct.INDIRECT_DATA_1.addr, ct.TICK_BLOCK_SIZE
BACKUP_STORE = b"\x01CTRL"
#: Indirect Data 1..7 while Indirect Address 1..7 are at their defaults: their own 0s
DEFAULT_BLOCK = bytes(BLOCK)


def moving_servo(t: float = 0.0) -> VirtualServo:
    """A servo with the tick block mapped, on its way to a goal."""
    servo = VirtualServo("XM430-W350", 1, t=t)
    assert servo.write(ct.INDIRECT_ADDRESS_1.addr, ct.tick_block_targets(), t) == OK
    assert servo.write(TORQUE, b"\x01", t) == OK
    assert servo.write(GOAL_POSITION, le(3000, 4), t) == OK
    return servo


def direct_block(servo: VirtualServo, t: float) -> bytes:
    """The tick block read item by item at its own addresses."""
    out = b""
    for item in ct.TICK_BLOCK:
        err, data = servo.read(item.addr, item.size, t)
        assert err == OK
        out += data
    return out


def block(servo: VirtualServo, t: float) -> bytes:
    err, data = servo.read(BLOCK_AT, BLOCK, t)
    assert err == OK
    return data


def test_the_block_reads_what_its_items_hold_while_the_servo_moves():
    servo = moving_servo()
    seen = []
    for k in range(1, 6):
        t = 0.01 * k
        seen.append(block(servo, t))
        assert seen[-1] == direct_block(servo, t)
    assert seen[0][:4] != seen[-1][:4]  # it moved


def test_an_indirect_address_written_mid_show_is_read_at_once():
    """Indirect Address 1..4 moved to Present Velocity between two reads of the block."""
    servo = moving_servo()
    block(servo, 0.02)  # the plan is built
    velocity = [PRESENT_VELOCITY + b for b in range(4)]
    assert servo.write(ct.INDIRECT_ADDRESS_1.addr, b"".join(le(a, 2) for a in velocity), 0.03) == OK
    data = block(servo, 0.03)
    assert data[:4] == servo.read(PRESENT_VELOCITY, 4, 0.03)[1]
    assert data[4:] == direct_block(servo, 0.03)[4:]
    assert data[:4] != servo.read(PRESENT_POSITION, 4, 0.03)[1]  # moving: they differ


def test_one_byte_of_the_block_moved_through_indirect_data_itself():
    """A write through Indirect Data is a write of what it stands for; a write of Indirect
    Address 7 (the marker byte) alone moves only that byte."""
    servo = moving_servo()
    block(servo, 0.01)
    assert servo.write(ct.indirect_address(7).addr, le(TORQUE, 2), 0.02) == OK
    data = block(servo, 0.02)
    assert data[6] == 1 and data[4] == 1  # Torque Enable twice
    assert servo.write(ct.indirect_address(7).addr, le(ct.indirect_data(7).addr, 2), 0.02) == OK
    assert block(servo, 0.02)[6] == 0  # Indirect Data 7 standing for itself: its own 0


def test_the_block_follows_its_stored_items_under_one_plan():
    """Torque Enable and Bus Watchdog written between reads (Indirect Addresses unchanged):
    the block's bytes of them follow at once."""
    servo = moving_servo()
    assert block(servo, 0.01)[4:6] == b"\x01\x00"
    assert servo.write(ct.BUS_WATCHDOG.addr, b"\x05", 0.02) == OK
    assert block(servo, 0.02)[4:6] == b"\x01\x05"
    assert servo.write(TORQUE, b"\x00", 0.03) == OK
    assert block(servo, 0.03) == direct_block(servo, 0.03)
    assert block(servo, 0.03)[4:6] == b"\x00\x05"


@pytest.mark.parametrize("how", ["reboot", "brownout", "factory_reset"])
def test_a_restart_puts_the_indirect_addresses_back_and_the_block_reads_zeros(how):
    servo = moving_servo()
    assert block(servo, 0.02)[6] == ct.STATUS_RETURN_ALL
    if how == "reboot":
        assert servo.reboot(0.03) & 0x7F == OK
    elif how == "brownout":
        servo.brownout(0.03)
    else:
        assert servo.write(TORQUE, b"\x00", 0.03) == OK
        assert servo.factory_reset(0x02, 0.03) & 0x7F == OK
    assert servo.read(ct.INDIRECT_ADDRESS_1.addr, 2, 0.04) == (OK, le(BLOCK_AT, 2))
    assert block(servo, 0.04) == DEFAULT_BLOCK


def test_a_backup_with_ram_restore_brings_the_block_back_at_boot():
    """protocol2.md Control Table Backup keeps the Indirect Addresses; Startup Configuration
    RAM Restore puts them back at boot (no Write of them on the wire)."""
    servo = VirtualServo("XL430-W250", 1)  # a model with Startup Configuration
    at = ct.INDIRECT_ADDRESS_1.addr
    assert servo.write(at, ct.tick_block_targets(), 0.0) == OK
    assert servo.write(STARTUP_CONFIGURATION, bytes((RAM_RESTORE,)), 0.0) == OK
    assert servo.backup(BACKUP_STORE, 0.0) & 0x7F == OK
    assert servo.write(at, le(at, 2), 0.0) == OK  # Indirect Data 1 := Indirect Address 1's
    assert block(servo, 0.01)[0] == at  # low byte, read through a plan
    assert servo.reboot(0.02) & 0x7F == OK
    assert servo.read(at, 2, 0.03) == (OK, le(PRESENT_POSITION, 2))
    assert block(servo, 0.03) == direct_block(servo, 0.03)
    assert block(servo, 0.03)[6] == ct.STATUS_RETURN_ALL


def test_every_span_reads_as_the_byte_loop_defines_it():
    """Random spans over the whole table, read twice (the second from the plan), under
    random Indirect Addresses moved between reads: gaps, spans that start or end inside a
    field, Indirect Data pointing at other Indirect Data or at a gap, a computed field both
    directly in the span and through Indirect Data."""
    rng = random.Random(30)
    servo = moving_servo()
    reg = servo._reg
    table_end = servo.model.table_end
    spans = [(BLOCK_AT, BLOCK), (0, PRESENT_POSITION + 4), (120, 120), (611, 4)]
    spans += [(a, rng.randint(1, 40)) for a in rng.sample(range(table_end - 40), 60)]
    indirect = servo.model.indirect
    links = list(indirect.values())
    plain = [a for a in range(64, 662) if a not in indirect]  # not Indirect Data
    stored = [
        f.addr
        for f in servo.model.fields
        if f.addr not in reg.dynamic
        and f.addr not in indirect
        and f.addr not in links
        and f.addr >= 64  # RAM, not the ID or baud rate the servo answers on
    ]

    def target() -> int:
        roll = rng.random()
        if roll < 0.03:
            return BLOCK_AT + 3  # another Indirect Data: its stored byte
        if roll < 0.2:
            return PRESENT_POSITION + rng.randint(0, 3)
        return rng.choice(plain)  # a field's byte or a gap

    for at in links:
        reg.values[at] = target()
    t = 0.0
    for round_ in range(12):
        t += 0.007
        for at in rng.sample(links, 4):
            reg.values[at] = target()
        if round_ % 3 == 0:
            reg.values[ct.INDIRECT_ADDRESS_1.addr] = BLOCK_AT  # a default among the others
        for at in rng.sample(stored, 6):  # stored values change under the same plan
            reg.values[at] = rng.randint(-(2**31), 2**31 - 1)
        servo.advance(t)
        for addr, length in spans:
            for _ in range(2):
                err, data = reg.read(addr, length)
                assert err == OK, (addr, length)
                assert data == reg._read_span(addr, length), (round_, addr, length)


def test_spans_the_e_manual_refuses_are_still_refused_after_a_plan():
    servo = moving_servo()
    reg = servo._reg
    end = servo.model.table_end
    assert reg.read(BLOCK_AT, BLOCK)[0] == OK
    assert reg.read(end - 2, 4) == (StatusError.ACCESS, b"")
    assert reg.read(BLOCK_AT, 0) == (StatusError.DATA_LENGTH, b"")
    assert reg.read(BLOCK_AT, 65536 + BLOCK) == (StatusError.ACCESS, b"")
