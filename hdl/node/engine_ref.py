"""Bit-exact Python references of the multiply-accumulate engine, at two levels.

* :class:`EngineModel` executes the compiled microcode one instruction after the other (no
  pipeline). The gateware (:class:`~hdl.node.engine.MacEngine`) must leave the register file
  and output registers exactly as this does, for any program the scheduler produced.
* :func:`run_statements` executes the *statements* of a program in program order with their
  mathematical meaning (exact sum of products, one rounding onto the destination's LSB). It
  checks the compiler: shifts, unit constants and the schedule must not change any result.
"""

from __future__ import annotations

from mrm_cosim.protocol.fixed import WORD, round_shift, saturate, wrap
from mrm_cosim.protocol.isa import IO_BASE, IO_PORTS, Microcode, Op, mem_depth

__all__ = ["EngineModel", "run_statements"]


def _word(v: int) -> int:
    return wrap(v, WORD)


class EngineModel:
    """Instruction-level model of one engine.

    Parameters
    ----------
    microcode : Microcode
    mem : list of int, optional
        Register-file contents (default: the microcode's power-on values).

    Attributes
    ----------
    mem : list of int
        Register file (:func:`mem_depth` words; addresses are taken modulo its size).
    outputs : list of int
        Output registers, :data:`~mrm_cosim.protocol.isa.IO_PORTS` words.
    """

    def __init__(self, microcode: Microcode, mem=None):
        self.mc = microcode
        size = mem_depth(microcode.depth)
        self.mem = [0] * size
        src = microcode.init if mem is None else mem
        for i, v in enumerate(src[:size]):
            self.mem[i] = _word(v)
        self.outputs = [0] * IO_PORTS

    def _read(self, addr: int, inputs) -> int:
        if addr >= IO_BASE:
            k = addr - IO_BASE
            return _word(inputs[k]) if k < len(inputs) else 0
        return self.mem[addr % len(self.mem)]

    def _write(self, addr: int, value: int) -> None:
        if addr >= IO_BASE:
            self.outputs[addr - IO_BASE] = value
        else:
            self.mem[addr % len(self.mem)] = value

    def write(self, addr: int, value: int) -> None:
        """Host write (the engine must be idle)."""
        self._write(addr, _word(value))

    def read(self, addr: int) -> int:
        """Host read of the register file."""
        return self.mem[addr % len(self.mem)]

    def run(self, entry: str, inputs=()) -> list[int]:
        """Run from ``entry`` to END with input ports ``inputs`` (held constant).

        Returns
        -------
        list of int
            ROM addresses of the MARK instructions met, in order.
        """
        pc = self.mc.entries[entry]
        acc = 0
        marks = []
        while True:
            ins = self.mc.instrs[pc]
            if ins.op == Op.END:
                return marks
            if ins.op == Op.MARK:
                marks.append(pc)
            elif ins.op == Op.MAC:
                prod = self._read(ins.a, inputs) * self._read(ins.b, inputs)
                term = (-prod if ins.neg else prod) << ins.pshift
                acc = term if ins.first else acc + term
                if ins.last:
                    v = round_shift(acc, ins.oshift)
                    self._write(ins.dst, _word(v) if ins.wrap else saturate(v))
            elif ins.op in (Op.MIN, Op.MAX):
                a, b = self._read(ins.a, inputs), self._read(ins.b, inputs)
                self._write(ins.dst, min(a, b) if ins.op == Op.MIN else max(a, b))
                acc = 0
            pc += 1


def run_statements(mc: Microcode, entry: str, values: dict[str, int],
                   inputs: dict[str, int] | None = None) -> dict[str, int]:
    """Execute the statements of ``entry`` (program order) on named values.

    Parameters
    ----------
    mc : Microcode
    entry : str
    values : dict of str to int
        Words of the register file by name (missing ones are zero); updated in place.
    inputs : dict of str to int, optional
        Input-port words by name.

    Returns
    -------
    dict of str to int
        ``values`` after the run, outputs included.
    """
    inputs = inputs or {}
    regs = mc.regs

    def get(name):
        if regs[name].kind == "const":
            return regs[name].init
        if regs[name].kind == "input":
            return _word(inputs.get(name, 0))
        return values.get(name, 0)

    started = False
    for s in mc.statements:
        if s.kind == "entry":
            started = started or s.label == entry
            continue
        if not started:
            continue
        if s.kind == "end":
            break
        if s.kind == "mark":
            continue
        if s.kind in ("min", "max"):
            a, b = get(s.terms[0].a), get(s.terms[1].a)
            values[s.dst] = min(a, b) if s.kind == "min" else max(a, b)
            continue
        f_dst = regs[s.dst].fmt.lsb
        parts = []
        for t in s.terms:
            if t.b is None:
                v, lsb = get(t.a), regs[t.a].fmt.lsb
            else:
                v, lsb = get(t.a) * get(t.b), regs[t.a].fmt.lsb + regs[t.b].fmt.lsb
            parts.append((-v if t.neg else v, lsb))
        L = min([lsb for _, lsb in parts] + [f_dst])
        total = sum(v << (lsb - L) for v, lsb in parts)
        r = round_shift(total, f_dst - L)
        values[s.dst] = _word(r) if s.wrap else saturate(r)
    else:
        if not started:
            raise KeyError(f"no entry {entry!r}")
    return values
