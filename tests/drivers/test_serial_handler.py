"""dxlsim:// as a pyserial port: URLs, timeouts on the virtual clock, the object API, the trace."""

from __future__ import annotations

import pytest
import serial

import drivers.dxlsim  # noqa: F401  (registers the scheme)
from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.protocol import Instruction, decode, encode_instruction, split_status_stream

PING1 = encode_instruction(1, Instruction.PING)


def test_url_builds_a_bus_and_answers_a_ping():
    port = serial.serial_for_url(
        "dxlsim://?ids=1-3&model=XL430-W250&rdt_us=0", baudrate=1_000_000, timeout=0
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
        "dxlsim://?ids=1&rdt_us=0&turnaround_us=0", baudrate=1_000_000, timeout=1.0
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
    port = serial.serial_for_url("dxlsim://?ids=1", timeout=None)
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
    port = serial.serial_for_url("dxlsim://?ids=1&baud=57600", baudrate=57_600)
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
