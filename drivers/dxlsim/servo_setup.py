"""A new virtual servo's start: its constructor's settings applied as Writes, once.

:class:`~drivers.dxlsim.servo.VirtualServo` calls :func:`apply_initial` at the end of its
constructor; kept apart so that the servo's module holds the instructions and their hot
paths.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.protocol2.control_table import EEPROM_END, StatusError

from . import registers as rg
from .models import ServoModel

if TYPE_CHECKING:
    from .servo import VirtualServo

#: Physical quantities a constructor override may set although the field is read-only.
INITIAL_STATE_FIELDS = ("present_position", "present_input_voltage", "present_temperature")


def goal_write_range(model: ServoModel) -> tuple[int, int, int]:
    """``(address, lo, hi)`` of the model's Goal Position when a Write of it can take the
    servo's short way (4 bytes, signed, writable RAM, no choices, not Indirect Data); the
    address is -1 when it cannot."""
    f = model.by_addr.get(rg.GOAL_POSITION)
    if (
        f is None
        or f.size != 4
        or not f.signed
        or not f.writable
        or f.choices
        or f.addr < EEPROM_END
        or f.addr in model.indirect
    ):
        return -1, 0, 0
    return f.addr, f.lo, f.hi


def apply_initial(
    servo: VirtualServo, id_: int, baud_index: int, rdt: int, overrides: dict[str, int]
) -> None:
    """The constructor's ID, baud, Return Delay Time and ``overrides`` (see
    :class:`~drivers.dxlsim.servo.VirtualServo`), validated like Writes; ValueError on
    anything invalid."""
    model = servo.model
    eeprom = {"id": id_, "baud_rate": baud_index, "return_delay_time": rdt}
    ram: dict[str, int] = {}
    state: dict[str, int] = {}
    for name, value in overrides.items():
        try:
            f = model.field(name)
        except KeyError as exc:
            raise ValueError(str(exc.args[0])) from None
        if f.name in INITIAL_STATE_FIELDS:
            state[f.name] = value
        elif not f.writable:
            raise ValueError(f"{f.name} is read-only")
        else:
            (eeprom if f.eeprom else ram)[f.name] = value
    # EEPROM first (torque is off), then the physical state, then torque, then RAM.
    for name, value in sorted(eeprom.items(), key=lambda kv: model.field(kv[0]).addr):
        _initial_write(servo, name, value)
    mo = servo._mo
    if "present_position" in state:
        mo.x = float(state["present_position"] - mo.offset())
        mo.hold(mo.x)
    if "present_input_voltage" in state:
        servo.set_input_voltage(state["present_input_voltage"] / 10.0)
    if "present_temperature" in state:
        servo.set_temperature(float(state["present_temperature"]))
    servo._regs[rg.GOAL_POSITION] = mo.present_position()
    if "torque_enable" in ram:
        _initial_write(servo, "torque_enable", ram.pop("torque_enable"))
    for name, value in sorted(ram.items(), key=lambda kv: model.field(kv[0]).addr):
        _initial_write(servo, name, value)


def _initial_write(servo: VirtualServo, name: str, value: int) -> None:
    f = servo.model.field(name)
    try:
        data = (value & rg.MASKS[f.size]).to_bytes(f.size, "little")
    except (TypeError, AttributeError):
        raise ValueError(f"{name} must be an int, got {value!r}") from None
    if not f.accepts(value):
        raise ValueError(f"{name}={value} is outside {f.lo}..{f.hi} {f.choices or ''}")
    err = servo.write(f.addr, data, servo.now) & 0x7F
    if err:
        raise ValueError(f"{name}={value} refused: {StatusError(err).name}")
