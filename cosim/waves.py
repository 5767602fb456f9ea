"""Waveform files besides VCD: FST (GTKWave's compressed format) and GTKWave save files.

* :func:`vcd_to_fst` — a VCD (as :class:`cosim.backends.PysimBackend` writes it) rewritten as
  FST: read with pyvcd's tokenizer, written with GTKWave's own ``fstapi`` through ``pylibfst``;
* :func:`filter_fst` — the raw FST Verilator writes natively (``--trace-fst``) cut down to
  the chosen signals below the design's top, on the 20 ns grid, like
  :func:`cosim.compiled.filter_vcd` does for VCD;
* :func:`read_fst` — value changes of an FST file (tests, scripts);
* :func:`write_gtkw` — a ``.gtkw`` save file beside a waveform that opens with the link's and
  each node's key signals grouped (``gtkwave waves.fst waves.gtkw``), naming only signals the
  waveform has.

``pylibfst`` is an optional dependency (``pip install 'mrm-cosim[fst]'``): :func:`require_fst`
refuses an FST request without it, naming the flag, before anything runs.
"""

from __future__ import annotations

import re
from pathlib import Path

from mrm_cosim.errors import InputError

__all__ = ["require_fst", "vcd_to_fst", "filter_fst", "read_fst", "write_gtkw", "key_signals"]

_RANGE = re.compile(r"\s*\[\d+(:\d+)?\]$")


def require_fst(field: str = "fst"):
    """The ``pylibfst`` module, or an :class:`InputError` naming ``field`` if not installed."""
    try:
        import pylibfst
    except ImportError:
        raise InputError(field, "FST waveforms need the optional 'fst' extra: "
                         "pip install 'mrm-cosim[fst]' (or use --vcd)") from None
    return pylibfst


def _bits(value, width: int) -> bytes:
    """A VCD value (int, or a string of 0/1/x/z) as ``width`` ASCII bits, MSB first."""
    if isinstance(value, int):
        return format(value & ((1 << width) - 1), f"0{width}b").encode()
    text = str(value).lower()
    return text.rjust(width, "x" if text[:1] == "x" else "0")[-width:].encode()


def vcd_to_fst(vcd_path, fst_path) -> list[str]:
    """Rewrite a VCD as FST (same scopes, names, widths, time stamps and timescale).

    Returns the dotted names (below the VCD's outermost scope) written.
    """
    from vcd.reader import TokenKind, tokenize

    pylibfst = require_fst()
    lib, ffi = pylibfst.lib, pylibfst.ffi
    ctx = lib.fstWriterCreate(str(fst_path).encode(), 1)
    if ctx == ffi.NULL:
        raise OSError(f"cannot write {fst_path}")
    handles: dict[str, tuple[int, int]] = {}
    names, scope = [], []
    try:
        with open(vcd_path, "rb") as f:
            for tok in tokenize(f):
                kind = tok.kind
                if kind is TokenKind.TIMESCALE:
                    ts = tok.timescale
                    exponent = {"s": 0, "ms": -3, "us": -6, "ns": -9, "ps": -12,
                                "fs": -15}[ts.unit.value]
                    exponent += {1: 0, 10: 1, 100: 2}[ts.magnitude.value]
                    lib.fstWriterSetTimescale(ctx, exponent)
                elif kind is TokenKind.SCOPE:
                    scope.append(tok.scope.ident)
                    lib.fstWriterSetScope(ctx, lib.FST_ST_VCD_MODULE,
                                          tok.scope.ident.encode(), ffi.NULL)
                elif kind is TokenKind.UPSCOPE:
                    scope.pop()
                    lib.fstWriterSetUpscope(ctx)
                elif kind is TokenKind.VAR:
                    var = tok.var
                    alias = handles.get(var.id_code, (0, 0))[0]
                    h = lib.fstWriterCreateVar(ctx, lib.FST_VT_VCD_WIRE, lib.FST_VD_IMPLICIT,
                                               var.size, var.reference.encode(), alias)
                    handles.setdefault(var.id_code, (h, var.size))
                    names.append(".".join([*scope[1:], var.reference]))
                elif kind is TokenKind.CHANGE_TIME:
                    lib.fstWriterEmitTimeChange(ctx, tok.time_change)
                elif kind in (TokenKind.CHANGE_SCALAR, TokenKind.CHANGE_VECTOR):
                    h, width = handles[tok.data.id_code]
                    lib.fstWriterEmitValueChange(ctx, h, _bits(tok.data.value, width))
    finally:
        lib.fstWriterClose(ctx)
    return names


