"""The Dynamixel driver: dynamixel-sdk behind snake_case, on any pyserial port and injected clock.

This package is the only place that imports ``dynamixel_sdk``.

The names below are imported on first use (PEP 562), so ``drivers.dynamixel.units`` or
``control_table`` can be used without loading the SDK. Bus scanning:
``from drivers.dynamixel.scan import scan`` (the module and the function share a name).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what the lazy names are, for type checkers (the import is at first use)
    from drivers.dynamixel.bus import DynamixelBus as DynamixelBus
    from drivers.dynamixel.errors import CommError as CommError
    from drivers.dynamixel.errors import CommTimeout as CommTimeout
    from drivers.dynamixel.errors import CorruptPacket as CorruptPacket
    from drivers.dynamixel.errors import DynamixelError as DynamixelError
    from drivers.dynamixel.errors import ExitNotConfirmed as ExitNotConfirmed
    from drivers.dynamixel.errors import Mismatch as Mismatch
    from drivers.dynamixel.errors import PortBusy as PortBusy
    from drivers.dynamixel.errors import PortGone as PortGone
    from drivers.dynamixel.errors import ServoError as ServoError
    from drivers.dynamixel.errors import StartupMismatch as StartupMismatch
    from drivers.dynamixel.link import LatencyTimerWarning as LatencyTimerWarning
    from drivers.dynamixel.link import Link as Link
    from drivers.dynamixel.startup import Expectation as Expectation
    from drivers.dynamixel.startup import ReadMode as ReadMode
    from drivers.dynamixel.startup import ServoState as ServoState
    from drivers.dynamixel.startup import StartupReport as StartupReport

_EXPORTS = {
    "DynamixelBus": "drivers.dynamixel.bus",
    "Expectation": "drivers.dynamixel.startup",
    "LatencyTimerWarning": "drivers.dynamixel.link",
    "Link": "drivers.dynamixel.link",
    "ReadMode": "drivers.dynamixel.startup",
    "ServoState": "drivers.dynamixel.startup",
    "StartupReport": "drivers.dynamixel.startup",
    "CommError": "drivers.dynamixel.errors",
    "CommTimeout": "drivers.dynamixel.errors",
    "CorruptPacket": "drivers.dynamixel.errors",
    "DynamixelError": "drivers.dynamixel.errors",
    "ExitNotConfirmed": "drivers.dynamixel.errors",
    "Mismatch": "drivers.dynamixel.errors",
    "PortBusy": "drivers.dynamixel.errors",
    "PortGone": "drivers.dynamixel.errors",
    "ServoError": "drivers.dynamixel.errors",
    "StartupMismatch": "drivers.dynamixel.errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
