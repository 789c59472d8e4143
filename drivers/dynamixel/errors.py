"""Everything the Dynamixel driver raises, in one tree.

::

    ServoBusError                      (drivers.servo_bus: the backend-neutral root)
     └── DynamixelError
          ├── CommError                a transaction failed on the wire
          │    ├── CommTimeout         no status packet in time      (also a TimeoutError)
          │    ├── CorruptPacket       a reply with a bad CRC, length or header
          │    └── PortBusy            the port is still marked in use by an earlier call
          ├── PortGone                 the adapter vanished (unplugged); wraps the
          │                            SerialException/OSError    (also a ConnectionError)
          ├── ServoError               a status packet with an error number ≠ 0
          ├── StartupMismatch          the servos differ from what the rig expects (a table)
          └── ExitNotConfirmed         the exit policy could not be confirmed on some servos

dynamixel-sdk's integer result codes become these in exactly one place,
:func:`drivers.dynamixel.sdk_result.raise_for`; nothing above the driver ever sees ``-3001``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from drivers.protocol2.control_table import (
    ALERT_BIT,
    ERROR_NUMBER_MASK,
    error_name,
)
from drivers.servo_bus import ExitReport, ServoBusError


class DynamixelError(ServoBusError):
    """Root of the Dynamixel driver's errors."""


class CommError(DynamixelError):
    """A transaction with ``servo_id`` (None: broadcast) failed: ``what`` was being done."""

    def __init__(self, message: str, *, servo_id: int | None = None, what: str = "") -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.what = what


class CommTimeout(CommError, TimeoutError):  # noqa: N818  (names read as what happened)
    """No status packet arrived before the packet timeout."""


class CorruptPacket(CommError):  # noqa: N818  (names read as what happened)
    """A status packet arrived but was malformed (CRC, length or header)."""

    #: a whole status packet from the servo asked whose CRC fails (line noise, two servos at
    #: once), not one cut short or never framed: set by :func:`~.sdk_result.raise_for`
    complete: bool = False


class PortBusy(CommError):  # noqa: N818  (names read as what happened)
    """The SDK still marks the port in use (an earlier transaction never finished)."""


class PortGone(DynamixelError, ConnectionError):  # noqa: N818  (names read as what happened)
    """The serial adapter is gone (unplugged, or the device node vanished).

    ``__cause__`` is the original :class:`serial.SerialException` or :class:`OSError`.
    Nothing more can be sent: the exit policy cannot be applied.
    """


class ServoError(DynamixelError):
    """Servo ``servo_id`` answered ``what`` with error number ``number`` (ERR bits 0-6).

    ``error`` is the raw ERR byte; ``alert`` is its bit 7 (a hardware error is latched,
    read Hardware Error Status, addr 70). An Alert bit alone is not raised: the
    instruction succeeded, and the start-up check and every read report the alert.
    """

    def __init__(self, servo_id: int, error: int, what: str = "") -> None:
        self.servo_id = servo_id
        self.error = int(error)
        self.number = self.error & ERROR_NUMBER_MASK
        self.name = error_name(self.number)
        self.alert = bool(self.error & ALERT_BIT)
        self.what = what
        text = f"servo {servo_id}: {self.name} ({self.number})"
        if what:
            text += f" on {what}"
        if self.alert:
            text += "; Alert bit set: a hardware error is latched (read addr 70)"
        super().__init__(text)


@dataclass(frozen=True, slots=True)
class Mismatch:
    """One difference between a servo and its expectation; ``fix`` says what to do."""

    servo_id: int
    item: str
    expected: str
    found: str
    fix: str = ""


_HEADERS = ("id", "item", "expected", "found", "fix")


def render_table(rows: Iterable[Mismatch]) -> str:
    """Mismatches as one aligned text table, one line per row, sorted by servo ID."""
    cells = [_HEADERS] + [
        (str(r.servo_id), r.item, r.expected, r.found, r.fix)
        for r in sorted(rows, key=lambda r: r.servo_id)
    ]
    widths = [max(len(row[c]) for row in cells) for c in range(len(_HEADERS))]
    lines = []
    for k, row in enumerate(cells):
        lines.append("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


class StartupMismatch(DynamixelError):  # noqa: N818  (names read as what happened)
    """The start-up check found differences; ``rows`` holds every one of them (data),
    ``str()`` renders them as one aligned table."""

    def __init__(self, rows: Iterable[Mismatch], port: str = "") -> None:
        self.rows: tuple[Mismatch, ...] = tuple(sorted(rows, key=lambda r: r.servo_id))
        self.port = port
        where = f" on {port}" if port else ""
        ids = sorted({r.servo_id for r in self.rows})
        super().__init__(
            f"start-up check failed{where}: {len(self.rows)} mismatch(es) on servo(s) "
            f"{ids}\n{render_table(self.rows)}"
        )

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return tuple(sorted({r.servo_id for r in self.rows}))


class ExitNotConfirmed(DynamixelError):  # noqa: N818  (names read as what happened)
    """The exit policy could not be confirmed on some servos; ``report`` names them
    (:class:`~drivers.servo_bus.ExitReport`) with the reason for each."""

    def __init__(self, report: ExitReport) -> None:
        self.report = report
        super().__init__(str(report))

    @property
    def servo_ids(self) -> tuple[int, ...]:
        return self.report.unconfirmed_ids
