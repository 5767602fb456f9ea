"""CRC-16/CCITT-FALSE, one byte per clock, for the packet layer.

# Ref: ITU-T V.41 polynomial; the parameters, the bit-serial definition and the zero-residue
# property the receiver relies on are in :mod:`mrm_cosim.protocol.crc`.

:func:`crc16_next` builds the update of one byte (eight steps of the long division) as an XOR
network (the eight steps unrolled into one GF(2)-linear map, each new bit the XOR of fixed old
register and data bits), so the :class:`CRC16` component handles one byte per cycle with no
state machine.
"""

from amaranth import *
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from mrm_cosim.protocol.crc import CRC16_INIT, CRC16_POLY

__all__ = ["crc16_next", "CRC16"]


def _next_state_taps():
    """Which register and data bits feed each bit of the register after one byte.

    The update is linear over GF(2), so each new bit is the XOR of a fixed set of old register
    bits and data bits. Run the eight bit steps on sets instead of bits to find them.

    Returns
    -------
    list of (frozenset of int, frozenset of int), length 16
        For new bit ``i``: (old register bits, data bits).
    """
    # Bit i of the register is a set of symbols: ("c", j) old register bit j, ("d", j) data bit j.
    reg = [{("c", i)} for i in range(16)]
    for i in range(8):
        reg[8 + i] = reg[8 + i] ^ {("d", i)}
    for _ in range(8):
        top = reg[15]
        reg = [set()] + reg[:15]
        for i in range(16):
            if (CRC16_POLY >> i) & 1:
                reg[i] = reg[i] ^ top
    return [(frozenset(j for kind, j in bit if kind == "c"),
             frozenset(j for kind, j in bit if kind == "d")) for bit in reg]


_TAPS = _next_state_taps()


def crc16_next(crc, byte):
    """Return the expression of the CRC register after one more byte.

    Parameters
    ----------
    crc : Value, 16 bits
        Register before the byte.
    byte : Value, 8 bits
        The data byte.

    Returns
    -------
    Value, 16 bits
        Each bit an XOR of register and data bits (the unrolled eight-step division).
    """
    crc, byte = Value.cast(crc), Value.cast(byte)
    bits = []
    for reg_taps, data_taps in _TAPS:
        terms = [crc[j] for j in sorted(reg_taps)] + [byte[j] for j in sorted(data_taps)]
        bits.append(Cat(*terms).xor())
    return Cat(*bits)


class CRC16(wiring.Component):
    """Byte-serial CRC-16/CCITT-FALSE register.

    Attributes
    ----------
    start : In(1)
        Restart from the initial value 0xFFFF. If ``valid`` is also asserted, ``data`` is the
        first byte of the new computation.
    valid : In(1)
        ``data`` holds a byte to fold in at this clock edge.
    data : In(8)
        The byte.
    crc : Out(16)
        CRC of the bytes folded in since the last ``start`` (registered: it reflects a byte one
        cycle after ``valid``). Equals 0 after a frame followed by its own CRC, high byte first.
    """

    start: In(1)
    valid: In(1)
    data:  In(8)
    crc:   Out(16, init=CRC16_INIT)

    def elaborate(self, platform):
        m = Module()

        base = Mux(self.start, C(CRC16_INIT, 16), self.crc)
        with m.If(self.valid):
            m.d.sync += self.crc.eq(crc16_next(base, self.data))
        with m.Elif(self.start):
            m.d.sync += self.crc.eq(CRC16_INIT)

        return m
