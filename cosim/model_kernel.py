"""The ``model`` backend's compiled inner loop: what runs it, and the nodes and encoders on it.

The plain part of a plant step — every node's encoder taking the plant's count changes, and for
every node with no event in the piece (no packet or time-code reaching it, no boundary, commit
or pre-arm cycle, :meth:`FastNode.next_special <cosim.model_node.FastNode.next_special>`) its
control ticks and the torque word the plant samples — is one call of
:func:`cosim.model_kernel_src.plain_step`, compiled with numba and cached under
``$MRM_CACHE_DIR/numba/<digest>``, the digest of every source the compiled code reads
(:func:`kernel_sources`: numba freezes their constants into it). The functions
there are translations of the references, line by line; the references stay the readable
source of truth and the pure-Python path (``ModelBackend(kernel="python")``), and the tests run
both and require the same trace hashes.

* :class:`KernelEncoder` — :class:`~cosim.model_node.EncoderEvents`' interface on the kernel's
  arrays (one row of the backend's). Its state lives there only, so the nodes' Python event
  loop and the kernel share it without copies.
* :class:`KernelNode` — :class:`~cosim.model_node.FastNode` whose plain steps run in the kernel.
  Between two plain steps its tick state stays in the kernel's row; before the Python event
  loop takes the node (a packet, a time-code, a boundary, a commit) the row is copied back
  into the object (:meth:`KernelNode.pull`), and the other way round (:meth:`KernelNode.push`)
  before the next plain step. The event loop itself is the reference's, unchanged.

Selection: :func:`load` returns the compiled functions, or None with a one-line
:class:`RuntimeWarning` when numba is missing or fails (the pure-Python path then runs);
``MRM_MODEL_KERNEL=python`` selects the pure-Python path.
"""

from __future__ import annotations

import os
import warnings
from functools import cache
from pathlib import Path

import numpy as np

from mrm_cosim.cosim.model_node import _BRAKE, _CYCLES_MAX, _STOP, FastNode
from mrm_cosim.errors import InputError
from mrm_cosim.hdl.node.core_ref import NodeModel
from mrm_cosim.hdl.node.trig_ref import sin_cos
from mrm_cosim.protocol.cordic import bam_constant
from mrm_cosim.hdl.node.vdc_ref import VdcModel
from mrm_cosim.cosim import model_kernel_src as src
from mrm_cosim.models import compliant_kernel_src as compliant_src
from mrm_cosim.models import plant_kernel_src as plant_src
from mrm_cosim.protocol.fixed import CNT, FORCE, IHI, POS, SGN, TIME, VEL
from mrm_cosim.protocol.fixed import ACC, ANG, CT, IM, IVLC, IVS, KC, LAM, LAMC, TS, VISC, GAIN
from mrm_cosim.protocol.joint_program import MODES, joint_microcode, pid_formats
from mrm_cosim.protocol.packet import PacketType
from mrm_cosim.protocol.regs import Config, NodeEvent

__all__ = ["load", "load_plant", "kernel_choice", "kernel_sources", "kernel_digest",
           "KernelEncoder", "KernelNode", "KernelArrays", "KernelVdc", "point_shifts",
           "param_row"]

#: Buffer sizes per node (:mod:`cosim.model_kernel_src`, which lays them out in one blob).
PEND_CAP, VIS_CAP, PIPE_CAP, DUE_CAP = src.PEND_CAP, src.VIS_CAP, src.PIPE_CAP, src.DUE_CAP
CHANGE_CAP = src.CHANGE_CAP

_loaded = None          # the compiled module, False if it cannot be, None before trying


def kernel_choice(kernel: str | None = None) -> str:
    """``"numba"`` or ``"python"``: ``kernel``, else ``$MRM_MODEL_KERNEL``, else numba."""
    choice = kernel or os.environ.get("MRM_MODEL_KERNEL") or "numba"
    if choice not in ("numba", "python"):
        raise ValueError(f"model kernel must be 'numba' or 'python', not {choice!r}")
    return choice


def jit_module(module, njit) -> None:
    """Replace every function defined in ``module`` (and those it names in ``CALLS``, from
    other modules) by ``njit(function)`` in that module: they call each other through its
    globals, so all of them compile. The originals elsewhere stay Python."""
    import types

    names = set(getattr(module, "CALLS", ()))
    for name, obj in list(vars(module).items()):
        if name == "borrow" and obj is getattr(src, "borrow", None):
            setattr(module, name, borrowed())
        elif name == "pin_call" and obj is getattr(src, "pin_call", None):
            setattr(module, name, pin_called())
        elif isinstance(obj, types.FunctionType) and (obj.__module__ == module.__name__
                                                      or name in names):
            setattr(module, name, njit(obj))


@cache
def borrowed():
    """:func:`cosim.model_kernel_src.borrow` compiled: a numba intrinsic giving the array with
    a null meminfo, so that numba's reference counting of it and of its views (``NRT_incref``,
    ``NRT_decref``: a locked instruction each, where the pointer is not null) does nothing.
    The data, shape and strides are the array's; the caller keeps the array alive (an entry
    point's argument, held by Python for the call). 24 % of the ``model`` backend's CPU time
    on ``mrm3`` went to those two instructions before (perf, 26 Nov 2026). (This file is
    among :func:`kernel_sources`: a change here makes numba compile its callers afresh.)"""
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    @intrinsic
    def borrow(typingctx, a):
        if not isinstance(a, types.Array):
            return None

        def codegen(context, builder, sig, args):
            ary = context.make_array(sig.args[0])(context, builder, value=args[0])
            ary.meminfo = cgutils.get_null_value(ary.meminfo.type)
            return ary._getvalue()

        return a(a), codegen

    return borrow


