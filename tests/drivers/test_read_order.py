"""The Sync Read order and the Fast readings taken back while a late reply may still come
(drivers/dynamixel/read_order.py), step by step; the whole bus under late replies is
tests/hilsim/test_fault_matrix.py row 8."""

from __future__ import annotations

import math

from drivers.dynamixel.fast_reply import GOOD, STALE
from drivers.dynamixel.read_order import LATE_BLOCK_S, ReadOrder

S, A, B = 0, 1, 2  # servo indices


def _read(orders: ReadOrder, now: float, missing: set[int]) -> list[int]:
    """One Fast read at ``now``: the servos in ``missing`` sent nothing, the chain stopped at
    the first of them; the statuses after distrust() and after()."""
    status, pos, errors = [GOOD] * 3, [1.0] * 3, [0] * 3
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
    _read(orders, 0.0, {S})
    assert orders.order[0] == S
    _read(orders, 0.004, {S})
    assert orders.order[-1] == S
    status = _read(orders, 0.006, set())  # S answers (or its late block does): taken back
    assert status[S] == STALE and status[A] == GOOD
    later = LATE_BLOCK_S + 0.01
    assert _read(orders, later, set()) == [GOOD] * 3  # suspicion over: read again


def test_another_servo_taking_the_first_place_does_not_let_a_suspect_be_read_elsewhere():
    orders = ReadOrder(3)
    _read(orders, 0.0, {A})  # A first now
    status = _read(orders, 0.004, {S})  # S misses at a later place: S first, A second
    assert orders.order[0] == S and orders.order[-1] == A  # suspects last
    status = _read(orders, 0.005, set())
    assert status[A] == STALE  # A's late block could be there: not a reading
    assert status[S] == GOOD and status[B] == GOOD


def test_a_reading_taken_back_does_not_renew_the_suspicion():
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
