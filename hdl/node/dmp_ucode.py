"""Microprogram of the DMP generator (:mod:`.dmp`): one step's computation as micro-operations.

Every micro-operation takes the same five cycles (read, operands, product, sum, write) and
does::

    A, B  = (RF[ra] | r | f | 1),  (RF[rb] | EXT[ebase + (0 | i | j | n)])    if mul
    p     = A · B + rc                                                         (else p is kept)
    z     = sat((X ± Y) >> sh),    X = RF[ra] | 0,   Y = p | RF[rb]
    dst  ← z                        (RF[wa], the exp input, a pending output; if cond)

``RF`` is the register file (intermediate values, the state x, v, φ, constants), ``EXT`` the
parameter memory (host words, the exp table, the exp unit's shift scales), ``r`` the exp
input's interpolation fraction, ``f`` the divider's result. Loops over the basis are a branch
field; the divider is one micro-operation that holds the sequencer for its 34 quotient bits.
Every rounding point of :mod:`.dmp_ref` is one micro-operation: ``rs(a·b, n)`` is a product
with ``rc = 2^(n−1)`` and ``sh = n`` for n = 20 or 32, or ``rs(a·2^k·b, n + k)`` with the
narrow operand prescaled in the register file (``2^k·b`` exact, so the same value), so the
shifter has four settings and the outputs are the reference's bit for bit. Cycles:
``step_cycles(n) = 278 + 90 n``: 48 + 18 n micro-operations of five cycles (OP_CYCLES) and the
divider's, which takes 38 (DIV_CYCLES: its read and operand phases, 34 quotient bits, the
rounding cycle, the write phase).
"""

from amaranth import unsigned
from amaranth.lib import data, enum

from mrm_cosim.protocol.dmp import N_SCALARS, Reg

__all__ = ["ASel", "BSel", "YSel", "Sat", "Dst", "Cond", "EOff", "Br", "SHIFTS", "RF",
           "RF_INIT", "RF_WIDTH", "OP_CYCLES", "DIV_CYCLES", "instr_layout", "program",
           "split_labels", "assemble"]

RF_WIDTH = 72           # register-file word: u = t² (67 bits) and Σψw (≤ 60) fit
OP_CYCLES = 5           # read, operands, product, sum, write
DIV_CYCLES = 2 + 34 + 1 + 1  # the divider's: read, operands, quotient bits, rounding, write
SHIFTS = (0, 8, 20, 32)  # every rounding shift is one of these (a narrow operand is prescaled)
RCS = (0, 1 << 7, 1 << 19, 1 << 31)  # the product's rounding constants


class ASel(enum.Enum, shape=2):
    RF = 0
    R = 1               # the exp input's fraction bits (interpolation weight)
    F = 2               # the divider's rounded quotient
    ONE = 3


class BSel(enum.Enum, shape=1):
    RF = 0
    EXT = 1


class YSel(enum.Enum, shape=1):
    P = 0
    RF = 1


class Sat(enum.Enum, shape=3):
    NONE = 0
    S24 = 1
    S35 = 2
    S40 = 3
    U46 = 4             # clamp to 0 … 2^46 − 1 (φ, the exp input)


class Dst(enum.Enum, shape=3):
    NONE = 0
    RF = 1
    EIN = 2
    QD = 3
    VD = 4
    AD = 5


class Cond(enum.Enum, shape=3):
    ALWAYS = 0
    INIT = 1            # the computation a start strobe began
    FLAG = 2            # the last flag-setting operation's result was negative
    NFLAG = 3
    GS = 4              # goal scaling
    NGS = 5


class EOff(enum.Enum, shape=2):
    NONE = 0
    I = 1               # noqa: E741 — the basis index
    J = 2               # the exp input's table index
    N = 3               # the exp input's integer part