@cache
def pin_called():
    """:func:`cosim.model_kernel_src.pin_call` compiled: a numba intrinsic calling
    ``mrm_pin`` (:mod:`cosim.pin_shim`) through the address the kernel is given, with the
    arrays' data pointers. The address comes in as an argument, never as a constant, so the
    compiled code stays cacheable and the same for every process."""
    from llvmlite import ir
    from numba.core import types
    from numba.extending import intrinsic

    @intrinsic
    def pin_call(typingctx, fn, model, which, q, v, tau, out):
        if not all(isinstance(t, types.Integer) for t in (fn, model, which)) or not all(
                isinstance(t, types.Array) and t.dtype == types.float64 and t.ndim == 1
                for t in (q, v, tau, out)):
            return None

        def codegen(context, builder, sig, args):
            dp = ir.DoubleType().as_pointer()
            i8p = ir.IntType(8).as_pointer()
            i64 = ir.IntType(64)
            fnty = ir.FunctionType(ir.VoidType(), [i8p, i64, dp, dp, dp, dp])
            ptrs = [context.make_array(t)(context, builder, value=a).data
                    for t, a in zip(sig.args[3:], args[3:], strict=True)]
            f = builder.inttoptr(context.cast(builder, args[0], sig.args[0], types.int64),
                                 fnty.as_pointer())
            m = builder.inttoptr(context.cast(builder, args[1], sig.args[1], types.int64), i8p)
            w = context.cast(builder, args[2], sig.args[2], types.int64)
            builder.call(f, [m, w, *ptrs])
            return context.get_dummy_value()

        return types.void(fn, model, which, q, v, tau, out), codegen

    return pin_call


def kernel_sources() -> list[Path]:
    """Every source file the compiled kernel depends on: the three kernel modules, this one
    (:func:`borrowed`), and every ``mrm_cosim`` module they import, transitively. numba
    freezes the globals a compiled function reads (``protocol.fixed``'s formats, the encoder's
    tables, :mod:`models.gear`'s functions called from the compliant plant) into its machine
    code, and its own cache is keyed on the defining file alone: a change to one of the
    others would otherwise run the stale code, silently."""
    import ast
    import importlib.util

    todo = [Path(m.__file__).resolve() for m in (src, plant_src, compliant_src)]
    todo.append(Path(__file__).resolve())
    seen: set[Path] = set()
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            for name in names:
                if name != "mrm_cosim" and not name.startswith("mrm_cosim."):
                    continue
                try:                        # a module, or a name imported from one: skip
                    spec = importlib.util.find_spec(name)
                except ModuleNotFoundError:
                    spec = None
                if spec is not None and spec.origin and spec.origin.endswith(".py"):
                    todo.append(Path(spec.origin).resolve())
    return sorted(seen)


def kernel_digest(paths=None) -> str:
    """A digest of ``paths`` (default :func:`kernel_sources`: their file names and contents)
    and of numba's and Python's versions: the name of the directory the compiled kernel is
    cached in."""
    import hashlib
    import sys

    import numba

    h = hashlib.sha256(f"{numba.__version__} {sys.version_info[:3]}".encode())
    for path in sorted(kernel_sources() if paths is None else paths):
        h.update(f"\0{path.name}\0".encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def load():
    """The compiled kernel module (:mod:`cosim.model_kernel_src` with its functions jitted),
    or None, after one warning, if numba is missing or cannot compile it here."""
    global _loaded
    if _loaded is None:
        try:
            import numba

            from mrm_cosim.cosim.cache import mark_used
            from mrm_cosim.cosim.compiled import cache_dir

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")             # numba's own notices
                # numba's cache in a directory named by the digest of every source the
                # kernel reads (kernel_sources): a changed constant or callee recompiles
                saved = numba.config.CACHE_DIR
                numba.config.CACHE_DIR = str(cache_dir() / "numba" / kernel_digest())
                mark_used(Path(numba.config.CACHE_DIR))
                try:
                    for module in (src, plant_src, compliant_src):
                        jit_module(module, numba.njit(cache=True))
                finally:
                    numba.config.CACHE_DIR = saved
                _warm_up(src)
                _warm_up_plant(plant_src)
                _warm_up_compliant(compliant_src)
            _loaded = src
        except Exception as e:          # noqa: BLE001 — any failure: the Python path runs
            _loaded = False
            warnings.warn(f"model backend: compiled inner loop unavailable "
                          f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}); "
                          "running the pure-Python path", RuntimeWarning, stacklevel=2)
    return _loaded or None


def load_plant():
    """The plant step's compiled functions (:mod:`models.plant_kernel_src`, for
    :meth:`Plant.use_kernel <models.plant.Plant.use_kernel>`), or None where :func:`load`
    gives None."""
    return plant_src if load() is not None else None


def _warm_up_plant(k) -> None:
    """Compile (or load) the plant step's functions once, on a throw-away state."""
    S = np.zeros((k.S_ROWS, 2))
    C = np.ones((k.C_ROWS, 2))
    k.pre(S, C, np.zeros(2), 5e-6)
    k.pre_free(S, C, np.zeros(2), 5e-6, 1.0)
    k.free_force(S, 1.0)
    k.free_end(S, np.zeros(2), 1e-5, True)
    k.stuck(S, np.zeros(2))
    S[k.SIGN, 0] = 1.0
    k.likely_pattern(S, np.eye(2), 1e-5)
    k.finish(S, 1e-5, 5e-6)


