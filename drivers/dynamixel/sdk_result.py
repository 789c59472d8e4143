"""dynamixel-sdk's result codes, and the one place they become exceptions.

The SDK answers every transaction with an integer result code (``COMM_SUCCESS``,
``COMM_RX_TIMEOUT``, ...) and, for unicast replies, the status packet's ERR byte.
:func:`raise_for` turns the two into the tree of :mod:`drivers.dynamixel.errors`;
:func:`port_gone` wraps a vanished adapter's ``SerialException``/``OSError``
(:data:`SERIAL_ERRORS`). :data:`OK`, :data:`TIMEOUT` and :data:`CORRUPT` are the codes the
driver's own paths compare against (the per-tick reads, a broadcast Ping). Nothing above
:mod:`drivers.dynamixel` ever sees ``-3001``.
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import serial

from drivers.dynamixel.errors import (
    CommError,
    CommTimeout,
    CorruptPacket,
    PortBusy,
    PortGone,
    ServoError,
)
from drivers.protocol2 import control_table as ct

#: The transaction succeeded (a reply may still carry an error number: see :func:`raise_for`).
OK: int = sdk.COMM_SUCCESS
#: No status packet within the packet timeout.
TIMEOUT: int = sdk.COMM_RX_TIMEOUT
#: A status packet arrived malformed (CRC, length or header).
CORRUPT: int = sdk.COMM_RX_CORRUPT
#: What pyserial raises when the adapter vanishes (see :func:`port_gone`).
SERIAL_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError)

_RESULT_TEXT: dict[int, str] = {
    sdk.COMM_TX_FAIL: "the instruction packet could not be sent",
    sdk.COMM_RX_FAIL: "no status packet could be received",
    sdk.COMM_TX_ERROR: "the instruction packet is malformed",
    sdk.COMM_RX_WAITING: "a status packet is still arriving",
    sdk.COMM_NOT_AVAILABLE: "the instruction is not available",
}


def raise_for(
    result: int, error: int, servo_id: int | None, what: str, rx: list[int] | bytes | None = None
) -> None:
    """The one place SDK result codes and status error numbers become exceptions.

    Returns quietly when ``result`` is success and the error number (ERR bits 0-6) is 0;
    an Alert bit alone is not an error of the instruction. A :class:`CorruptPacket` gets
    ``complete``: True when ``rx`` (what the SDK received) is a whole status packet from
    ``servo_id`` - valid header, that ID, all LEN bytes - whose CRC fails (line noise, or
    two servos answering at once), False when the reply was cut short or never framed
    (late, truncated, garbage).
    """
    if result == OK:
        if error & ct.ERROR_NUMBER_MASK:
            raise ServoError(servo_id if servo_id is not None else -1, error, what)
        return
    who = "broadcast" if servo_id is None else f"servo {servo_id}"
    if result == TIMEOUT:
        raise CommTimeout(f"{who}: no reply to {what} (timeout)", servo_id=servo_id, what=what)
    if result == CORRUPT:
        exc = CorruptPacket(f"{who}: corrupt reply to {what}", servo_id=servo_id, what=what)
        exc.complete = _complete_reply(rx, servo_id)
        raise exc
    if result == sdk.COMM_PORT_BUSY:
        raise PortBusy(
            f"{who}: port busy during {what} (an earlier transaction never finished)",
            servo_id=servo_id,
            what=what,
        )
    text = _RESULT_TEXT.get(result, f"communication failed ({result})")
    raise CommError(f"{who}: {text} ({what})", servo_id=servo_id, what=what)


def _complete_reply(rx: list[int] | bytes | None, servo_id: int | None) -> bool:
    """``rx`` (the SDK's list, or bytes) is a whole status packet from ``servo_id``:
    header, ID, INST, every LEN byte."""
    return (
        rx is not None
        and servo_id is not None
        and len(rx) >= 11
        and bytes(rx[:4]) == b"\xff\xff\xfd\x00"
        and rx[4] == servo_id
        and rx[7] == 0x55
        and len(rx) == (rx[5] | rx[6] << 8) + 7
    )


def port_gone(exc: BaseException, port_name: str, what: str) -> PortGone:
    """The :class:`PortGone` to raise (``from exc``) when one of :data:`SERIAL_ERRORS`
    interrupted ``what`` on ``port_name``: the adapter vanished."""
    return PortGone(f"{port_name}: adapter gone during {what}: {exc}")