class Br(enum.Enum, shape=2):
    NONE = 0
    LOOP = 1            # i = n − 1: i ← 0, next; else i ← i + 1, go to tgt
    NZERO = 2           # n = 0: go to tgt
    END = 3             # the computation is done


_NAMES = ("ZERO BIG C64 C128 C256 C1024 C2048 C4096 C16384 C65536 "
          "X V PHI G G12 AMP IT IT10 DT8 PR6 AB8 RADC6 RADC7 K DPHI S S10 UMIN NUM DEN "
          "DS DS64 TT U T0 DIF SL YV PSI MAG E8 T1 TMP").split()
#: Register-file addresses by name; after the divider the basis temporaries are reused.
RF = {name: a for a, name in enumerate(_NAMES)}
RF.update(SF=RF["DS"], FORCE=RF["TT"], DAMP=RF["U"], VDOT=RF["YV"], A1=RF["PSI"],
          A2=RF["MAG"], VT=RF["UMIN"])
RF_INIT = [1 << 70 if n == "BIG" else int(n[1:]) if n[0] == "C" else 0 for n in _NAMES]
_RF_BITS = 6
assert len(_NAMES) <= 1 << _RF_BITS


def instr_layout(ext_bits: int, pc_bits: int) -> data.StructLayout:
    """One micro-operation word."""
    return data.StructLayout({
        "ra": _RF_BITS, "rb": _RF_BITS, "wa": _RF_BITS,
        "asel": ASel, "bsel": BSel, "mul": 1, "rc": 2,
        "xz": 1, "ysel": YSel, "neg": 1, "sh": unsigned(2), "sat": Sat,
        "dst": Dst, "cond": Cond, "setf": 1, "div": 1,
        "ebase": ext_bits, "eoff": EOff, "br": Br, "tgt": pc_bits,
    })


def _mul(a, b, n=0, **kw):
    """``rs(a·b, n)``: ``a``/``b`` a register name or an ASel/EXT source."""
    op = dict(mul=1, rc=RCS.index(1 << n >> 1) if n else 0, xz=1, sh=n, **kw)
    if isinstance(a, ASel):
        op["asel"] = a
    else:
        op["ra"] = a
    if b == "EXT":
        op["bsel"] = BSel.EXT
    else:
        op["rb"] = b
    return op


def _alu(x, y, neg=False, **kw):
    """``x ± y`` of two registers."""
    return dict(ra=x, rb=y, ysel=YSel.RF, neg=int(neg), **kw)


def _exp(ext0, dst):
    """``dst = 2^(−ein)`` (exp unit; the input already in ``ein``)."""
    return [
        _mul(ASel.ONE, "EXT", ebase=ext0, eoff=EOff.J, dst=Dst.RF, wa="T0"),
        dict(_mul(ASel.ONE, "EXT", ebase=ext0 + 1, eoff=EOff.J, dst=Dst.RF, wa="DIF"),
             ra="T0", xz=0, neg=1),                                       # T[j] − T[j+1]
        _mul(ASel.R, "DIF", 32, dst=Dst.RF, wa="SL"),                     # r·2^8: rs(·, 24)
        _alu("T0", "SL", neg=True, dst=Dst.RF, wa="YV"),                  # interpolated y
        _mul("YV", "EXT", 32, ebase=ext0 + 257, eoff=EOff.N, dst=Dst.RF, wa=dst),  # rs(y, n+2)
    ]


def _basis_t(mb):
    """``u = t²``, ``t = rs((s − c_i)·R_i, 14) = rs((s − c_i)·2^6·R_i, 20)``."""
    return [
        dict(_mul(ASel.ONE, "EXT", ebase=N_SCALARS + mb, eoff=EOff.I, dst=Dst.RF, wa="DS"),
             ra="S", xz=0, neg=1),                                        # s − c_i
        _mul("DS", "C64", dst=Dst.RF, wa="DS64"),
        _mul("DS64", "EXT", 20, ebase=N_SCALARS + 2 * mb, eoff=EOff.I, dst=Dst.RF, wa="TT"),
        _mul("TT", "TT", dst=Dst.RF, wa="U"),
    ]