def _warm_up_compliant(k) -> None:
    """Compile (or load) the compliant plant step's functions (:mod:`models.compliant_kernel_src`,
    which :meth:`CompliantPlant.use_kernel <models.compliant.CompliantPlant.use_kernel>` runs)."""
    S = np.zeros((k.S_ROWS, 2))
    C = np.ones((k.C_ROWS, 2))
    k.pre(S, C, np.zeros(2), np.zeros(2), 1e-5, 5e-6, True)
    k.finish(S, np.zeros(2), 1e-5, 5e-6)


def _throw_away() -> KernelArrays:
    """One node's arrays in a state the kernel can run (for the warm-up)."""
    a = KernelArrays(1)
    a.IB[src.H_CYCLES] = 500
    a.E[0, src.E_KNOWN] = -1
    a.E[0, src.E_MINWIN] = a.E[0, src.E_STOP] = 10
    a.E[0, src.E_KV] = 100
    a.E[0, src.E_FILTER] = 2
    a.E[0, src.E_DUE_GAP] = src.NEVER
    a.E[0, src.E_LAST_C] = a.E[0, src.E_TAKEN] = -1
    a.N[0, src.N_TICK] = 50
    a.P[0, src.P_CYC:src.P_CYC + 3] = 40
    return a


def _warm_up(k) -> None:
    """Compile (or load from numba's cache) every entry point once, on throw-away arrays."""
    b = _throw_away()
    F = np.zeros(src.f_size(1))
    F[src.F_H], F[src.F_HH] = 1e-5, 5e-6
    k.fast_step(b.IB, F, np.zeros((plant_src.S_ROWS, 1)), np.zeros(1), np.ones((1, 1)),
                np.zeros((2, 1, 1)), 0, 0, 1, np.ones((plant_src.C_ROWS, 1)), 1, np.zeros(5))
    b = _throw_away()
    k.fast_step_compliant(b.IB, F, np.zeros((compliant_src.S_ROWS, 1)), np.zeros(1),
                          np.zeros((2, 1, 1)), 0, 0, np.ones((compliant_src.C_ROWS, 1)),
                          np.zeros((2, 1)), 1)
    z6, z13 = np.zeros(6, dtype=np.int64), np.zeros(13, dtype=np.int64)
    k.vdc_link(z13, z6, z13, z13, z13, z6, z6, z6, np.zeros(3, dtype=np.int64), z6,
               z13.copy())
    k.vdc_link_packed(np.zeros(79, dtype=np.int64), np.zeros(19, dtype=np.int64))
    k.vdc_step(np.zeros(src.VX_SIZE, dtype=np.int64), np.zeros(src.VO_SIZE, dtype=np.int64))
    a = _throw_away()
    z = np.zeros(0, dtype=np.int64)
    tau = np.zeros(1)
    k.step_changes(np.array([[0.0], [1.0], [-5e4], [1e-5]]), np.array([1.27e5]), 1e-5, 500,
                   a.CHC, a.CHN, a.NCH)
    a.CUR[:] = 0
    k.plain_step(a.N, a.P, a.E, a.VIS, a.PIPE, a.DUE, a.PEND, np.ones(1, dtype=np.int64), 0,
                 500, 0, a.CHC, a.CHN, a.NCH, a.CUR, tau)
    e = a.rows(0)
    k.enc_tick_sample(e[0], e[2], e[3], e[4], 600)
    k.enc_defer(e[0], e[2], e[4], 650)
    k.enc_defer_range(e[0], e[4], 700, 800, 50)
    k.enc_count_at(e[0], e[2], 800)
    k.enc_preset(e[0], e[2], e[3], e[4], 900, 0)
    k.enc_feed_changes(e[0], e[1], e[2], 500, 500, z, z)
    k.materialize(a.N[0], a.P[0])
    k.any_trip(a.N, 0)
    k.sin_cos(-5, 1 << 20)


def point_shifts(fmt, *lsbs) -> tuple[int, ...]:
    """The 6 slots of one rounding point ``fx_point(fmt, *lsbs)``: each summand's left shift
    onto the finest LSB (0 for unused slots), then the rounding shift."""
    low = min(*lsbs, fmt.lsb)
    shifts = [lsb - low for lsb in lsbs] + [0] * (5 - len(lsbs))
    return (*shifts, fmt.lsb - low)


