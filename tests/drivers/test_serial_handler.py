"""dxlsim:// as a pyserial port: URLs, timeouts on the virtual clock, the object API, the trace."""

from __future__ import annotations

import gc
import weakref

import pytest
import serial

import drivers.dxlsim  # noqa: F401  (registers the scheme)
from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.protocol import Instruction, decode, encode_instruction, split_status_stream
from drivers.dxlsim.url import DxlsimUrl, live_buses

PING1 = encode_instruction(1, Instruction.PING)


def test_url_builds_a_bus_and_answers_a_ping():
    port = serial.serial_for_url(
        "dxlsim://?ids=1-3&model=XL430-W250&rdt_us=0&clock=virtual", baudrate=1_000_000, timeout=0
    )
    assert port.bus.clock.virtual
    assert [s.id for s in port.bus.servos] == [1, 2, 3]
    port.write(PING1)
    assert port.read(100) == b""  # timeout=0: nothing is readable yet
    port.timeout = 0.01
    reply = decode(port.read(14))
    assert reply.params[:2] == (1060).to_bytes(2, "little")


def test_read_with_timeout_jumps_the_virtual_clock_exactly():
    port = serial.serial_for_url(
        "dxlsim://?ids=1&rdt_us=0&turnaround_us=0&clock=virtual", baudrate=1_000_000, timeout=1.0
    )
    clock = port.clock
    t0 = clock.now()
    port.write(PING1)
    assert len(port.read(14)) == 14
    assert clock.now() - t0 == pytest.approx(24 * 10e-6, abs=1e-12)
    # Nothing more is coming: a read waits its whole timeout, then returns what there is.
    t1 = clock.now()
    assert port.read(1) == b""
    assert clock.now() - t1 == pytest.approx(1.0)


def test_read_without_timeout_refuses_to_block_forever():
    port = serial.serial_for_url("dxlsim://?ids=1&clock=virtual", timeout=None)
    with pytest.raises(serial.SerialException, match="block forever"):
        port.read(1)


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("dxlsim://?ids=1-300", "0..252"),
        ("dxlsim://?ids=1&colour=red", "unknown key"),
        ("dxlsim://?ids=1&model=XQ999", "XQ999"),
        ("dxlsim://?ids=1&clock=sundial", "clock"),
        ("dxlsim://?faults=explode", "unknown fault kind"),
        ("dxlsim://nosuchbus", "no emulated bus named"),
    ],
)
def test_bad_urls_say_what_is_wrong(url, message):
    with pytest.raises(serial.SerialException, match=message):
        serial.serial_for_url(url)


def test_named_bus_object_api_and_trace():
    clock = VirtualClock()
    bus = DxlBus(
        [VirtualServo("XM430-W350", 7, baud=57_600, t=0.0)], baud=57_600, clock=clock, trace=True
    )
    url = register_bus("bench-7", bus)
    try:
        port = serial.serial_for_url(url, baudrate=57_600, timeout=0.1)
        assert port.bus is bus
        port.write(encode_instruction(7, Instruction.PING))
        (status,) = split_status_stream(port.read(14))
        assert status.id == 7
        tx, rx = bus.trace
        assert (tx.direction, rx.direction) == ("tx", "rx")
        assert tx.data == encode_instruction(7, Instruction.PING)
        assert rx.t_start >= tx.t_end + 500e-6  # factory Return Delay Time
        assert rx.note == "id=7"
    finally:
        unregister_bus("bench-7")


def test_host_baud_change_reaches_the_bus():
    port = serial.serial_for_url("dxlsim://?ids=1&baud=57600&clock=virtual", baudrate=57_600)
    port.baudrate = 115_200
    assert port.bus.baud == 115_200


