"""The Sync Read order, the Fast readings taken back while a late reply may still come and
the plain reads' lengths (drivers/dynamixel/read_order.py), step by step; the whole bus
under late replies is tests/hilsim/test_fault_matrix.py row 8."""

from __future__ import annotations

import math

from drivers.dynamixel.fast_reply import GOOD, STALE
from drivers.dynamixel.read_order import (
    LATE_BLOCK_S,
    MAX_SUSPECT_S,
    PLAIN_LATE_S,
    PLAIN_LENGTHS,
    ReadOrder,
)
from drivers.protocol2 import control_table as ct

S, A, B = 0, 1, 2  # servo indices


def _read(orders: ReadOrder, now: float, missing: set[int]) -> list[int]:
    """One Fast read at ``now``: the servos in ``missing`` sent nothing, the chain stopped at
    the first of them; the statuses after distrust() and after()."""
    n = len(orders.order)
    status, pos, errors = [GOOD] * n, [1.0] * n, [0] * n
    broken = False
    for k in orders.order:
        broken = broken or k in missing
        if broken:
            status[k], pos[k] = STALE, math.nan
    if orders.suspect:
        orders.distrust(now, pos, status, errors)
    if STALE in status:
        orders.after(status, now, fast=True)
    return status


def test_missing_at_a_later_place_it_is_asked_first():
    orders = ReadOrder(3)
    assert orders.order == [S, A, B]
    _read(orders, 0.0, {A})
    assert orders.order == [A, S, B] and A in orders.headerless


def test_missing_first_it_goes_last_and_is_not_first_again_while_its_reply_may_come():
    orders = ReadOrder(3)
    _read(orders, 0.0, {S})
    assert orders.order == [A, B, S] and S in orders.headed
    _read(orders, 0.004, {S})  # silent again, at a later place: it would be first ...
    assert orders.order[0] != S  # ... but its whole late reply would start the next read
    assert S in orders.headerless


def test_a_late_block_cannot_outlive_the_read_after_its_own():
    # the review's chain: S missing at a later place, asked first, missing there too, so
    # last: its first late block (headerless) could come now, where a block of S is not
    # a reading until LATE_BLOCK_S has passed
    orders = ReadOrder(3)
    orders.order = [A, S, B]
    step = LATE_BLOCK_S / 4  # reads a quarter of the window apart
    _read(orders, 0.0, {S})
    assert orders.order[0] == S
    _read(orders, step, {S})
    assert orders.order[-1] == S
    status = _read(orders, 2 * step, set())  # S answers (or its late block does): back
    assert status[S] == STALE and status[A] == GOOD
    later = LATE_BLOCK_S + 0.01
    assert _read(orders, later, set()) == [GOOD] * 3  # suspicion over: read again


def test_another_servo_taking_the_first_place_does_not_let_a_suspect_be_read_elsewhere():
    orders = ReadOrder(3)
    step = LATE_BLOCK_S / 4
    _read(orders, 0.0, {A})  # A first now
    status = _read(orders, step, {S})  # S misses at a later place: S first, A second
    assert orders.order[0] == S and orders.order[-1] == A  # suspects last
    status = _read(orders, 2 * step, set())
    assert status[A] == STALE  # A's late block could be there: not a reading
    assert status[S] == GOOD and status[B] == GOOD


def test_two_suspects_taking_turns_still_end():
    orders = ReadOrder(3)
    _read(orders, 0.0, {A})
    _read(orders, 0.001, {S})  # two suspects: one of them is read elsewhere than first
    t = 0.002
    while orders.suspect and t < 1.0:
        _read(orders, t, set())
        t += 0.001
    assert not orders.suspect and t < 2 * LATE_BLOCK_S + 0.01
    assert _read(orders, t, set()) == [GOOD] * 3


def test_plain_reads_only_move_the_first_missing_servo_last():
    orders = ReadOrder(3)
    status = [GOOD, STALE, STALE]
    assert orders.after(status, 0.0, fast=False) == 1
    assert orders.order == [S, B, A] and not orders.suspect


def test_plain_lengths_are_present_position_and_what_follows_but_no_health_block():
    assert PLAIN_LENGTHS[0] == ct.PRESENT_POSITION.size == 4
    assert ct.PRESENT_POSITION.addr + max(PLAIN_LENGTHS) == ct.PRESENT_TEMPERATURE.end
    assert ct.HEALTH_BLOCK.size not in PLAIN_LENGTHS  # a late health reply is 7 bytes
    assert len(set(PLAIN_LENGTHS)) == len(PLAIN_LENGTHS) == 11