@cache
def _points(pid_shift: int) -> tuple[int, ...]:
    """The rounding points of hdl/node/joint_ref.py, in :data:`src.POINTS` order, their 6
    slots each one after the other."""
    f = pid_formats(pid_shift)
    return sum([
        point_shifts(POS, POS.lsb, CNT.lsb),                                        # E
        point_shifts(VEL, VEL.lsb, LAMC.lsb + POS.lsb),                             # QDR
        point_shifts(ACC, ACC.lsb, LAM.lsb + VEL.lsb),                              # QDDR
        point_shifts(SGN, IVS.lsb + VEL.lsb, IVLC.lsb + POS.lsb),                   # SG
        point_shifts(FORCE, FORCE.lsb, IM.lsb + ACC.lsb, VISC.lsb + VEL.lsb,
                     FORCE.lsb + SGN.lsb, GAIN.lsb + VEL.lsb),                      # TAU_VDC
        point_shifts(FORCE, FORCE.lsb, f["kp"].lsb + POS.lsb, f["ki"].lsb + POS.lsb,
                     f["ki"].lsb + IHI.lsb, f["kd"].lsb + VEL.lsb),                 # TAU_PID
        point_shifts(IHI, POS.lsb, POS.lsb, CNT.lsb),                               # I_CARRY
        point_shifts(POS, POS.lsb, POS.lsb, CNT.lsb, IHI.lsb),                      # I_LO
        point_shifts(IHI, IHI.lsb, IHI.lsb),                                        # I_HI
        point_shifts(FORCE, FORCE.lsb),                                             # TAU_D
        point_shifts(TS, TIME.lsb + CT.lsb),                                        # TS
        point_shifts(VEL, VEL.lsb, ACC.lsb + TS.lsb),                               # VD
        point_shifts(ANG, VEL.lsb + TS.lsb),                                        # DQ
        point_shifts(POS, POS.lsb, ANG.lsb + KC.lsb),                               # QD
    ], ())


def param_row(params, out: np.ndarray | None = None) -> np.ndarray:
    """The kernel's parameter row of :class:`~protocol.joint_program.JointParams` ``params``."""
    row = np.zeros(src.P_SIZE, dtype=np.int64) if out is None else out
    for i, name in enumerate(src.PARAM_WORDS):
        row[i] = getattr(params, name)
    mc = joint_microcode(params.pid_shift)
    row[src.P_CYC:src.P_CYC + 3] = [mc.cycles(m) for m in MODES]
    row[src.P_SH:] = _points(params.pid_shift)
    return row


class KernelArrays:
    """The kernel's state for ``n`` nodes: node rows ``N``, parameter rows ``P``, encoder rows
    ``E`` and the encoders' queues."""

    def __init__(self, n: int):
        shapes = ((n, src.N_SIZE), (n, src.P_SIZE), (n, src.E_SIZE), (n, 2, PEND_CAP, 2),
                  (n, VIS_CAP, 2), (n, PIPE_CAP, 4), (n, DUE_CAP), (n, CHANGE_CAP),
                  (n, CHANGE_CAP), (n,), (n,), (src.SCRATCH,))
        sizes = [int(np.prod(sh)) for sh in shapes]
        #: every array below is a view of this one (:func:`cosim.model_kernel_src.blob_views`),
        #: so the fast path passes one argument for all of them
        self.IB = np.zeros(src.H_SIZE + sum(sizes), dtype=np.int64)
        self.IB[src.H_N] = n
        views, o = [], src.H_SIZE
        for sh, size in zip(shapes, sizes, strict=True):
            views.append(self.IB[o:o + size].reshape(sh))
            o += size
        (self.N, self.P, self.E, self.PEND, self.VIS, self.PIPE, self.DUE,
         # the count changes of the current plant step (step_changes) and the next one to feed
         self.CHC, self.CHN, self.NCH, self.CUR,
         self.SCR) = views             # (SCR: the fast path's scratch, _step_changes)
        self.N[:, src.N_COMMIT_C] = src.NEVER   # no commit armed

    def rows(self, k: int) -> tuple:
        """Node ``k``'s encoder views ``(E, PEND, VIS, PIPE, DUE)``."""
        return self.E[k], self.PEND[k], self.VIS[k], self.PIPE[k], self.DUE[k]


