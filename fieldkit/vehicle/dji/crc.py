"""The two checksums of DJI's OPEN protocol: CRC16 over the header, CRC32 over the frame.

Both are the usual reflected, table-driven CRCs (CRC-16/ARC's polynomial 0x8005 and the
standard CRC-32 polynomial 0x04C11DB7), but seeded with 0x3AA3 and without a final XOR
(docs/vehicles.md, spec §3.3-3.4). Stored little-endian, so a whole header (or frame) run
through its CRC gives 0: that residue is how a receiver checks it.

    crc16(b"123456789") == 0x2752
    crc32(b"123456789") == 0xE4D9DC14     # not 0xCBF43926, the zlib/Ethernet CRC-32
"""

from __future__ import annotations

import zlib

SEED = 0x3AA3
"""The start value of both CRCs (widened to 32 bits for CRC32)."""


def _table16() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_T16 = _table16()


def crc16(data: bytes | bytearray | memoryview, crc: int = SEED) -> int:
    """DJI's header CRC16 of `data` (reflected poly 0x8005, seed 0x3AA3, no final XOR)."""
    t = _T16
    for b in data:
        crc = (crc >> 8) ^ t[(crc ^ b) & 0xFF]
    return crc


def crc32(data: bytes | bytearray | memoryview) -> int:
    """DJI's frame CRC32 of `data` (standard reflected table, seed 0x3AA3, no final XOR).

    zlib inverts its start value on the way in and its result on the way out; inverting
    both around it leaves the plain table CRC with our seed, at C speed.
    """
    return ~zlib.crc32(data, ~SEED & 0xFFFFFFFF) & 0xFFFFFFFF


__all__ = ["SEED", "crc16", "crc32"]