def test_a_servo_a_plain_read_did_not_read_makes_that_length_busy_for_it():
    orders = ReadOrder(3)
    assert orders.plain_length(0.0) == (4, ())
    orders.plain_unread(4, [A, B], 0.001)  # A and B may send 4 bytes late
    assert orders.busy_lengths == {4: {A: 0.001 + PLAIN_LATE_S, B: 0.001 + PLAIN_LATE_S}}
    assert orders.late_ids((11, 12, 13)) == {12, 13}
    assert orders.plain_length(0.004) == (5, ())
    assert orders.plain_length(0.008) == (5, ())  # (the read of 5 was whole)
    orders.plain_unread(5, [S], 0.009)
    assert orders.plain_length(0.012) == (6, ())
    orders.plain_unread(7, [S], 0.012)  # the health read's length is never asked: no book
    assert 7 not in orders.busy_lengths
    assert orders.plain_length(0.001 + PLAIN_LATE_S) == (4, ())  # 4's packets are past
    assert orders.plain_length(0.009 + PLAIN_LATE_S) == (4, ()) and not orders.busy_lengths


def test_with_every_plain_length_busy_the_fewest_servos_are_not_read():
    orders = ReadOrder(3)
    for k, n in enumerate(PLAIN_LENGTHS):  # B corrupt every time, and S once
        assert orders.plain_length(k * 1e-3) == (n, ())
        orders.plain_unread(n, [S, B] if k == 3 else [B], k * 1e-3)
    # every length has B's late packet to fear: the first (4) has only B's
    assert orders.plain_length(0.0115) == (4, (B,))
    orders.plain_unread(4, [B], 0.0115)  # B taken back: renewed
    assert orders.plain_length(0.02) == (4, (B,))
    assert orders.plain_length(0.0115 + PLAIN_LATE_S)[1] == ()


def test_one_servo_missing_is_not_read_while_its_whole_late_reply_may_come():
    orders = ReadOrder(1)
    status, pos, errors = [STALE], [math.nan], [0]
    orders.after(status, 0.0, fast=True)
    assert 0 in orders.headed and orders.order == [0]  # its only order starts with it
    status, pos = [GOOD], [1.0]  # a reply came: its own, or the late one
    orders.distrust(0.004, pos, status, errors)
    assert status == [STALE] and math.isnan(pos[0])
    orders.after(status, 0.004, fast=True)
    status, pos = [GOOD], [1.0]
    orders.distrust(MAX_SUSPECT_S + 0.001, pos, status, errors)
    assert status == [GOOD]  # suspicion ends


def test_a_reading_taken_back_renews_the_suspicion_up_to_a_limit():
    # the late reply of read 0 may have filled read 1 (taken back): read 1's own reply is
    # then late in turn, and read 2 must not take it either
    orders = ReadOrder(2)
    _read(orders, 0.0, {S})  # S missing first: headed, not first
    assert orders.order == [A, S]
    _read(orders, 0.001, {A})  # A missing first: headed too; S is first again
    status = _read(orders, 0.002, set())  # a read that starts with a headed servo ...
    assert status == [STALE, STALE]  # ... is taken back whole
    assert orders.headed[S] >= 0.002 + LATE_BLOCK_S - 1e-9  # renewed from this read on
    t = 0.003
    while orders.suspect and t < 1.0:
        _read(orders, t, set())
        t += 0.001
    assert LATE_BLOCK_S < t <= 0.001 + MAX_SUSPECT_S + 0.002  # A's first miss + the limit


def test_a_servo_really_missing_after_one_taken_back_is_suspect_too():
    orders = ReadOrder(4)
    orders.order = [1, 0, 2, 3]
    orders.headerless[0], orders._since[0] = 1.0, 0.0  # suspect until 1.0, missing at 0.0
    status, pos, errors = [GOOD] * 4, [1.0] * 4, [0] * 4
    orders.distrust(0.5, pos, status, errors)  # 0 at a later place: it and after it back
    assert status == [STALE, GOOD, STALE, STALE]
    orders._taken_back.discard(3)  # as if servo 3's block had been missing anyway
    orders.after(status, 0.5, fast=True)
    assert 3 in orders.headerless and orders.order[0] == 3


def test_a_suspect_kept_off_the_first_place_stops_being_suspect_within_the_limit():
    # a servo suspect both ways (missing first, then at a later place) is never asked first,
    # so it is taken back every read, and each taking back renews it: the renewals stop
    # MAX_SUSPECT_S after its last real miss
    orders = ReadOrder(2)
    orders.headed[0] = orders.headerless[0] = LATE_BLOCK_S
    orders._since[0] = 0.0
    t = 0.001
    while orders.suspect and t < 1.0:
        _read(orders, t, set())
        t += 0.001
    assert not orders.suspect and t <= MAX_SUSPECT_S + 0.002


def test_missing_again_while_suspect_renews_from_the_last_miss():
    orders = ReadOrder(1)
    again, back = 0.8 * LATE_BLOCK_S, 1.4 * LATE_BLOCK_S
    orders.after([STALE], 0.0, fast=True)  # missing: suspect until LATE_BLOCK_S
    status, pos, errors = [STALE], [math.nan], [0]
    orders.distrust(again, pos, status, errors)
    orders.after(status, again, fast=True)  # missing again (not taken back)
    status, pos = [GOOD], [1.0]
    orders.distrust(back, pos, status, errors)  # a reply: maybe the late one, taken back
    assert status == [STALE]
    orders.after(status, back, fast=True)  # its own may come late: renewed in full, within
    assert orders.headed[0] >= back + LATE_BLOCK_S - 1e-9  # again + MAX_SUSPECT_S