def program(max_basis: int, ext0: int) -> list:
    """The micro-operations of one step's computation (labels as strings), ``ext0`` the
    address of the exp table in the parameter memory."""
    ext, mb = "EXT", max_basis
    rf = dict(dst=Dst.RF)
    return [
        # Latch g and 1/τ; the state from X0, V0 after a start.
        dict(_mul(ASel.ONE, ext, ebase=Reg.GOAL), **rf, wa="G"),
        dict(_mul(ASel.ONE, ext, ebase=Reg.INVTAU), **rf, wa="IT"),
        # Narrow operands prescaled, so that every rounding shift is 20 or 32.
        dict(_mul("C1024", "IT"), **rf, wa="IT10"),
        dict(_mul("C256", ext, ebase=Reg.DT), **rf, wa="DT8"),
        dict(_mul("C64", ext, ebase=Reg.PHASE_RATE), **rf, wa="PR6"),
        dict(_mul("C256", ext, ebase=Reg.ALPHA_BETA), **rf, wa="AB8"),
        dict(_mul("C64", ext, ebase=Reg.RADC), **rf, wa="RADC6"),
        dict(_mul("C128", ext, ebase=Reg.RADC), **rf, wa="RADC7"),
        dict(_mul("C4096", ext, ebase=Reg.X0), **rf, wa="X", cond=Cond.INIT),
        dict(_mul("C64", ext, ebase=Reg.V0), **rf, wa="V", cond=Cond.INIT),
        _alu("ZERO", "ZERO", **rf, wa="PHI", cond=Cond.INIT),
        dict(_mul("G", "C4096"), rc=RCS.index(1 << 7), **rf, wa="G12"),    # (g << 12) + 2^7
        dict(_mul(ASel.ONE, ext, ebase=Reg.X0), ra="G", xz=0, neg=1, **rf, wa="AMP",
             cond=Cond.GS),                                               # g − x0
        dict(_mul(ASel.ONE, ext, ebase=Reg.AMPLITUDE), **rf, wa="AMP", cond=Cond.NGS),
        dict(_mul("DT8", "IT", 20), **rf, wa="K"),                          # rs(DT·IT, 12)
        dict(_mul("K", "PR6", 20), **rf, wa="DPHI"),                        # rs(k·PR, 14)
        # Phase s = rs(E(φ), 6).
        _alu("PHI", "ZERO", dst=Dst.EIN),
        *_exp(ext0, "PSI"),
        dict(_mul("C16384", "PSI", 20), **rf, wa="S"),                     # rs(E, 6)
        dict(_mul("S", "C1024"), **rf, wa="S10"),
        _alu("BIG", "ZERO", **rf, wa="UMIN"),
        _alu("ZERO", "ZERO", **rf, wa="NUM"),
        _alu("ZERO", "ZERO", **rf, wa="DEN", br=Br.NZERO, tgt="div"),
        # First pass: u_min.
        "pass1",
        *_basis_t(mb),
        _alu("UMIN", "U", neg=True, setf=1),                              # flag: u > u_min
        _alu("U", "ZERO", **rf, wa="UMIN", cond=Cond.NFLAG, br=Br.LOOP, tgt="pass1"),
        # Second pass: ψ_i = E(min(u_i − u_min, PHI_MAX)), Σψw, Σψ.
        "pass2",
        *_basis_t(mb),
        _alu("U", "UMIN", neg=True, sat=Sat.U46, dst=Dst.EIN),
        *_exp(ext0, "PSI"),
        dict(_mul("PSI", ext, ebase=N_SCALARS, eoff=EOff.I), xz=0, ysel=YSel.RF, rb="DEN",
             **rf, wa="DEN"),                                             # p = ψw, Σψ
        dict(ra="NUM", **rf, wa="NUM", br=Br.LOOP, tgt="pass2"),          # Σψw
        # f = ±((q + 1) >> 1), q = floor(|num| 2^10 / den).
        "div",
        _alu("NUM", "ZERO", setf=1, **rf, wa="MAG"),
        _alu("ZERO", "NUM", neg=True, **rf, wa="MAG", cond=Cond.FLAG),
        dict(ra="MAG", rb="DEN", div=1),
        # Forcing and acceleration.
        dict(_mul(ASel.F, "S10", 32), **rf, wa="SF"),                      # rs(s·f, 22)
        dict(_mul("SF", "AMP", 20), **rf, wa="FORCE"),
        _alu("G12", "X", neg=True, sh=8, **rf, wa="E8"),                  # rs((g<<12) − x, 8)
        dict(_mul("E8", "AB8", 20), **rf, wa="T1"),                         # rs(e·AB, 12)
        dict(_mul("V", ext, 20, ebase=Reg.ALPHA), **rf, wa="DAMP"),
        _alu("T1", "DAMP", neg=True, **rf, wa="TMP"),
        _alu("TMP", "FORCE", sat=Sat.S35, **rf, wa="VDOT"),
        # Pending outputs.
        dict(_mul("VDOT", "IT", 20), sat=Sat.S35, **rf, wa="A1"),
        dict(_mul("A1", "IT", 20), sat=Sat.S35, **rf, wa="A2"),
        dict(_mul("A2", "RADC6", 32), sat=Sat.S24, dst=Dst.AD),            # rs(·RADC, 26)
        dict(_mul("V", "IT10", 32), sat=Sat.S35, **rf, wa="VT"),           # rs(v·IT, 22)
        dict(_mul("VT", "RADC7", 32), sat=Sat.S24, dst=Dst.VD),            # rs(·RADC, 25)
        _alu("X", "C2048", sh=8, **rf, wa="TMP"),                          # rs(x, 12) =
        dict(_mul("TMP", "C65536"), sh=20, sat=Sat.S24, dst=Dst.QD),       # ⌊(x+2^11)/2^8⌋ >> 4
        # State update.
        dict(_mul("K", "VDOT", 32), **rf, wa="TMP"),
        _alu("V", "TMP", sat=Sat.S35, **rf, wa="V"),
        dict(_mul("K", "V", 32), **rf, wa="TMP"),
        _alu("X", "TMP", sat=Sat.S40, **rf, wa="X"),
        _alu("PHI", "DPHI", sat=Sat.U46, **rf, wa="PHI", br=Br.END),
    ]


