"""A dual-axis case (2XL430-W250): two servos, one communication module.

Baud Rate and Protocol Type, once changed on one axis, are the other's too, and neither axis
may take the other's ID (2xl430-w250.md, Baud Rate and Protocol Type cautions).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.dxlsim import registers as rg

if TYPE_CHECKING:
    from drivers.dxlsim.servo import VirtualServo

__all__ = ["pair_axes", "share_module"]


def share_module(servo: VirtualServo) -> None:
    """Copy ``servo``'s Baud Rate and Protocol Type to its other axis, if it has one."""
    partner = servo.partner
    if partner is not None:
        for a in (rg.BAUD_RATE, rg.PROTOCOL_TYPE):
            partner._regs[a] = servo._regs[a]
        partner._derive()  # its listening baud


def pair_axes(a: VirtualServo, b: VirtualServo) -> None:
    """Make ``a`` and ``b`` the two axes of one dual-axis case (2XL430-W250): one Baud Rate
    and Protocol Type between them (``b`` takes ``a``'s), and neither may take the other's
    ID. Raises ValueError when the model has no second axis or the IDs are equal."""
    for s in (a, b):
        if s.model.axes != 2:
            raise ValueError(f"{s.model.name} has one axis; only a dual-axis model pairs")
    if a.id == b.id:
        raise ValueError(f"the two axes of one {a.model.name} need two IDs, got {a.id} twice")
    a.partner, b.partner = b, a
    share_module(a)
