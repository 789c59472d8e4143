"""DxlsimUrl: the one owner of the ``dxlsim://`` grammar, its defaults and the bus it builds."""

from __future__ import annotations

import dataclasses

import pytest

from drivers.clock import DEFAULT_SPIN_S, MonotonicClock, VirtualClock
from drivers.dxlsim import DxlBus, register_bus, unregister_bus
from drivers.dxlsim.url import DxlsimUrl, bus_from_url
from drivers.protocol2.wire_time import DEFAULT_TURNAROUND_S


@pytest.mark.parametrize(
    "url",
    [
        "dxlsim://",
        "dxlsim://?ids=1-4&model=XM430-W350&rdt_us=0&latency_ms=1",
        "dxlsim://?ids=3,1,2&baud=57600&clock=real&spin_us=50",
        "dxlsim://?faults=drop:id=2,rate=0.1;unplug:at=3&seed=7&firmware=44&trace=1",
        "dxlsim://?ids=1-3,7&turnaround_us=12.5&latency_ms=0.25",
        "dxlsim://bench-7",
    ],
)
def test_str_parses_back_to_an_equal_url(url):
    parsed = DxlsimUrl.parse(url)
    assert DxlsimUrl.parse(str(parsed)) == parsed
    assert str(DxlsimUrl.parse(str(parsed))) == str(parsed)


def test_str_is_the_normal_form_keeping_the_keys_named():
    text = "dxlsim://?rdt_us=500&ids=1-2&clock=virtual"  # rdt_us and clock at defaults
    assert str(DxlsimUrl.parse(text)) == "dxlsim://?ids=1-2&rdt_us=500&clock=virtual"
    assert str(DxlsimUrl.parse("dxlsim://?trace=1&latency_ms=1")) == (
        "dxlsim://?latency_ms=1&trace=1"
    )
    assert str(DxlsimUrl(ids=(1, 2, 3, 4), rdt_us=0)) == "dxlsim://?ids=1-4&rdt_us=0"
    assert str(DxlsimUrl()) == "dxlsim://"
    assert str(DxlsimUrl(name="bench")) == "dxlsim://bench"


def test_parse_reads_every_key():
    u = DxlsimUrl.parse(
        "dxlsim://?ids=2,5&model=XL330-M288&baud=57600&rdt_us=0&turnaround_us=30"
        "&latency_ms=16&clock=REAL&spin_us=80&faults=drop:id=2&seed=3&firmware=45&trace=1"
    )
    assert u == DxlsimUrl(
        ids=(2, 5),
        model="XL330-M288",
        baud=57_600,
        rdt_us=0.0,
        turnaround_us=30.0,
        latency_ms=16.0,
        clock="real",
        spin_us=80.0,
        faults="drop:id=2",
        seed=3,
        firmware=45,
        trace=True,
    )


def test_defaults_live_in_the_fields_once():
    u = DxlsimUrl.parse("dxlsim://")
    assert u == DxlsimUrl()
    assert u.turnaround_us * 1e-6 == pytest.approx(DEFAULT_TURNAROUND_S, rel=1e-12)
    assert u.spin_us / 1e6 == DEFAULT_SPIN_S
    assert (u.ids, u.model, u.baud, u.rdt_us, u.clock) == (
        (1,),
        "XM430-W350",
        None,
        500.0,
        "real",  # a program's time.sleep lets the servos move (e-Manual: none; README)
    )
    bus = u.build_bus()
    assert bus.turnaround_s == pytest.approx(DEFAULT_TURNAROUND_S, rel=1e-12)
    assert isinstance(bus.clock, MonotonicClock) and bus.baud == 1_000_000
    assert [s.return_delay_s for s in bus.servos] == [500e-6]


def test_replace_changes_fields_and_prints_them():
    u = DxlsimUrl.parse("dxlsim://?ids=1-2")
    real = u.replace(clock="real")
    assert real.clock == "real" and real.ids == (1, 2) and u.clock == "real"
    assert str(real) == "dxlsim://?ids=1-2&clock=real"
    assert str(u.replace(clock="virtual")) == "dxlsim://?ids=1-2&clock=virtual"
    assert str(u.replace(trace=True)) == "dxlsim://?ids=1-2&trace=1"
    assert u.replace(ids="1-4").ids == (1, 2, 3, 4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        u.clock = "virtual"  # type: ignore[misc]


def test_spin_us_reaches_the_real_clock():
    bus = DxlsimUrl.parse("dxlsim://?clock=real&spin_us=50").build_bus()
    assert isinstance(bus.clock, MonotonicClock) and bus.clock.spin_s == pytest.approx(50e-6)
    bus = DxlsimUrl(clock="real").build_bus()
    assert bus.clock.spin_s == DEFAULT_SPIN_S == MonotonicClock().spin_s
    virtual = DxlsimUrl(clock="virtual", spin_us=50).build_bus().clock
    assert isinstance(virtual, VirtualClock)  # ignored there


def test_servo_baud_and_host_baud():
    bus = DxlsimUrl.parse("dxlsim://?ids=1&baud=57600&clock=virtual").build_bus(host_baud=1_000_000)
    assert bus.baud == 1_000_000 and bus.servos[0].baud == 57_600
    bus = DxlsimUrl.parse("dxlsim://?ids=1&clock=virtual").build_bus(host_baud=57_600)
    assert bus.servos[0].baud == 57_600


@pytest.mark.parametrize(
    ("url", "says"),
    [
        ("serial:///dev/ttyUSB0", "not a dxlsim:// URL"),
        ("dxlsim://bus?ids=1", "a named bus takes no ?keys"),
        ("dxlsim://?spin_us=-1", "spin_us: expected µs, a finite number >= 0, got '-1'"),
        ("dxlsim://?clock=sundial", "clock: must be 'virtual' or 'real', got 'sundial'"),
        ("dxlsim://?model=XM999", "model: unknown servo model 'XM999'"),
    ],
)
def test_parse_errors_name_the_url_and_the_key(url, says):
    with pytest.raises(ValueError) as info:
        DxlsimUrl.parse(url)
    assert repr(url) in str(info.value) and says in str(info.value)


def test_build_errors_name_the_url_it_was_parsed_from():
    url = "dxlsim://?ids=1&rdt_us=501"
    with pytest.raises(ValueError) as info:
        DxlsimUrl.parse(url).build_bus()
    assert str(info.value).startswith(f"{url!r}: rdt_us: ")
    with pytest.raises(ValueError, match="clock: must be"):
        DxlsimUrl(clock="sundial")


def test_named_bus_through_the_registry():
    bus = DxlBus([], clock=VirtualClock())
    url = register_bus("url-test", bus)
    try:
        assert DxlsimUrl.parse(url) == DxlsimUrl(name="url-test")
        assert DxlsimUrl.parse(url).build_bus() is bus is bus_from_url(url)
    finally:
        unregister_bus("url-test")
    with pytest.raises(ValueError, match="no emulated bus named 'url-test'"):
        DxlsimUrl(name="url-test").build_bus()
    with pytest.raises(ValueError, match="a named bus takes no"):
        DxlsimUrl(name="url-test", ids=(1, 2))
