"""dxlsim: an emulated bus of Dynamixel X-series servos that speaks Protocol 2.0 byte for byte,
or of Protocol 1.0-framed servos (Dynamixel AX/MX-P1, Feetech STS/SCS: :class:`P1Bus`).

Three ways in:

* ``serial.serial_for_url("dxlsim://?ids=1-4&model=XM430-W350")`` after ``import drivers.dxlsim``
  (URL keys: :class:`drivers.dxlsim.url.DxlsimUrl`), or a bus you built yourself under a name with
  :func:`register_bus` and opened as ``dxlsim://NAME``;
* :class:`drivers.dynamixel.port.PortHandler` (the dynamixel-sdk adapter) opens the same URLs;
* ``hilsim emulate`` serves a bus on a pseudo-terminal for unmodified serial programs.
"""

from __future__ import annotations

import serial

from drivers.dxlsim.bus import DxlBus, TraceRecord
from drivers.dxlsim.faults import Fault, FaultKind, FaultPlan, parse_fault_plan
from drivers.dxlsim.p1bus import P1Bus
from drivers.dxlsim.p1servo import P1Servo
from drivers.dxlsim.servo import VirtualServo
from drivers.dxlsim.url import DxlsimUrl, bus_from_url, register_bus, unregister_bus

__all__ = [
    "DxlBus",
    "DxlsimUrl",
    "Fault",
    "FaultKind",
    "FaultPlan",
    "P1Bus",
    "P1Servo",
    "TraceRecord",
    "VirtualServo",
    "bus_from_url",
    "parse_fault_plan",
    "register",
    "register_bus",
    "unregister_bus",
]


def register() -> None:
    """Make ``serial.serial_for_url`` understand ``dxlsim://`` (idempotent)."""
    if "drivers.dxlsim" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("drivers.dxlsim")


register()