def split_labels(prog: list) -> tuple[dict, list]:
    """``prog``'s labels (name → index of the micro-operation after it) and its
    micro-operations, in order."""
    labels, ops = {}, []
    for item in prog:
        if isinstance(item, str):
            labels[item] = len(ops)
        else:
            ops.append(item)
    return labels, ops


def assemble(prog: list, layout: data.StructLayout) -> list[int]:
    """ROM words of ``prog`` (labels resolved, register names to addresses)."""
    labels, ops = split_labels(prog)
    words = []
    for op in ops:
        fields = dict(op)
        for k in ("ra", "rb", "wa"):
            if isinstance(fields.get(k), str):
                fields[k] = RF[fields[k]]
        if isinstance(fields.get("tgt"), str):
            fields["tgt"] = labels[fields["tgt"]]
        if "sh" in fields:
            fields["sh"] = SHIFTS.index(fields["sh"])
        word = 0
        for name, field in layout:
            value = fields.pop(name, 0)
            value = value.value if isinstance(value, enum.Enum) else int(value)
            width = field.width
            if not 0 <= value < 1 << width:
                raise ValueError(f"field {name} = {value} does not fit {width} bits")
            word |= value << field.offset
        if fields:
            raise ValueError(f"unknown fields {sorted(fields)}")
        words.append(word)
    return words
