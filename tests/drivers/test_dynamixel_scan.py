"""scan(): servos found by baud, ID, model and firmware, on the emulated bus."""

from __future__ import annotations

import pytest

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dynamixel.scan import Found, scan

BAUDS = (57_600, 115_200, 1_000_000)


@pytest.fixture
def registered():
    names = []

    def _register(servos, faults=None) -> str:
        name = f"scan-{len(names)}"
        names.append(name)
        return register_bus(name, DxlBus(servos, baud=57_600, clock=VirtualClock(), faults=faults))

    yield _register
    for name in names:
        unregister_bus(name)


def test_finds_servos_sitting_at_different_bauds(registered):
    url = registered(
        [
            VirtualServo("XM430-W350", 1, baud=57_600),
            VirtualServo("XM430-W350", 7, baud=57_600, firmware=44),
            VirtualServo("XL330-M288", 3, baud=1_000_000),
            VirtualServo("XM540-W270", 4, baud=1_000_000),
        ]
    )
    found = scan(url, bauds=BAUDS)
    assert found == [
        Found(57_600, 1, 1020, "XM430-W350", 46),
        Found(57_600, 7, 1020, "XM430-W350", 44),
        Found(1_000_000, 3, 1200, "XL330-M288", 46),
        Found(1_000_000, 4, 1120, "XM540-W270", 46),
    ]
    assert str(found[2]) == "ID   3 @ 1000000 bit/s: XL330-M288 (model 1200, firmware 46)"


def test_ids_limit_what_is_reported(registered):
    url = registered([VirtualServo("XM430-W350", i, baud=1_000_000) for i in (1, 2, 3)])
    assert [f.id for f in scan(url, bauds=(1_000_000,), ids=[2, 3, 9])] == [2, 3]


def test_unicast_fallback_when_broadcast_finds_nobody(registered):
    # The first reply of the broadcast chain is lost, so nobody after it answers either.
    servos = [VirtualServo("XM430-W350", i, baud=1_000_000) for i in (1, 2)]
    url = registered(servos, faults="drop:id=1,count=1")
    assert scan(url, bauds=(1_000_000,), ids=range(5), unicast_fallback=False) == []
    url = registered(
        [VirtualServo("XM430-W350", i, baud=1_000_000) for i in (1, 2)], faults="drop:id=1,count=1"
    )
    assert [f.id for f in scan(url, bauds=(1_000_000,), ids=range(5))] == [1, 2]


def test_scan_a_url_bus():
    found = scan("dxlsim://?ids=1-3&baud=115200&clock=virtual", bauds=BAUDS)
    assert [(f.baud, f.id) for f in found] == [(115_200, 1), (115_200, 2), (115_200, 3)]


def test_nothing_there_is_an_empty_list():
    assert scan("dxlsim://?ids=1&baud=9600&clock=virtual", bauds=(57_600,), ids=range(3)) == []