def _fst_vars(pylibfst, fst) -> list[tuple[tuple[str, ...], str, int, int]]:
    """``(scope, name, width, handle)`` of every variable of an open FST reader, the scope
    from the hierarchy itself (names may hold dots: ``$auto$verilog_backend.cc:…``)."""
    lib, ffi = pylibfst.lib, pylibfst.ffi
    out, scope = [], []
    lib.fstReaderIterateHierRewind(fst)
    while (h := lib.fstReaderIterateHier(fst)) != ffi.NULL:
        if h.htyp == lib.FST_HT_SCOPE:
            scope.append(pylibfst.string(h.u.scope.name))
        elif h.htyp == lib.FST_HT_UPSCOPE:
            scope.pop()
        elif h.htyp == lib.FST_HT_VAR:
            out.append((tuple(scope), _RANGE.sub("", pylibfst.string(h.u.var.name)),
                        h.u.var.length, h.u.var.handle))
    return out


def read_fst(path) -> dict[str, list[tuple[int, int | str]]]:
    """``{dotted name: [(time, value), ...]}`` of an FST file; names below its outermost
    scope; values as ints (``str`` if they hold x or z); time in the file's timescale."""
    pylibfst = require_fst()
    lib = pylibfst.lib
    fst = lib.fstReaderOpen(str(path).encode())
    if fst == pylibfst.ffi.NULL:
        raise ValueError(f"{path}: not an FST file")
    try:
        by_handle: dict[int, list[str]] = {}
        for scope, name, _width, handle in _fst_vars(pylibfst, fst):
            by_handle.setdefault(handle, []).append(".".join([*scope[1:], name]))
        out = {n: [] for ns in by_handle.values() for n in ns}
        lib.fstReaderSetFacProcessMaskAll(fst)

        def change(_data, time, handle, value):
            bits = pylibfst.string(value)
            v = int(bits, 2) if set(bits) <= {"0", "1"} else bits
            for n in by_handle[handle]:
                out[n].append((time, v))

        pylibfst.fstReaderIterBlocks(fst, change)
    finally:
        lib.fstReaderClose(fst)
    return out


def filter_fst(src, dst, top: str, keep, period_ps: int = 20_000, fs: bool = False) -> list[str]:
    """Rewrite Verilator's raw FST of a trace window for users, as ``filter_vcd`` does VCD.

    Keeps the variables inside the first scope named ``top`` whose dotted name relative to it
    satisfies ``keep(name)`` (not the ``$`` temporaries of the Verilog backend, nor the top's
    ``clk``/``rst``, nor a node domain's), under one ``top`` scope; time stamps (cycle
    numbers) become picoseconds, ``period_ps`` per cycle, or with ``fs`` stay (femtoseconds:
    a per-node-clock model's edge times). Returns the dotted names kept.
    """
    from mrm_cosim.cosim.compiled import _TOP_CLOCK_RE

    pylibfst = require_fst()
    lib, ffi = pylibfst.lib, pylibfst.ffi
    fst = lib.fstReaderOpen(str(src).encode())
    if fst == ffi.NULL:
        raise ValueError(f"{src}: not an FST file")
    kept: list[tuple[tuple[str, ...], str, int, int]] = []      # (scope, name, width, handle)
    try:
        found = [(scope[scope.index(top) + 1:], name, width, handle)
                 for scope, name, width, handle in _fst_vars(pylibfst, fst) if top in scope]
        # the top's clk and rst (and their aliases below): one sample per cycle says nothing
        clocks = {handle for rel, name, _, handle in found
                  if not rel and _TOP_CLOCK_RE.match(name)}
        kept = [(rel, name, width, handle) for rel, name, width, handle in found
                if handle not in clocks and not name.startswith("$")
                and keep(".".join([*rel, name]))]
        kept.sort(key=lambda k: k[0])
        changes: list[tuple[int, int, bytes]] = []
        for *_, handle in kept:
            lib.fstReaderSetFacProcessMask(fst, handle)

        def change(_data, time, handle, value):
            changes.append((time, handle, ffi.string(value)))

        pylibfst.fstReaderIterBlocks(fst, change)
    finally:
        lib.fstReaderClose(fst)
    changes.sort(key=lambda c: c[0])
    ctx = lib.fstWriterCreate(str(dst).encode(), 1)
    if ctx == ffi.NULL:
        raise OSError(f"cannot write {dst}")
    try:
        lib.fstWriterSetTimescale(ctx, -15 if fs else -12)
        if fs:
            period_ps = 1
        lib.fstWriterSetScope(ctx, lib.FST_ST_VCD_MODULE, top.encode(), ffi.NULL)
        cur: tuple[str, ...] = ()
        out_handle: dict[int, int] = {}
        for rel, name, width, handle in kept:
            common = 0
            while common < min(len(cur), len(rel)) and cur[common] == rel[common]:
                common += 1
            for _ in cur[common:]:
                lib.fstWriterSetUpscope(ctx)
            for s in rel[common:]:
                lib.fstWriterSetScope(ctx, lib.FST_ST_VCD_MODULE, s.encode(), ffi.NULL)
            cur = rel
            alias = out_handle.get(handle, 0)
            h = lib.fstWriterCreateVar(ctx, lib.FST_VT_VCD_WIRE, lib.FST_VD_IMPLICIT, width,
                                       name.encode(), alias)
            out_handle.setdefault(handle, h)
        for _ in cur:
            lib.fstWriterSetUpscope(ctx)
        lib.fstWriterSetUpscope(ctx)
        last = None
        for time, handle, value in changes:
            if time != last:
                lib.fstWriterEmitTimeChange(ctx, time * period_ps)
                last = time
            lib.fstWriterEmitValueChange(ctx, out_handle[handle], value)
    finally:
        lib.fstWriterClose(ctx)
    return [".".join([*rel, name]) for rel, name, _, _ in kept]