class KernelEncoder:
    """:class:`~cosim.model_node.EncoderEvents` on row ``k`` of :class:`KernelArrays` (same
    methods, same results; tests/test_model_kernel.py)."""

    def __init__(self, kern, arrays: KernelArrays, k: int, params, count0: int):
        self._k = kern
        self.p = params
        E, self._pend, self._vis, self._pipe, self._due = arrays.rows(k)
        self._E = E
        count0 = int(count0)
        a, b = (((count0 & 3) >> 1) ^ (count0 & 1)), (count0 & 3) >> 1
        E[:] = 0
        E[src.E_RAW] = count0
        E[src.E_KNOWN] = -1
        E[src.E_FILT0], E[src.E_FILT1] = a, b
        E[src.E_PAIR0], E[src.E_PAIR1] = a, b
        E[src.E_MOVED_C] = -1
        E[src.E_TAKEN] = -2
        E[src.E_LAST_C] = -1
        E[src.E_MINWIN] = params.min_window
        E[src.E_STOP] = params.stop_cycles
        E[src.E_DUE_GAP] = src.NEVER
        E[src.E_KV] = params.kv
        E[src.E_FILTER] = params.filter_cycles

    @property
    def count(self) -> int:
        return int(self._E[src.E_COUNT])

    @property
    def velocity(self) -> int:
        return int(self._E[src.E_VEL])

    @property
    def errors(self) -> int:
        return int(self._E[src.E_ERRORS])

    def feed(self, start: int, counts) -> None:
        """:meth:`EncoderEvents.feed`."""
        counts = np.asarray(counts, dtype=np.int64)
        prev = np.empty_like(counts)
        prev[0] = self._E[src.E_RAW]
        prev[1:] = counts[:-1]
        idx = np.flatnonzero(counts != prev)
        self.feed_arrays(start, len(counts), idx.astype(np.int64), counts[idx])

    def feed_changes(self, start: int, n: int, changes) -> None:
        """:meth:`EncoderEvents.feed_changes`."""
        if changes:
            arr = np.array(changes, dtype=np.int64)
            self.feed_arrays(start, n, arr[:, 0].copy(), arr[:, 1].copy())
        else:
            z = np.zeros(0, dtype=np.int64)
            self.feed_arrays(start, n, z, z)

    def feed_arrays(self, start: int, n: int, cycles, counts) -> None:
        known = int(self._E[src.E_KNOWN])
        if start != known + 1:
            raise ValueError(f"feed must continue at cycle {known + 1}, not {start}")
        self._k.enc_feed_changes(self._E, self._pend, self._vis, start, n, cycles, counts)

    def sample(self, c: int) -> tuple[int, int, int]:
        """:meth:`EncoderEvents.sample`."""
        E = self._E
        self._k.enc_tick_sample(E, self._vis, self._pipe, self._due, c)
        return int(E[src.E_LAST_COUNT]), int(E[src.E_LAST_VEL]), int(E[src.E_ERR_LAST])

    def tick_sample(self, c: int) -> tuple[int, int]:
        """:meth:`EncoderEvents.tick_sample`."""
        E = self._E
        self._k.enc_tick_sample(E, self._vis, self._pipe, self._due, c)
        return int(E[src.E_LAST_COUNT]), int(E[src.E_LAST_VEL])

    def defer(self, c: int) -> int:
        """:meth:`EncoderEvents.defer`."""
        return int(self._k.enc_defer(self._E, self._vis, self._due, c))

    def defer_range(self, first: int, last: int, step: int) -> None:
        """:meth:`EncoderEvents.defer_range`."""
        self._k.enc_defer_range(self._E, self._due, first, last, step)

    def count_at(self, c: int) -> int:
        """:meth:`EncoderEvents.count_at`."""
        return int(self._k.enc_count_at(self._E, self._vis, c))

    def preset(self, c: int, value: int) -> None:
        """:meth:`EncoderEvents.preset`."""
        value = ((int(value) + 2**31) % 2**32) - 2**31
        self._k.enc_preset(self._E, self._vis, self._pipe, self._due, c, value)


class KernelVdc(VdcModel):
    """:class:`~hdl.node.vdc_ref.VdcModel` whose step runs compiled
    (:func:`cosim.model_kernel_src.vdc_step`, the step around both links, and
    :func:`~cosim.model_kernel_src.vdc_link`, each link; same words bit for bit;
    tests/test_model_kernel.py). :meth:`adopt` turns a node's model into one."""

    def step(self, x):
        """:meth:`VdcModel.step <hdl.node.vdc_ref.VdcModel.step>` in one compiled call."""
        p = self.params
        th = self.theta
        X = np.array([*th[0], *th[1], *p.K[0], *p.K[1], *p.rho_T[0], *p.rho_T[1],
                      *p.lower[0], *p.lower[1], *p.upper[0], *p.upper[1], p.inv_T,
                      *self.prev_C, self.prev_qd_r, self.primed, x.qd_r, *x.V_C, *x.V_rC,
                      x.qd, x.cos_q, x.sin_q, *x.g_C], dtype=np.int64)
        if X.shape[0] != src.VX_SIZE:           # not the unit's shapes: the reference says how
            return VdcModel.step(self, x)
        out = np.empty(src.VO_SIZE, dtype=np.int64)
        src.vdc_step(X, out)
        w = out.tolist()
        self.theta = [w[src.VO_TH:src.VO_TH + 13], w[src.VO_TH + 13:src.VO_TH + 26]]
        self.prev_C = list(x.V_rC)
        self.prev_qd_r = x.qd_r
        self.primed = True
        return w[src.VO_F:src.VO_F + 6], w[src.VO_F + 6:src.VO_F + 12]

    @classmethod
    def adopt(cls, vdc: VdcModel) -> None:
        """Make ``vdc`` (a node's :class:`VdcModel`, state kept) run its links compiled."""
        vdc.__class__ = cls

    def _link(self, i, V, V_r, dV, g):
        p = self.params
        out = np.empty(19, dtype=np.int64)
        src.vdc_link_packed(np.array([*self.theta[i], *p.K[i], *p.rho_T[i], *p.lower[i],
                                      *p.upper[i], *V, *V_r, *dV, *g], dtype=np.int64), out)
        w = out.tolist()
        return w[:6], w[6:]


_ROW_PACKETS = tuple(int(t) for t in (PacketType.COMM_A, PacketType.COMM_B, PacketType.COMM_C,
                                       PacketType.COMM_D))
_TICK, _MODE, _TIMEOUT, _TAU_MIN, _TAU_MAX, _RAMP, _COMMIT, _SYNC_WINDOW, _PERIOD = (
    int(c) for c in (Config.TICK, Config.MODE, Config.TIMEOUT, Config.TAU_MIN, Config.TAU_MAX,
                     Config.RAMP, Config.COMMIT, Config.SYNC_WINDOW, Config.PERIOD))


