"""Diagnosis: why the bus is slow, what to change, and the rate each change would give.

Four checks, run the same way on hardware and on the emulator (over the bus, through the SDK):

=================== ======================================================================
latency timer       USB adapter holds replies: ``/sys/bus/usb-serial/devices/ttyUSBn/
                    latency_timer`` where it exists, else inferred from single-read times
                    (measured − wire model ≈ 16 ms on an untuned FTDI)
return delay        Return Delay Time (addr 9, 2 µs units) of each servo; factory 500 µs
baud rate           below 1 Mbps
fast sync read      Ping model number + Firmware Version (addr 6): Fast Sync Read needs
                    ≥ 45 on X430/X540, ≥ 46 on X330
=================== ======================================================================

Every finding carries its fix and the wire-model rate with that fix alone; the diagnosis also
gives the rate with all fixes. Rates are for the best read the servos support (Fast when all
of them have it).
"""

from __future__ import annotations

import os
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from drivers.dynamixel.bench_session import BenchBus
from drivers.dynamixel.link import SYSFS_USB_SERIAL
from drivers.protocol2 import control_table as ct
from drivers.protocol2.wire_time import (
    DEFAULT_TURNAROUND_S,
    cycle_rate_hz,
    read_bytes,
    wire_time_s,
)
from hilsim._types import JsonDict

#: A latency timer at or above this (ms) is reported; FTDI's default is 16, tuned is 1.
LATENCY_FLAG_MS = 2.0
#: An excess read time above this (ms) is taken as an adapter latency timer.
LATENCY_INFER_MS = 0.5
#: A Return Delay Time at or above this (µs) is reported (the factory setting is 500).
RDT_FLAG_US = 20.0
#: Below this baud rate (bit/s) the baud rate is reported.
LOW_BAUD = 1_000_000
#: A USB serial adapter's latency timer, ``{name}`` its device (``ttyUSB0``).
SYSFS_LATENCY = str(SYSFS_USB_SERIAL / "{name}" / "latency_timer")


@dataclass(frozen=True)
class ServoFacts:
    """One servo as read over the bus; None where it did not answer."""

    id: int
    model_number: int | None
    model: str | None
    firmware: int | None
    fast_min_firmware: int | None
    return_delay_us: float | None

    @property
    def fast_read(self) -> bool | None:
        """Firmware has Fast Sync Read (None: unknown model or no answer)."""
        if self.firmware is None or self.fast_min_firmware is None:
            return None
        return self.firmware >= self.fast_min_firmware


@dataclass(frozen=True)
class BusFacts:
    """What the checks know about a bus. Times: ms for the adapter, µs for the servos."""

    port: str
    baud: int
    servos: tuple[ServoFacts, ...]
    turnaround_us: float
    read_time_ms: float | None  # median single Read of Present Position, measured
    read_model_ms: float | None  # the same from the wire model (no latency timer)
    sysfs_path: str | None
    sysfs_latency_ms: float | None

    @property
    def read_excess_ms(self) -> float | None:
        if self.read_time_ms is None or self.read_model_ms is None:
            return None
        return self.read_time_ms - self.read_model_ms

    @property
    def latency_timer_ms(self) -> float:
        """The adapter's latency timer: sysfs, else the measured excess when it is large."""
        if self.sysfs_latency_ms is not None:
            return self.sysfs_latency_ms
        excess = self.read_excess_ms
        return excess if excess is not None and excess >= LATENCY_INFER_MS else 0.0

    @property
    def latency_source(self) -> str:
        if self.sysfs_latency_ms is not None:
            return f"read from {self.sysfs_path}"
        return "inferred from measured read times"

    @property
    def fast_read(self) -> bool:
        """Every servo is known to have Fast Sync Read."""
        return bool(self.servos) and all(s.fast_read for s in self.servos)

    @property
    def return_delays_s(self) -> list[float]:
        return [(s.return_delay_us or 0.0) * 1e-6 for s in self.servos]


@dataclass(frozen=True)
class Finding:
    """One problem: what, why, how to fix it, and the model rate before / with the fix."""

    check: str
    problem: str
    fix: str
    current_hz: float
    predicted_hz: float | None
    alternatives: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> JsonDict:
        return {
            "check": self.check,
            "problem": self.problem,
            "fix": self.fix,
            "current_hz": self.current_hz,
            "predicted_hz": self.predicted_hz,
            "alternatives_hz": dict(self.alternatives),
        }