#: Per node k, the key signals of a waveform and where each may be found (the first name the
#: waveform has wins): link state and Run, the D/S lines towards the master, the time-code
#: the node took, its observation-port events, torque, encoder count and status.
_NODE_KEYS = (
    ("link state", ("node{k}.link.up_codec.state", "node{k}.link.up_codec.fsm.state")),
    ("link running", ("node{k}.link.up_codec.running", "node{k}.link.running")),
    ("D in", ("node{k}.link.up_codec.d_in", "node{k}.link.d_in")),
    ("S in", ("node{k}.link.up_codec.s_in", "node{k}.link.s_in")),
    ("D out", ("node{k}.link.up_codec.d_out", "node{k}.link.d_out")),
    ("S out", ("node{k}.link.up_codec.s_out", "node{k}.link.s_out")),
    ("time-code", ("node{k}.link.tc_strobe",)),
    ("time", ("node{k}.link.tc_time",)),
    ("events", ("events{k}", "node{k}.events", "node{k}.core.events")),
    ("torque", ("torque{k}", "node{k}.torque", "node{k}.core.torque")),
    ("count", ("count{k}", "node{k}.count", "node{k}.core.count")),
    ("status", ("status{k}", "node{k}.status", "node{k}.core.status")),
)
_MASTER_KEYS = (
    ("link state", ("master.codec.state", "master.codec.fsm.state")),
    ("link running", ("master.codec.running",)),
    ("D out", ("master.codec.d_out",)),
    ("S out", ("master.codec.s_out",)),
    ("D in", ("master.codec.d_in",)),
    ("S in", ("master.codec.s_in",)),
    ("time-code", ("master.codec.tick_in",)),
    ("time", ("master.codec.time_in",)),
)
_SIGNED = {"torque"}


def key_signals(names) -> list[tuple[str, list[tuple[str, str]]]]:
    """``[(group, [(alias, dotted name), ...]), ...]``: the master port's and each node's key
    signals among ``names`` (groups with none are left out)."""
    have = set(names)
    groups = []
    nodes = sorted({int(m.group(1)) for n in have
                    if (m := re.match(r"(?:node|torque|events|count|status)(\d+)\b", n))})
    for title, keys, k in [("master port", _MASTER_KEYS, 0),
                           *((f"node{k}", _NODE_KEYS, k) for k in nodes)]:
        traces = []
        for alias, candidates in keys:
            found = next((c.format(k=k) for c in candidates if c.format(k=k) in have), None)
            if found is not None:
                traces.append((alias, found))
        if traces:
            groups.append((title, traces))
    return groups


def write_gtkw(wave_path, names, top: str = "system") -> Path:
    """Write ``<wave>.gtkw`` beside ``wave_path``: a GTKWave save file that opens the waveform
    with :func:`key_signals` grouped per node (``gtkwave waves.fst waves.gtkw``).

    ``names`` are the dotted names the waveform holds below ``top``; only those are named.
    Returns the save file's path.
    """
    from vcd.gtkw import GTKWSave

    wave_path = Path(wave_path)
    path = wave_path.with_suffix(".gtkw")
    with open(path, "w") as f:
        save = GTKWSave(f)
        save.comment(f"GTKWave save file written by mrm-cosim for {wave_path.name}: "
                     f"gtkwave {wave_path.name} {path.name}")
        save.dumpfile(wave_path.name, abspath=False)     # beside it, wherever it moves
        save.savefile(path.name, abspath=False)
        save.treeopen(top)
        for title, traces in key_signals(names):
            with save.group(title, closed=False):
                for alias, name in traces:
                    fmt = "signed" if alias in _SIGNED else "hex"
                    save.trace(f"{top}.{name}", alias=alias, datafmt=fmt)
    return path