class KernelNode(FastNode):
    """:class:`~cosim.model_node.FastNode` whose plain steps run in the compiled kernel, on
    row ``_row`` of the backend's :class:`KernelArrays` (module docstring). While
    :attr:`in_kernel`, the row holds the tick state, not the object: :meth:`pull` first."""

    in_kernel = False
    _row = None
    _prow = None
    _prow_of = None         # the joint's parameter words the row holds (None: write it again)

    def _param(self, bank: int, addr: int, w: int) -> None:
        self._prow_of = None                # a host write may change a joint word
        FastNode._param(self, bank, addr, w)

    def _config(self, now: int, reg: int, value: int) -> None:
        if reg == Config.TC_DISCIPLINE and value:
            # the kernel keeps PERIOD-cycle periods and every tick
            raise InputError("config.tc_discipline",
                             f"{value:#x}: the model backend's compiled kernel does not model "
                             "the disciplined period timer (issue 21 item 3); the backend's "
                             "pure-Python path does (ModelBackend(kernel='python'), or a "
                             "[clocks] run)")
        FastNode._config(self, now, reg, value)

    _kern = None

    def bind(self, arrays: KernelArrays, k: int, kern=None) -> None:
        """Row ``k`` of ``arrays``; with ``kern`` (the compiled module), :meth:`run` runs the
        plain ticks there too."""
        self._row = arrays.N[k]
        self._prow = arrays.P[k]
        self._erows = (arrays.E[k], arrays.VIS[k], arrays.PIPE[k], arrays.DUE[k])
        self._kern = kern
        #: the timer's events run with the tick state in the row (no copy of it either way)
        self.in_row = {"boundary": 0, "commit": 0, "timecode": 0, "packet": 0}
        #: plain commit points the kernel took inside a fast step (:meth:`arm_commit`)
        self.fast_commits = 0

    def run(self, until: int, sample=None, stay: bool = False) -> None:
        """:meth:`FastNode.run` with its runs of plain ticks in the kernel
        (:func:`~cosim.model_kernel_src.node_plain`, the translation of that loop's lazy
        branch; the row is pushed first) and the timer's other events in the reference's event
        loop (the row pulled back first). The object holds the state on return, unless
        ``stay`` (then the row may: :meth:`pull` before reading it)."""
        if sample is not None:
            self._sample = sample
        if until <= self._done:         # every event before it processed: nothing to run
            if not (stay or self._row_packet):  # (NodeModel.packet and .timecode run to a
                self.pull()                     # cycle the backend has just run the node to)
            return
        if self._kern is None or not self.lazy or self._sample is None:
            self.pull()
            FastNode.run(self, until)
            return
        node_plain = self._kern.node_plain
        E, vis, pipe, due = self._erows
        while True:
            if self.safe_stop_near(until):     # the safe stop: the reference's event loop
                self.pull()
                FastNode.run(self, until)
                return
            special = self.next_special()
            lim = special if special < until else until
            if self._nt < lim:
                if not self.in_kernel:
                    self.push()
                node_plain(self._row, self._prow, E, vis, pipe, due, lim)
            if special >= until:
                break
            if self._boundary_in_row(special) or self._commit_in_row(special):
                continue
            self.pull()
            NodeModel.run(self, special + 1)
        if not stay:
            self.pull()
        if until > self._done:
            self._done = until

    def _boundary_in_row(self, c: int) -> bool:
        """The timer's next event, at cycle ``c``, with the tick state in the kernel's row if it
        is a plain boundary (no ARM taking effect, no generator, not tripped, the safe stop
        not near: :meth:`run` checked): :meth:`NodeModel._boundary
        <hdl.node.core_ref.NodeModel._boundary>` step by step — the watchdog's view in cycle
        ``c`` (:func:`~cosim.model_kernel_src.torque_at`, the translation of
        :meth:`FastNode.torque_at`), the encoder's strobe and the snapshot (the reference's
        code, on the object), the CORDIC compiled (:func:`~cosim.model_kernel_src.sin_cos`, the
        translation of :func:`~hdl.node.trig_ref.sin_cos`), then the boundary's tick in the
        kernel. False (nothing
        done but the watchdog's view, which the reference's own then repeats) for any other
        event, or where the watchdog trips or PRIME is due."""
        if c != self._nb or self.arming or self.dmp_waiting or self.dmp_running or \
                (self.arm_pending and self._pre_seen != c):
            return False
        if not self.in_kernel:
            self.push()
        row = self._row
        self._kern.torque_at(row, c)                            # _watch(c)
        if row[src.N_TRIPPED] or row[src.N_PRIME_SET] or row[src.N_TORQUE_NONE]:
            return False
        self._now = c
        count, qd, errors = self._sample(c)
        self.tripped = False                # the status word's view of the row
        self.prime = bool(row[src.N_PRIME])
        overruns = int(row[src.N_OVERRUNS])
        self._snap = (int(row[src.N_TORQUE]), int(self.status), errors, overruns,
                      self.sync_errors, self.late_d)
        self.snap_count, self.snap_qd = count, qd
        kb = self._kb
        if kb is None:
            kb = self._kb = bam_constant(self.encoder.counts_per_rev)
        self.cos_q, self.sin_q = (self._kern.sin_cos(count, kb) if kb < src.SIN_COS_KB_MAX
                                  else sin_cos(count, self.encoder.counts_per_rev))
        self.fresh = False
        self._lb = c
        self._nb = c + self.config[_PERIOD]
        self.boundaries.append(c)
        if self.events is not None:
            self.events.append((c, NodeEvent.BOUNDARY))
        row[src.N_NT] = c                   # the boundary's tick (each boundary ticks)
        E, vis, pipe, due = self._erows
        self._kern.node_plain(row, self._prow, E, vis, pipe, due, c + 1)
        self.in_row["boundary"] += 1
        return True

    def _commit_in_row(self, c: int) -> bool:
        """The timer's next event, at cycle ``c``, in the kernel's row if it is a plain commit
        point (no boundary, pre-arm cycle or generator step with it, the safe stop not near:
        :meth:`run` checked): the tick in cycle ``c`` first, in the kernel (as
        :meth:`NodeModel.run <hdl.node.core_ref.NodeModel.run>` runs a cycle's tick before
        its commit), then the reference's commit (:meth:`NodeModel._take_d
        <hdl.node.core_ref.NodeModel._take_d>` on the object) and the words it changed into
        the row: no copy of the row each way. False (nothing done) for any other event."""
        if c != self._lb + self.config[_COMMIT] or self._commit_seen == self._lb or \
                c >= self._nb or self.arm_pending or self.dmp_running or self.dmp_waiting or \
                self.dmp_select:
            return False
        if not self.in_kernel:
            self.push()
        E, vis, pipe, due = self._erows
        self._kern.node_plain(self._row, self._prow, E, vis, pipe, due, c + 1)
        if self._commit_taken(c):
            row = self._row
            row[src.N_DBASE] = self.d_base
            row[src.N_D0:src.N_D0 + 4] = self.d_words
        self.in_row["commit"] += 1
        return True

    def kernel_commit(self) -> tuple[int, int] | None:
        """``(c, special)`` if the timer's next event is a commit point ``c`` that
        :meth:`_commit_in_row` would take (no boundary, pre-arm cycle or generator step with
        it, the generator's references not selected, the safe stop neither acting nor near by
        ``c``), ``special`` the next event after it (what :meth:`next_special` gives once it
        has passed); else None. A fast step may then run through ``c`` with the commit in the
        kernel (:meth:`arm_commit`)."""
        lb = self._lb
        if self._commit_seen == lb or self.arm_pending or self.dmp_running or \
                self.dmp_waiting or self.dmp_select or self._cfg_pending:
            return None
        cfg = self.config
        c = lb + cfg[_COMMIT]
        special = self._nb
        if c >= special:
            return None
        if cfg[_STOP] or cfg[_BRAKE]:
            if self.tripped:
                return None
            if self.armed:
                near = (self.last_packet + 2 + cfg[_TIMEOUT] - 2 * cfg[_TICK]
                        - _CYCLES_MAX - 2)
                if near <= c:
                    return None
                if near < special:
                    special = near
        return c, special

    def arm_commit(self, c: int) -> None:
        """The kernel takes the commit point ``c`` (:meth:`kernel_commit`) when its ticks pass
        it (:func:`~cosim.model_kernel_src.node_plain`): the pending Comm D's words, or the
        words in force if none is pending, into the row. The row must hold the tick state;
        :meth:`end_commit` after the kernel's calls."""
        # (N_COMMIT_C, N_DN_BASE, N_DN0 … N_DN0 + 3 in one assignment)
        if self.d_pending:
            self._row[src.N_COMMIT_C:src.N_DN0 + 4] = [c, self.d_next_base, *self.d_next]
        else:
            self._row[src.N_COMMIT_C:src.N_DN0 + 4] = [c, self.d_base, *self.d_words]

    def end_commit(self, c: int) -> bool:
        """After :meth:`arm_commit` ``c`` and the kernel's calls: if the kernel took the commit,
        the object's side of it, as :meth:`_commit_in_row` does after its tick (the
        observation port's COMMIT strobe, :meth:`NodeModel._take_d
        <hdl.node.core_ref.NodeModel._take_d>`); else the commit disarmed (the general path
        takes it). Returns whether the kernel took it."""
        row = self._row
        if row[src.N_COMMIT_C] != src.NEVER:
            row[src.N_COMMIT_C] = src.NEVER
            return False
        self._commit_taken(c)
        self.fast_commits += 1
        return True

    def _commit_taken(self, c: int) -> bool:
        """The object's side of a commit the kernel took in cycle ``c``: the period's commit
        seen and, with a Comm D pending, its COMMIT strobe and :meth:`NodeModel._take_d
        <hdl.node.core_ref.NodeModel._take_d>`. Returns whether a Comm D took effect."""
        self._commit_seen = self._lb
        if not self.d_pending:
            return False
        if self.events is not None:
            self.events.append((c, NodeEvent.COMMIT))
        self._take_d(self.d_next, self.d_next_base)
        self.d_pending = False
        return True

    _row_packet = False     # NodeModel.packet running with the tick state in the row
    _kb = None              # bam_constant of the encoder's counts per revolution (CORDIC)

    def packet(self, now: int, ptype: int, payload: bytes, period: int | None = None,
               enc_errors: int = 0, sample=None, stay: bool = False):
        """:meth:`NodeModel.packet <hdl.node.core_ref.NodeModel.packet>`; with ``stay`` (as
        in :meth:`run`), a Comm A, B, C or D leaves the tick state in the kernel's row where
        the watchdog's view in its cycle (:func:`~cosim.model_kernel_src.torque_at`, the
        translation of the reference's ``_watch``) neither trips nor primes: such a packet
        changes no tick state but the watchdog's last packet, PRIME (a Comm B clears it) and,
        disarmed, the joint's words (a Comm D), which go into the row after the reference's
        own code has run on the object (its ``run`` and ``_watch`` done here)."""
        if not stay or self._kern is None or ptype not in _ROW_PACKETS or self._row_packet:
            return NodeModel.packet(self, now, ptype, payload, period, enc_errors, sample)
        self.run(now + 1, sample, stay=True)
        row = self._row
        if self.in_kernel:
            self._kern.torque_at(row, now)                      # _watch(now)
        if not self.in_kernel or row[src.N_TRIPPED] or row[src.N_PRIME_SET] or \
                row[src.N_TORQUE_NONE]:
            self.pull()
            return NodeModel.packet(self, now, ptype, payload, period, enc_errors, sample)
        self._now = now
        self.tripped = False                # the status word's view of the row
        self.prime = bool(row[src.N_PRIME])
        self._row_packet = True
        try:
            reply = NodeModel.packet(self, now, ptype, payload, period, enc_errors, sample)
        finally:
            self._row_packet = False
        row[src.N_PRIME] = self.prime
        # N_LAST_PACKET, N_DBASE, N_D0 … N_D0 + 3 in one assignment
        row[src.N_LAST_PACKET:src.N_D0 + 4] = [now, self.d_base, *self.d_words]
        self.in_row["packet"] += 1
        return reply

    def _watch(self, now: int) -> None:
        if self._row_packet:                # done in the row (packet)
            return
        NodeModel._watch(self, now)

    def timecode(self, now: int, value: int, sample=None, stay: bool = False) -> bool:
        """:meth:`NodeModel.timecode <hdl.node.core_ref.NodeModel.timecode>`; one that does
        not resynchronise the timer touches no tick state (the observation port's strobe and
        the time-code's value only), so the node's ticks stay in the kernel. ``stay`` as in
        :meth:`run`."""
        self.run(now, sample, stay=True)
        if self._kern is None or self.phase(now) >= self.config[_SYNC_WINDOW]:
            self.pull()                         # a resync: the reference's boundary
            return NodeModel.timecode(self, now, value, sample)
        if self.events is not None:
            self.events.append((now, NodeEvent.TIMECODE))
        self.run(now + 1, stay=True)
        self.tc_value = value & 0xFF
        if not stay:
            self.pull()
        self.in_row["timecode"] += 1
        return False

    def run_torque(self, until: int, sample) -> int:
        """``run(until, sample)`` then ``torque_at(until)``, the node left in the kernel where
        its ticks ran there (:func:`~cosim.model_kernel_src.torque_at`, the translation of
        :meth:`FastNode.torque_at`): what the backend does at the end of every piece, without
        a pull and the next piece's push."""
        self.run(until, sample, stay=True)
        if self.in_kernel:
            w = int(self._kern.torque_at(self._row, until))
            if self._row[src.N_TORQUE_NONE]:
                raise RuntimeError("model kernel: an unobserved torque word was sampled")
            return w
        return self.torque_at(until)

    def push(self) -> None:
        """The object's tick state into the kernel's row; the kernel owns it from now. (One
        assignment of the whole row, in ``N_*`` order; a field the row marks absent — no
        landing, no deferred Part B, no PRIME due — is written 0, which the kernel never reads.)"""
        t = self.torque
        land = self._landing
        d = self._deferred
        j = self.joint
        pd = self._prime_due
        cfg = self.config
        self._row[:] = [
            self._nt, 0 if t is None else t, t is None,
            *((0, 0, 0) if land is None else (land[0], 0, 2) if land[1] is None else
              (land[0], land[1], 1)),
            self._started, self._busy_until, self.overruns,
            *((0, 0, 0, 0, 0) if d is None else (1, *d)),
            j.q_des, j.v_des, j.i_lo, j.i_hi,
            self.armed, self.tripped, self.prime, 0 if pd is None else pd, pd is not None,
            self.last_packet, self.d_base, *self.d_words,
            cfg[_TICK], cfg[_MODE], cfg[_TIMEOUT], cfg[_TAU_MIN], cfg[_TAU_MAX], cfg[_RAMP],
            src.NEVER, 0, 0, 0, 0, 0]           # no commit armed (ModelBackend arms one)
        if self._prow_of is not j.params:
            param_row(j.params, self._prow)
            self._prow_of = j.params
        self.in_kernel = True

    def pull(self) -> None:
        """The kernel's row back into the object (what the plain ticks changed)."""
        if not self.in_kernel:
            return
        self.in_kernel = False
        N = self._row.tolist()
        self._nt = N[src.N_NT]
        self.torque = None if N[src.N_TORQUE_NONE] else N[src.N_TORQUE]
        kind = N[src.N_LAND]
        self._landing = None if kind == 0 else \
            (N[src.N_LAND_C], N[src.N_LAND_V] if kind == 1 else None)
        self._started = N[src.N_STARTED]
        self._busy_until = N[src.N_BUSY]
        self.overruns = N[src.N_OVERRUNS]
        self._deferred = tuple(N[src.N_DEF_TN:src.N_DEF_A + 1]) if N[src.N_DEF] else None
        j = self.joint
        j.q_des, j.v_des, j.i_lo, j.i_hi = N[src.N_QDES:src.N_IHI + 1]
        if N[src.N_TRIPPED] and not self.tripped:        # the kernel tripped it
            self.trip_cycle = N[src.N_LAST_PACKET] + 2 + N[src.N_TIMEOUT]
            self.hold_pos, self.hold_fixed = None, False
            self.still_cycle, self.still_run = None, 0     # as NodeModel._watch's trip
        self.tripped = bool(N[src.N_TRIPPED])
        self.prime = bool(N[src.N_PRIME])
        self._prime_due = N[src.N_PRIME_DUE] if N[src.N_PRIME_SET] else None
