"""Instruction set, program builder and scheduler of the node's multiply-accumulate engine.

The engine (:mod:`mrm_cosim.hdl.node.engine`) issues one instruction per cycle from a ROM. A
program is written as *statements* over named registers, each with a fixed-point format
(:mod:`.fixed`)::

    dst = sat24( round( Σ ± a_k · b_k ) )        (MAC; "a_k" alone means a_k · 1)
    dst = min(a, b) / max(a, b)                   (MIN / MAX, same format)
    MARK                                          (pulse ``mark`` once all earlier writes landed)
    END                                           (stop; ``done`` once all writes landed)

A statement's exact sum is rounded once, half up, onto the destination's LSB and saturated to
24 bits (or wrapped). The compiler turns it into one instruction per term: the product of term
``k`` is shifted left by ``pshift_k`` so that all terms share the finest LSB ``L`` of the
statement, the accumulator adds them exactly, and the last term carries the write-back: round
by ``oshift = lsb(dst) − L`` and saturate. Every term of a statement carries its ``oshift``
(the first one starts the sum from the rounding constant). A term ``x`` without a second
factor multiplies by a unit constant ``2^k · 2^-k`` (k in :data:`UNIT_SHIFTS`) chosen so its
shift stays small.

The scheduler orders statements (respecting read-after-write with the pipeline's
:data:`LATENCY`, and keeping write-after-read and write-after-write pairs in program order) and
fills the gaps with NOPs, so the pipelined engine computes exactly what executing the
statements one after the other computes (:mod:`mrm_cosim.hdl.node.engine_ref` checks both).

Addresses are :data:`ADDR_BITS` wide: the register file below :data:`IO_BASE`, the engine's
input ports (read) and output registers (write) at ``IO_BASE + k``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from .fixed import WORD_MAX, WORD_MIN, Fmt

__all__ = ["LATENCY", "ADDR_BITS", "IO_BASE", "IO_PORTS", "PSHIFT_MAX", "OSHIFT_MAX",
           "MAX_TERMS", "UNIT_SHIFTS", "ACC_WIDTH", "Op", "Instr", "INSTR_FIELDS", "INSTR_BITS",
           "encode", "decode", "mem_depth", "Term", "T", "Reg", "Program", "Microcode"]

LATENCY = 7        # issue of a statement's last term → first issue that may read its result
ADDR_BITS = 9
IO_PORTS = 16
IO_BASE = (1 << ADDR_BITS) - IO_PORTS
PSHIFT_MAX = 15
OSHIFT_MAX = 63
MAX_TERMS = 32
UNIT_SHIFTS = (0, 8, 16, 22)
# |product| ≤ 2^46, shifted by ≤ 15, at most 32 terms: |sum| < 2^66; one more bit of sign and
# headroom for the rounding constant.
ACC_WIDTH = 48 + PSHIFT_MAX + 5 + 1


class Op(enum.IntEnum):
    NOP  = 0
    MAC  = 1
    MIN  = 2
    MAX  = 3
    MARK = 4
    END  = 5


INSTR_FIELDS = (("op", 3), ("a", ADDR_BITS), ("b", ADDR_BITS), ("neg", 1), ("first", 1),
                ("last", 1), ("pshift", 4), ("dst", ADDR_BITS), ("oshift", 6), ("wrap", 1))
INSTR_BITS = sum(w for _, w in INSTR_FIELDS)


@dataclass(frozen=True)
class Instr:
    """One engine instruction (see the module docstring)."""

    op: Op = Op.NOP
    a: int = 0
    b: int = 0
    neg: bool = False
    first: bool = False
    last: bool = False
    pshift: int = 0
    dst: int = 0
    oshift: int = 0
    wrap: bool = False


def encode(ins: Instr) -> int:
    """Pack an instruction into an :data:`INSTR_BITS`-bit integer, fields LSB first."""
    word, pos = 0, 0
    for name, width in INSTR_FIELDS:
        value = int(getattr(ins, name))
        if not 0 <= value < (1 << width):
            raise ValueError(f"instruction field {name}={value} does not fit {width} bits")
        word |= value << pos
        pos += width
    return word


def decode(word: int) -> Instr:
    """Inverse of :func:`encode`."""
    values, pos = {}, 0
    for name, width in INSTR_FIELDS:
        values[name] = (word >> pos) & ((1 << width) - 1)
        pos += width
    values["op"] = Op(values["op"])
    for flag in ("neg", "first", "last", "wrap"):
        values[flag] = bool(values[flag])
    return Instr(**values)


def mem_depth(depth: int) -> int:
    """Register-file size the gateware builds for ``depth`` words: the next power of two
    (addresses are taken modulo it)."""
    return 1 << max(0, (depth - 1).bit_length())


@dataclass(frozen=True)
class Term:
    """``± a·b`` in a MAC statement; ``b is None`` means ``a`` times one."""

    a: str
    b: str | None = None
    neg: bool = False

    def __neg__(self) -> Term:
        return Term(self.a, self.b, not self.neg)


def T(a: str, b: str | None = None) -> Term:
    """A product term ``a·b`` (or ``a`` alone)."""
    return Term(a, b)


@dataclass(frozen=True)
class Reg:
    """A named word: address, format, role and power-on value."""

    name: str
    addr: int
    fmt: Fmt
    kind: str   # "const", "param", "state", "input", "output", "temp", "host"
    init: int = 0


@dataclass
class _Stmt:
    kind: str                  # "mac", "min", "max", "mark", "end", "entry"
    dst: str | None = None
    terms: tuple = ()
    wrap: bool = False
    label: str = ""

    def reads(self) -> set[str]:
        names = set()
        for t in self.terms:
            names.add(t.a)
            if t.b is not None:
                names.add(t.b)
        return names


@dataclass
class Microcode:
    """A compiled program.

    Attributes
    ----------
    instrs : list of Instr
        ROM contents, address order.
    entries : dict of str to int
        Start address of each entry point.
    ends : dict of str to int
        Address of the END that finishes each entry point's routine.
    regs : dict of str to Reg
    depth : int
        Register-file words used (the RTL memory is this deep).
    init : list of int
        Power-on contents of the register file (constants; everything else zero).
    statements : list
        The statements in program order (for the statement-level reference).
    """

    instrs: list[Instr]
    entries: dict[str, int]
    ends: dict[str, int]
    regs: dict[str, Reg]
    depth: int
    init: list[int]
    statements: list = field(repr=False, default_factory=list)

    @property
    def words(self) -> list[int]:
        return [encode(i) for i in self.instrs]

    def addr(self, name: str) -> int:
        return self.regs[name].addr

    def cycles(self, entry: str) -> int:
        """Cycles from the ``start`` strobe to ``done`` for ``entry`` (see the engine's timing:
        one cycle to fetch, then one instruction per cycle, then the pipeline drains)."""
        return self.ends[entry] - self.entries[entry] + 1 + LATENCY

    def mark_cycles(self, entry: str) -> int | None:
        """Cycles from the ``start`` strobe to ``mark`` for ``entry`` (the first MARK its
        routine reaches, counted as :meth:`cycles` counts to its END); None without a MARK."""
        start, end = self.entries[entry], self.ends[entry]
        for addr in range(start, end):
            if self.instrs[addr].op == Op.MARK:
                return addr - start + 1 + LATENCY
        return None


class Program:
    """Builder of an engine program: registers, statements, entry points; :meth:`compile`.

    Parameters
    ----------
    name : str
    depth : int
        Largest register-file size allowed (at most :data:`IO_BASE`).
    """

    def __init__(self, name: str, depth: int = IO_BASE):
        if not 1 <= depth <= IO_BASE:
            raise ValueError(f"depth must be 1..{IO_BASE}, not {depth!r}")
        self.name = name
        self.max_depth = depth
        self.regs: dict[str, Reg] = {}
        self._next = 0
        self._n_in = 0
        self._n_out = 0
        self.stmts: list[_Stmt] = []
        for k in UNIT_SHIFTS:
            self.reg(f"ONE{k}", Fmt(f"UNIT{k}", -k, "1"), "const", init=1 << k)

    # --- registers --------------------------------------------------------------------------
    def reg(self, name: str, fmt: Fmt, kind: str = "temp", init: int = 0) -> str:
        """Declare a word; inputs and outputs go to the I/O ports, the rest to the file."""
        if name in self.regs:
            raise ValueError(f"register {name!r} declared twice")
        if not WORD_MIN <= init <= WORD_MAX:
            raise ValueError(f"initial value of {name!r} does not fit 24 bits")
        if kind == "input":
            if self._n_in == IO_PORTS:
                raise ValueError("no input port left")
            addr = IO_BASE + self._n_in
            self._n_in += 1
        elif kind == "output":
            if self._n_out == IO_PORTS:
                raise ValueError("no output port left")
            addr = IO_BASE + self._n_out
            self._n_out += 1
        else:
            if self._next == self.max_depth:
                raise ValueError(f"program {self.name!r} needs more than {self.max_depth} words")
            addr = self._next
            self._next += 1
        self.regs[name] = Reg(name, addr, fmt, kind, init)
        return name

    def regs_of(self, kind: str) -> list[Reg]:
        return [r for r in self.regs.values() if r.kind == kind]

    @property
    def n_inputs(self) -> int:
        return self._n_in

    @property
    def n_outputs(self) -> int:
        return self._n_out

    # --- statements -------------------------------------------------------------------------
    def _check_read(self, name: str):
        if name not in self.regs:
            raise ValueError(f"unknown register {name!r}")
        if self.regs[name].kind == "output":
            raise ValueError(f"output {name!r} cannot be read")

    def _check_write(self, name: str):
        if name not in self.regs:
            raise ValueError(f"unknown register {name!r}")
        if self.regs[name].kind in ("input", "const"):
            raise ValueError(f"{self.regs[name].kind} {name!r} cannot be written")

    def mac(self, dst: str, terms, wrap: bool = False, label: str = "") -> None:
        """``dst = Σ terms`` (rounded half up onto dst's LSB, saturated or wrapped)."""
        terms = tuple(t if isinstance(t, Term) else Term(t) for t in terms)
        if not 1 <= len(terms) <= MAX_TERMS:
            raise ValueError(f"a statement has 1..{MAX_TERMS} terms, not {len(terms)}")
        for t in terms:
            self._check_read(t.a)
            if t.b is not None:
                self._check_read(t.b)
        self._check_write(dst)
        stmt = _Stmt("mac", dst, terms, wrap, label)
        self._mac_instrs(stmt)  # refuse formats the datapath cannot align, here
        self.stmts.append(stmt)

    def _minmax(self, kind: str, dst: str, a: str, b: str) -> None:
        for n in (a, b):
            self._check_read(n)
        self._check_write(dst)
        lsbs = {self.regs[n].fmt.lsb for n in (a, b, dst)}
        if len(lsbs) != 1:
            raise ValueError(f"{kind}({a}, {b}) -> {dst}: formats differ")
        self.stmts.append(_Stmt(kind, dst, (Term(a), Term(b))))

    def min(self, dst: str, a: str, b: str) -> None:
        self._minmax("min", dst, a, b)

    def max(self, dst: str, a: str, b: str) -> None:
        self._minmax("max", dst, a, b)

    def clamp(self, dst: str, src: str, lo: str, hi: str) -> None:
        """``dst = min(max(src, lo), hi)``."""
        self.max(dst, src, lo)
        self.min(dst, dst, hi)

    def mark(self) -> None:
        self.stmts.append(_Stmt("mark"))

    def end(self) -> None:
        self.stmts.append(_Stmt("end"))

    def entry(self, name: str) -> None:
        if any(s.kind == "entry" and s.label == name for s in self.stmts):
            raise ValueError(f"entry {name!r} declared twice")
        self.stmts.append(_Stmt("entry", label=name))

    # --- compilation ------------------------------------------------------------------------
    def _mac_instrs(self, s: _Stmt) -> list[tuple[Term, Instr]]:
        f_dst = self.regs[s.dst].fmt.lsb
        products = [self.regs[t.a].fmt.lsb + self.regs[t.b].fmt.lsb for t in s.terms
                    if t.b is not None]
        units = [self.regs[t.a].fmt.lsb for t in s.terms if t.b is None]
        L = min(products + [f_dst] + units)
        out = []
        for t in s.terms:
            if t.b is None:
                f = self.regs[t.a].fmt.lsb
                k = max(k for k in UNIT_SHIFTS if f - k >= L)
                b_name, lsb = f"ONE{k}", f - k
            else:
                b_name = t.b
                lsb = self.regs[t.a].fmt.lsb + self.regs[t.b].fmt.lsb
            pshift = lsb - L
            if pshift > PSHIFT_MAX:
                raise ValueError(f"{self.name}: {s.dst} = ... {t.a}·{t.b or 1}: product shift "
                                 f"{pshift} exceeds {PSHIFT_MAX}; adjust the formats")
            out.append((Term(t.a, b_name, t.neg),
                        Instr(Op.MAC, self.regs[t.a].addr, self.regs[b_name].addr, t.neg,
                              pshift=pshift)))
        oshift = f_dst - L
        if oshift > OSHIFT_MAX:
            raise ValueError(f"{self.name}: {s.dst}: output shift {oshift} too large")
        return out, oshift

    def compile(self) -> Microcode:
        """Schedule and encode the program (see the module docstring)."""
        stmts = self.stmts
        n = len(stmts)
        # Dependencies: RAW/WAR/WAW between MAC/MIN/MAX statements; barriers order everything.
        preds: list[set[int]] = [set() for _ in range(n)]
        reads = [s.reads() for s in stmts]          # each statement's reads, formed once
        last_barrier = None
        for j, s in enumerate(stmts):
            if s.kind in ("mark", "end", "entry"):
                preds[j] = set(range(last_barrier + 1 if last_barrier is not None else 0, j))
                if last_barrier is not None:
                    preds[j].add(last_barrier)
                last_barrier = j
                continue
            if last_barrier is not None:
                preds[j].add(last_barrier)
            r_j, w_j = reads[j], s.dst
            for i in range(last_barrier + 1 if last_barrier is not None else 0, j):
                d_i = stmts[i].dst
                if w_j in reads[i] or d_i == w_j or d_i in r_j:
                    preds[j].add(i)

        compiled = {j: self._mac_instrs(s) for j, s in enumerate(stmts) if s.kind == "mac"}
        avail: dict[str, int] = {}
        done = [False] * n
        instrs: list[Instr] = []
        entries: dict[str, int] = {}
        ends: dict[str, int] = {}
        current_entries: list[str] = []
        remaining = n
        while remaining:
            t = len(instrs)
            chosen = None
            for j in range(n):
                if done[j] or not all(done[p] for p in preds[j]):
                    continue
                s = stmts[j]
                if s.kind in ("mark", "end", "entry"):
                    chosen = (j, None)
                    break
                if s.kind == "mac":
                    tis, oshift = list(compiled[j][0]), compiled[j][1]
                    # Order the terms so that the latest-available operands come last.
                    tis.sort(key=lambda ti: max(avail.get(ti[0].a, 0), avail.get(ti[0].b, 0)))
                    ok = all(max(avail.get(ti[0].a, 0), avail.get(ti[0].b, 0)) <= t + k
                             for k, ti in enumerate(tis))
                    if ok:
                        chosen = (j, (tis, oshift))
                        break
                else:
                    a, b = s.terms[0].a, s.terms[1].a
                    if max(avail.get(a, 0), avail.get(b, 0)) <= t:
                        chosen = (j, None)
                        break
            if chosen is None:
                instrs.append(Instr(Op.NOP))
                continue
            j, payload = chosen
            s = stmts[j]
            done[j] = True
            remaining -= 1
            if s.kind == "entry":
                entries[s.label] = t
                current_entries.append(s.label)
            elif s.kind == "mark":
                instrs.append(Instr(Op.MARK))
            elif s.kind == "end":
                for name in current_entries:
                    ends[name] = t
                current_entries = []
                instrs.append(Instr(Op.END))
            elif s.kind == "mac":
                tis, oshift = payload
                dst = self.regs[s.dst].addr
                for k, (_term, ins) in enumerate(tis):
                    last = k == len(tis) - 1
                    instrs.append(Instr(Op.MAC, ins.a, ins.b, ins.neg, first=(k == 0), last=last,
                                        pshift=ins.pshift, dst=dst if last else 0,
                                        oshift=oshift, wrap=s.wrap and last))
                avail[s.dst] = len(instrs) - 1 + LATENCY
            else:
                op = Op.MIN if s.kind == "min" else Op.MAX
                instrs.append(Instr(op, self.regs[s.terms[0].a].addr,
                                    self.regs[s.terms[1].a].addr, first=True, last=True,
                                    dst=self.regs[s.dst].addr))
                avail[s.dst] = t + LATENCY
        if current_entries:
            raise ValueError(f"entries {current_entries} have no END")
        depth = max(1, self._next)
        init = [0] * depth
        for r in self.regs.values():
            if r.addr < IO_BASE:
                init[r.addr] = r.init
        return Microcode(instrs, entries, ends, dict(self.regs), depth, init, list(stmts))
