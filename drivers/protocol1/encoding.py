"""Words on the wire: byte order and sign-magnitude, as each family stores them.

* Dynamixel P1 (AX, MX) and Feetech STS/SMS: little-endian words.
* Feetech SCS: big-endian words (Feetech SDK ``SCS_END = 1``; LeRobot protocol 1).
* Feetech STS/SMS signed values are sign-magnitude, not two's complement: the magnitude in
  the low bits, the sign in one bit (15 for Goal/Present Position and Velocity, 11 for
  Homing Offset, 10 for Present Load: Feetech SDK ``SCS_TOHOST(a, b)`` / ``SCS_TOSCS``).
* Dynamixel P1 speed and load: a 10-bit magnitude with the direction in bit 10, which is
  sign-magnitude with sign bit 10 (1 = clockwise / negative here).
"""

from __future__ import annotations


def to_sign_magnitude(value: int, sign_bit: int) -> int:
    """``value`` as magnitude | (sign << sign_bit); ValueError if the magnitude does not fit."""
    mag = -value if value < 0 else value
    if mag >= 1 << sign_bit:
        raise ValueError(f"|{value}| does not fit below sign bit {sign_bit}")
    return mag | (1 << sign_bit) if value < 0 else mag


def from_sign_magnitude(raw: int, sign_bit: int) -> int:
    """The signed value of ``raw`` (bits above ``sign_bit`` ignored); -0 reads 0."""
    mag = raw & ((1 << sign_bit) - 1)
    return -mag if raw >> sign_bit & 1 else mag


def encode_word(value: int, size: int, big_endian: bool = False) -> bytes:
    """``value`` (unsigned, wrapped to ``size`` bytes) in the family's byte order."""
    return (int(value) & ((1 << (8 * size)) - 1)).to_bytes(size, "big" if big_endian else "little")


def decode_word(data: bytes | bytearray, big_endian: bool = False) -> int:
    """The unsigned value of ``data`` in the family's byte order."""
    return int.from_bytes(data, "big" if big_endian else "little")