def test_xm430_w210_firmware_38_answers_the_manual_ping_byte_for_byte():
    golden = {
        k: bytes.fromhex(v)
        for k, v in __import__("json")
        .loads((__import__("pathlib").Path(__file__).parent / "golden_packets.json").read_text())
        .items()
        if not k.startswith("_")
    }
    bus = DxlBus([VirtualServo("XM430-W210", 1, baud=57_600, firmware=38, t=0.0)], baud=57_600)
    bus.write(golden["ping_id1_instruction"])
    assert bus.read(100, bus.clock.now() + 0.01) == golden["ping_id1_status_model1030_fw38"]


def test_real_clock_bytes_become_readable_only_when_their_time_comes():
    port = serial.serial_for_url(
        "dxlsim://?ids=1&clock=real&rdt_us=500", baudrate=1_000_000, timeout=0
    )
    clock = port.clock
    assert not clock.virtual
    t0 = clock.now()
    port.write(PING1)
    early = port.read(14)
    port.timeout = 0.5
    late = port.read(14)
    elapsed = clock.now() - t0
    # 24 bytes on the wire + 500 µs Return Delay + 20 µs turnaround = 760 µs at the earliest.
    assert len(early + late) == 14
    assert elapsed >= 760e-6
    assert len(early) < 14


# ------------------------------------------------------------------ one URL, one bus
# Real servos keep their state while powered, whatever the host does with its port; a host at
# another baud rate hears no valid reply (e-Manual protocol2.md: half-duplex 8N1 at the
# servo's Baud Rate; x/xm430-w350.md Baud Rate(8)).
LED = 65  # e-Manual x/xm430-w350.md, LED(65): RAM, 1 byte


def _write_led(port, servo_id: int = 1) -> None:
    port.write(encode_instruction(servo_id, Instruction.WRITE, bytes([LED, 0, 1])))
    port.timeout = 0.01
    port.read(11)


def test_reopening_a_url_keeps_its_bus_and_servo_state():
    url = "dxlsim://?ids=1-2&rdt_us=0&clock=virtual"
    port = serial.serial_for_url(url, baudrate=1_000_000)
    bus = port.bus
    _write_led(port)
    port.close()
    port.open()  # the adapter re-plugged: the servos stayed powered
    assert port.bus is bus and bus.servo(1).read(LED, 1, bus.clock.now())[1] == b"\x01"
    other = serial.serial_for_url("dxlsim://?clock=virtual&rdt_us=0&ids=1,2", baudrate=57_600)
    assert other.bus is bus and other.clock is port.clock  # same normal form: same bus
    assert live_buses()[str(DxlsimUrl.parse(url))] is bus
    port.close()
    other.close()
    assert str(DxlsimUrl.parse(url)) not in live_buses()
    fresh = serial.serial_for_url(url, baudrate=1_000_000)  # every port closed: powered up anew
    assert fresh.bus is not bus and fresh.bus.servo(1).read(LED, 1, 0.0)[1] == b"\x00"
    fresh.close()


def test_a_port_dropped_while_open_does_not_keep_its_bus():
    url = "dxlsim://?ids=7&clock=virtual"
    port = serial.serial_for_url(url)
    ref = weakref.ref(port.bus)
    del port
    gc.collect()
    assert ref() is None and str(DxlsimUrl.parse(url)) not in live_buses()


@pytest.mark.parametrize("clock", ["virtual", "real"])
def test_host_baud_change_leaves_the_servos_at_theirs(clock):
    """e-Manual x/xm430-w350.md Baud Rate(8): the servo listens at its own rate only; a
    host at another rate sends noise, so no reply is ever scheduled (checked without
    waiting: the bus decides when the packet's last byte arrives)."""
    port = serial.serial_for_url(f"dxlsim://?ids=1&clock={clock}", baudrate=1_000_000)
    try:
        bus = port.bus
        port.baudrate = 57_600
        assert bus.baud == 57_600 and bus.servo(1).baud == 1_000_000
        port.write(PING1)
        assert bus.pending_rx == 0  # nothing on its way
        port.baudrate = 1_000_000
        port.write(PING1)
        assert bus.pending_rx == 14  # the servo's status packet is on its way
    finally:
        port.close()
