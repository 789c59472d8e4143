"""Fixtures: SDK sessions against the emulated bus, in-process and over a pty."""

from __future__ import annotations

import os
from dataclasses import dataclass

import dynamixel_sdk as sdk
import pytest

from drivers.clock import VirtualClock
from drivers.dxlsim import DxlBus, VirtualServo, register_bus, unregister_bus
from drivers.dxlsim.protocol import StreamParser
from drivers.dynamixel.port import PortHandler
from tests.emulate_pty import emulated_pty

IDS = (1, 2, 3, 4)
BAUD = 1_000_000


@dataclass
class Session:
    """An open dynamixel-sdk session: port, packet handler, and the bus when in-process."""

    port: sdk.PortHandler
    ph: sdk.Protocol2PacketHandler
    bus: DxlBus | None
    kind: str


def make_bus(
    ids=IDS,
    *,
    model="XM430-W350",
    rdt_us=0.0,
    turnaround_us=20.0,
    baud=BAUD,
    latency_timer_ms=0.0,
    faults=None,
    seed=0,
    trace=False,
    **servo_kw,
) -> DxlBus:
    clock = VirtualClock()
    servos = [
        VirtualServo(model, i, baud=baud, return_delay_us=rdt_us, t=0.0, **servo_kw) for i in ids
    ]
    return DxlBus(
        servos,
        baud=baud,
        clock=clock,
        latency_timer_ms=latency_timer_ms,
        turnaround_us=turnaround_us,
        faults=faults,
        seed=seed,
        trace=trace,
    )


@dataclass
class Asked:
    """One instruction the host sent (from a bus's trace) and the notes of the replies it
    caused, ``"id=2 fault=late"``; a dropped reply leaves none."""

    id: int
    instruction: int
    address: int | None
    replies: list[str]


def asked(bus: DxlBus, since: int = 0) -> list[Asked]:
    """Every instruction on ``bus``'s wire from trace record ``since`` on (the bus made with
    ``trace=True``): a test counts the tries of a retry here, not in the code retrying."""
    out: list[Asked] = []
    parser = StreamParser()
    for rec in bus.trace[since:]:
        if rec.direction == "tx":
            for frame in parser.feed(rec.data):
                p = frame.packet
                addr = p.params[0] | p.params[1] << 8 if len(p.params) >= 2 else None
                out.append(Asked(p.id, p.instruction, addr, []))
        elif out:
            out[-1].replies.append(rec.note)
    return out


def open_session(bus: DxlBus, name: str = "test-bus", latency_timer_ms: float = 16.0) -> Session:
    url = register_bus(name, bus)
    port = PortHandler(url, latency_timer_ms=latency_timer_ms)
    port.setBaudRate(bus.baud)
    assert port.openPort()
    return Session(port, sdk.PacketHandler(2.0), bus, "dxlsim")


@pytest.fixture
def dxl():
    """An in-process session on a fresh 4-servo bus, virtual clock."""
    bus = make_bus()
    session = open_session(bus)
    yield session
    session.port.closePort()
    unregister_bus("test-bus")


@pytest.fixture
def emulator_process():
    """``hilsim emulate`` in a subprocess; yields (process, pty path)."""
    args = ("--ids", "1-4", "--baud", str(BAUD), "--rdt-us", "0")
    with emulated_pty(*args, timeout_s=10) as (proc, path):
        yield proc, path


@pytest.fixture(params=["dxlsim", "pty"])
def session(request):
    """The contract suite runs on both backends."""
    if request.param == "dxlsim":
        bus = make_bus()
        s = open_session(bus)
        yield s
        s.port.closePort()
        unregister_bus("test-bus")
        return
    emulator = request.getfixturevalue("emulator_process")
    _, path = emulator
    port = sdk.PortHandler(path)  # the SDK's own, unmodified PortHandler
    assert port.openPort()
    assert port.setBaudRate(BAUD)
    yield Session(port, sdk.PacketHandler(2.0), None, "pty")
    port.closePort()


def pytest_collection_modifyitems(config, items):
    if not hasattr(os, "openpty"):
        skip = pytest.mark.skip(reason="no pseudo-terminals on this OS")
        for item in items:
            if "pty" in item.name:
                item.add_marker(skip)
