"""Protocol 2.0's CRC-16: polynomial 0x8005, initial value 0, MSB first, not reflected, over
the header through the last (stuffed) parameter byte. One table, shared by the emulator's codec
and the driver's Fast Sync Read parser (the SDK's own ``updateCRC`` rebuilds its table on every
call: 13 µs for one 4-servo packet)."""

from __future__ import annotations


def _make_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


#: the CRC of each high byte: crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
CRC_TABLE: tuple[int, ...] = _make_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16 of ``data`` continuing from ``crc``."""
    table = CRC_TABLE
    for byte in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc
