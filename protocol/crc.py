"""CRC-16/CCITT-FALSE of the packet layer: its parameters and the byte-wise function.

# Ref: ITU-T V.41 polynomial; parameters as catalogued by reveng ("CRC-16/IBM-3740", alias
# "CRC-16/CCITT-FALSE"): width 16, poly 0x1021, init 0xFFFF, refin/refout false, xorout 0,
# check("123456789") = 0x29B1, residue 0x0000.

Each data byte updates the register as eight steps of the long division, most significant bit
first::

    crc ^= byte << 8
    repeat 8:  crc = (crc << 1) ^ (0x1021 if crc & 0x8000 else 0)      (16 bits kept)

Because the CRC is not reflected and has no output XOR, running the same register over a frame
*followed by its CRC sent high byte first* leaves the register at 0 (the residue). A receiver
uses that: it does not need to know where the payload ends to check a frame.

The gateware's one-byte-per-cycle register is :class:`~mrm_cosim.hdl.link.crc.CRC16`; frames
(:mod:`.packet`) and the nodes' upload check (:func:`~.regs.upload_check`) use :func:`crc16`.
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["CRC16_POLY", "CRC16_INIT", "CRC16_CHECK", "crc16"]

CRC16_POLY  = 0x1021
CRC16_INIT  = 0xFFFF
CRC16_CHECK = 0x29B1  # CRC of the ASCII bytes "123456789"


def _make_table() -> tuple[int, ...]:
    """The register after one byte ``b`` from 0, for each ``b``: the table of :func:`crc16`."""
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC16_POLY if crc & 0x8000 else crc << 1) & 0xFFFF
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _make_table()


def crc16(data: Iterable[int], crc: int = CRC16_INIT) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (bytes or ints 0..255), continuing from ``crc``."""
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[(crc >> 8) ^ byte]
    return crc