@dataclass(frozen=True)
class Diagnosis:
    facts: BusFacts
    findings: tuple[Finding, ...]
    current_hz: float
    all_fixed_hz: float

    def as_dict(self) -> JsonDict:
        f = self.facts
        return {
            "port": f.port,
            "baud": f.baud,
            "latency_timer_ms": f.latency_timer_ms,
            "latency_source": f.latency_source,
            "read_time_ms": f.read_time_ms,
            "read_model_ms": f.read_model_ms,
            "servos": [
                {
                    "id": s.id,
                    "model": s.model,
                    "model_number": s.model_number,
                    "firmware": s.firmware,
                    "fast_sync_read": s.fast_read,
                    "return_delay_us": s.return_delay_us,
                }
                for s in f.servos
            ],
            "read": "fast" if f.fast_read else "plain",
            "current_model_hz": self.current_hz,
            "all_fixed_model_hz": self.all_fixed_hz,
            "findings": [x.as_dict() for x in self.findings],
        }


# ------------------------------------------------------------------------------ gathering
def sysfs_latency(device: str | None) -> tuple[str | None, float | None]:
    """``(path, ms)`` of a USB serial adapter's latency timer, or ``(None, None)``."""
    if device is None:
        return None, None
    path = SYSFS_LATENCY.format(name=os.path.basename(device))
    try:
        with open(path) as fh:
            return path, float(fh.read().strip())
    except (OSError, ValueError):
        return None, None


def _servo_facts(bb: BenchBus, servo_id: int) -> ServoFacts:
    number = bb.ping(servo_id)
    name = min_fw = None
    if number is not None:  # the real servo's facts (the control table), not the emulator's
        name, min_fw = ct.model_name(number), ct.fast_read_min_firmware(number)
    fw = bb.read_item(servo_id, ct.FIRMWARE_VERSION)
    rdt = bb.read_item(servo_id, ct.RETURN_DELAY_TIME)  # 2 µs units
    return ServoFacts(servo_id, number, name, fw, min_fw, None if rdt is None else rdt * 2.0)


def gather_facts(bb: BenchBus, ids: Sequence[int], *, reads: int = 7) -> BusFacts:
    """Read what the checks need over the bus and time ``reads`` single reads."""
    servos = tuple(_servo_facts(bb, i) for i in ids)
    bus = bb.bus
    turnaround_s = bus.turnaround_s if bus is not None else DEFAULT_TURNAROUND_S
    path, sysfs_ms = sysfs_latency(bb.device)
    read_ms = model_ms = None
    probe = next((s for s in servos if s.return_delay_us is not None), None)
    if probe is not None:
        assert probe.return_delay_us is not None  # the first servo that has one
        clock, item = bb.clock, ct.PRESENT_POSITION
        times = []
        for _ in range(reads):
            t0 = clock.now()
            if bb.read(probe.id, item.addr, item.size) is not None:
                times.append(clock.now() - t0)
        if times:
            read_ms = statistics.median(times) * 1e3
            wire = wire_time_s(read_bytes(item.size), bb.baud)  # Read instruction + status
            model_ms = (wire + probe.return_delay_us * 1e-6 + turnaround_s) * 1e3
    return BusFacts(
        port=bb.url,
        baud=bb.baud,
        servos=servos,
        turnaround_us=round(turnaround_s * 1e6, 6),
        read_time_ms=read_ms,
        read_model_ms=model_ms,
        sysfs_path=path,
        sysfs_latency_ms=sysfs_ms,
    )


# ------------------------------------------------------------------------------ judging
@dataclass(frozen=True)
class _Config:
    baud: float
    fast: bool
    rdts: tuple[float, ...]
    latency_s: float
    turnaround_s: float

    def rate(self) -> float:
        return cycle_rate_hz(
            len(self.rdts),
            self.baud,
            self.fast,
            return_delay_s=list(self.rdts),
            turnaround_s=self.turnaround_s,
            latency_s=self.latency_s,
        )


