"""Rig configuration: one TOML file describes a figure's bus, loop, joints, safety and telemetry.

Loaded into frozen dataclasses. Degrees live only at the edge: every angle in the dataclasses is
in radians. Every error names the file, the key and what is allowed, e.g.::

    configs/demo.toml: joints[2].max_deg: must be greater than min_deg (-30.0), got -40.0

A minimal file::

    [bus]
    port = "dxlsim://?ids=1-2&rdt_us=0"    # or /dev/ttyUSB0, or a pty path
    baud = 1000000

    [loop]
    rate_hz = 500

    [[joints]]
    name = "head_pan"
    servo_id = 1
    min_deg = -60
    max_deg = 60
    spring = { frequency_hz = 3.0, damping_ratio = 0.7 }
    target = { type = "sine", amplitude_deg = 30, frequency_hz = 0.25 }

Every key, with its unit, default, what is allowed and an example: ``docs/rig.md``, generated
from the definitions here by ``python -m hilsim.rig.doc``.

Modules: :mod:`~hilsim.rig.model` (the dataclasses, each file key's facts in its field's
metadata; the bus's in :mod:`~hilsim.rig.bus`), :mod:`~hilsim.rig.keys` (that metadata),
:mod:`~hilsim.rig.forms` (spring forms, target keys), :mod:`~hilsim.rig.reader` and
:mod:`~hilsim.rig.load` (the loader), :mod:`~hilsim.rig.doc` (the reference's generator).
"""

from __future__ import annotations

from drivers.dynamixel.startup import ReadMode
from drivers.servo_bus import ExitPolicy
from hilsim.rig.bus import SUPPORTED_BAUDS, BusConfig
from hilsim.rig.forms import MAX_DAMPING_RATIO, MAX_FEEDFORWARD, MAX_RESPONSE, SPRING_HZ_RANGE
from hilsim.rig.load import load_rig, load_rigs, select_bus
from hilsim.rig.model import (
    KNOWN_MODELS,
    MAX_COMM_FAILURE_BUDGET_MS,
    MAX_EXIT_RETRIES,
    MAX_SOFT_START_S,
    MAX_STEPS_PER_S,
    MAX_TRACKING_TIME_MS,
    MAX_TRACKING_TOLERANCE_DEG,
    MIN_ACCEL_DEG_S2,
    MIN_SPEED_DEG_S,
    TRACKING_TIME_MS,
    TRACKING_TOLERANCE_DEG,
    WATCHDOG_MAX_MS,
    WATCHDOG_UNIT_MS,
    JointConfig,
    LoopConfig,
    OverrunPolicy,
    Rig,
    RigError,
    SafetyConfig,
    TelemetryConfig,
    TelemetryFailurePolicy,
)

__all__ = [
    "KNOWN_MODELS",
    "MAX_COMM_FAILURE_BUDGET_MS",
    "MAX_DAMPING_RATIO",
    "MAX_EXIT_RETRIES",
    "MAX_FEEDFORWARD",
    "MAX_RESPONSE",
    "MAX_SOFT_START_S",
    "MAX_STEPS_PER_S",
    "MAX_TRACKING_TIME_MS",
    "MAX_TRACKING_TOLERANCE_DEG",
    "MIN_ACCEL_DEG_S2",
    "MIN_SPEED_DEG_S",
    "SPRING_HZ_RANGE",
    "SUPPORTED_BAUDS",
    "TRACKING_TIME_MS",
    "TRACKING_TOLERANCE_DEG",
    "WATCHDOG_MAX_MS",
    "WATCHDOG_UNIT_MS",
    "BusConfig",
    "ExitPolicy",
    "JointConfig",
    "LoopConfig",
    "OverrunPolicy",
    "ReadMode",
    "Rig",
    "RigError",
    "SafetyConfig",
    "TelemetryConfig",
    "TelemetryFailurePolicy",
    "load_rig",
    "load_rigs",
    "select_bus",
]