def diagnose(facts: BusFacts) -> Diagnosis:
    """Judge ``facts``: findings with fixes and model rates (see the module docstring)."""
    now = _Config(
        baud=facts.baud,
        fast=facts.fast_read,
        rdts=tuple(facts.return_delays_s),
        latency_s=facts.latency_timer_ms * 1e-3,
        turnaround_s=facts.turnaround_us * 1e-6,
    )
    silent = [s.id for s in facts.servos if s.model_number is None]
    if silent:
        missing = Finding(
            "no_answer",
            f"ID(s) {', '.join(map(str, silent))} do not answer a Ping at {facts.baud} bps",
            "check power, wiring, the IDs and the baud rate (`hilsim scan` finds servos "
            "at every baud rate)" + _emulated(facts, "ids=..."),
            float("nan"),
            None,
        )
        return Diagnosis(facts, (missing,), float("nan"), float("nan"))
    current = now.rate()
    fixed = now
    findings = []
    ids = ", ".join(str(s.id) for s in facts.servos)

    latency_ms = facts.latency_timer_ms
    if latency_ms >= LATENCY_FLAG_MS:
        better = replace(now, latency_s=1e-3)
        fixed = replace(fixed, latency_s=1e-3)
        target = facts.sysfs_path or SYSFS_LATENCY.format(name="ttyUSB0")
        findings.append(
            Finding(
                "latency_timer",
                f"the USB adapter holds every reply for ≈ {latency_ms:.1f} ms "
                f"({facts.latency_source}); each read waits for it",
                f"set the latency timer to 1 ms: `echo 1 | sudo tee {target}` (until "
                'replugged; for good, a udev rule: ACTION=="add", SUBSYSTEM=="usb-serial", '
                'DRIVER=="ftdi_sio", ATTR{latency_timer}="1")' + _emulated(facts, "latency_ms=1"),
                current,
                better.rate(),
            )
        )

    big = [s for s in facts.servos if (s.return_delay_us or 0.0) >= RDT_FLAG_US]
    if big:
        zero = tuple(0.0 for _ in now.rdts)
        better = replace(now, rdts=zero)
        fixed = replace(fixed, rdts=zero)
        worst = max(s.return_delay_us or 0.0 for s in big)  # (all set: >= RDT_FLAG_US)
        findings.append(
            Finding(
                "return_delay",
                f"Return Delay Time up to {worst:.0f} µs on ID(s) "
                f"{', '.join(str(s.id) for s in big)}: "
                + ("paid once per Fast Sync Read" if now.fast else "paid by every servo in turn"),
                f"with torque off, write 0 to Return Delay Time (addr 9) on ID(s) {ids}"
                + _emulated(facts, "rdt_us=0"),
                current,
                better.rate(),
            )
        )

    if facts.baud < LOW_BAUD:
        better = replace(now, baud=1_000_000)
        fixed = replace(fixed, baud=1_000_000)
        findings.append(
            Finding(
                "baud_rate",
                f"{facts.baud} bps: every byte takes {1e6 * 10 / facts.baud:.0f} µs",
                "with torque off, write 3 (1 Mbps) to Baud Rate (addr 8) on every servo, then "
                "open the port at 1000000 (or 6 = 4 Mbps, if the adapter takes it: U2D2 does)"
                + _emulated(facts, "baud=1000000"),
                current,
                better.rate(),
                {"4000000": replace(now, baud=4_000_000).rate()},
            )
        )

    old = [s for s in facts.servos if s.fast_read is False]
    if old:
        better = replace(now, fast=True)
        fixed = replace(fixed, fast=True)
        detail = ", ".join(f"ID {s.id} {s.model} fw {s.firmware}" for s in old)
        findings.append(
            Finding(
                "fast_sync_read",
                f"no Fast Sync Read ({detail}): each servo answers with its own status packet",
                "update the firmware with DYNAMIXEL Wizard 2.0 (Tools > Firmware Update): "
                "≥ 45 on X430/X540, ≥ 46 on X330; then read with Fast Sync Read"
                + _emulated(facts, "firmware=46"),
                current,
                better.rate(),
            )
        )
    return Diagnosis(facts, tuple(findings), current, fixed.rate())


def _emulated(facts: BusFacts, key: str) -> str:
    """The same fix in ``dxlsim://`` URL terms, when the bus is the emulator."""
    return f" (emulator: {key} in the URL)" if facts.port.startswith("dxlsim:") else ""
