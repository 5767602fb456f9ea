"""Pinocchio's dynamics for the model backend's compiled inner loop, bit for bit ``pin``'s.

The model backend's fast path (:meth:`cosim.model.ModelBackend.fast_path`) runs whole plant
steps in its compiled kernel, but the plant's dynamics are pinocchio's: before this module,
every step returned to Python for ``pin.aba`` (or ``pin.nonLinearEffects`` and ``pin.crba``)
and went back into the kernel with the result. Here a small C library, built on first use
against the ``pin`` wheel's own headers and linked to its ``libpinocchio_default``, exposes
one function, :data:`SOURCE`'s ``mrm_pin(model, which, q, v, tau, out)``, which calls the
*library's* instantiations of ``aba``, ``nonLinearEffects`` and ``crba`` — the very code the
Python binding runs (``PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION``, as the wheel's CMake target
sets it; :func:`build` checks with ``nm`` that none of the three was compiled into the
library here) — on a copy of the plant's model made by pinocchio's binary serialisation (the
same doubles). The kernel calls it through a function pointer (``IB[H_PIN_FN]``), so numba's
cache holds no address.

Every model handed to the library is checked first (:meth:`Dynamics.model`): the three
functions on states drawn at random and on rest states, against ``pin``'s, bit for bit, once
per model's contents (a model changed in place gets a new copy); a model that differs
anywhere is refused, and the fast path goes on calling ``pin`` from Python (one warning).
The build needs a C++ compiler and Eigen's headers (``cmeel-eigen``, in the ``fast`` and
``test`` extras); where either is missing or the build fails, :func:`load` gives None after
one warning and nothing else changes: the kernel is the same, only its steps return to Python
for the dynamics as before.

The build is cached under ``$MRM_CACHE_DIR/pin/<digest>`` (``mrm cache``;
:func:`cosim.compiled.cxx_library`, which builds the compiled backend's split loop too), the
digest of the source, its flags, the compiler's version and the versions of ``pin``,
``libpinocchio`` and ``cmeel-eigen``; one process builds at a time, the others wait for it.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import warnings
import weakref
from pathlib import Path

import numpy as np

__all__ = ["SOURCE", "Dynamics", "load", "build", "ABA", "NLE", "CRBA"]

#: ``which``: ``out = aba(q, v, tau)`` (n); ``nonLinearEffects(q, v)`` (n); ``crba(q)``'s
#: matrix, row by row (n·n: the upper triangle pinocchio fills, the lower as its ``data.M``
#: holds it)
ABA, NLE, CRBA = 0, 1, 2

SOURCE = r"""
#include <pinocchio/multibody.hpp>
#include <pinocchio/serialization.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <boost/asio/streambuf.hpp>
#include <cstdint>
#include <new>
#include <ostream>

namespace {
struct Handle {
  pinocchio::Model model;
  pinocchio::Data data;
};
typedef Eigen::Ref<const Eigen::VectorXd> R;
typedef Eigen::Map<const Eigen::VectorXd> M;
}

extern "C" {

// A model from pinocchio's binary serialisation (the bytes Python's Model.saveToBinary wrote
// into a StreamBuffer); null if they cannot be read.
void* mrm_pin_new(const char* bytes, int64_t size) {
  Handle* h = new (std::nothrow) Handle();
  if (!h) return nullptr;
  try {
    boost::asio::streambuf buffer;
    std::ostream out(&buffer);
    out.write(bytes, size);
    h->model.loadFromBinary(buffer);
    h->data = pinocchio::Data(h->model);
  } catch (...) {
    delete h;
    return nullptr;
  }
  return h;
}

void mrm_pin_free(void* p) { delete static_cast<Handle*>(p); }

int64_t mrm_pin_nv(void* p) { return static_cast<Handle*>(p)->model.nv; }

// 0: aba(q, v, tau) -> out[n]; 1: nonLinearEffects(q, v) -> out[n];
// 2: crba(q) -> out[n*n], row by row
void mrm_pin(void* p, int64_t which, const double* q, const double* v, const double* tau,
             double* out) {
  Handle* h = static_cast<Handle*>(p);
  const int n = h->model.nv;
  if (which == 0) {
    const Eigen::VectorXd& a = pinocchio::aba(h->model, h->data, R(M(q, n)), R(M(v, n)),
                                              R(M(tau, n)), pinocchio::Convention::LOCAL);
    for (int i = 0; i < n; i++) out[i] = a[i];
  } else if (which == 1) {
    const Eigen::VectorXd& b = pinocchio::nonLinearEffects(h->model, h->data, R(M(q, n)),
                                                           R(M(v, n)));
    for (int i = 0; i < n; i++) out[i] = b[i];
  } else {
    const Eigen::MatrixXd& m = pinocchio::crba(h->model, h->data, R(M(q, n)),
                                               pinocchio::Convention::LOCAL);
    for (int r = 0; r < n; r++)
      for (int c = 0; c < n; c++) out[r * n + c] = m(r, c);
  }
}

}
"""

_DEFINES = ("PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION", "BOOST_MPL_LIMIT_LIST_SIZE=30",
            "BOOST_MPL_LIMIT_VECTOR_SIZE=30", "BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS",
            "BOOST_FUSION_INVOKE_MAX_ARITY=12")

#: the three algorithms the library must take from libpinocchio_default (``nm -C`` names)
_LINKED = ("::aba<", "::nonLinearEffects<", "::crba<")

_loaded = None          # a Dynamics, False where it cannot be, None before trying


def _prefix_dirs() -> list[Path]:
    """The ``cmeel.prefix`` folders on the path (the ``pin`` wheel's, ``cmeel-eigen``'s)."""
    found = []
    for entry in sys.path:
        p = Path(entry or ".") / "cmeel.prefix"
        if p.is_dir() and p not in found:
            found.append(p)
    return found


def _toolchain() -> tuple[str, Path, Path]:
    """``(compiler, pinocchio's lib folder, Eigen's include folder)``, or RuntimeError saying
    what is missing."""
    prefixes = _prefix_dirs()
    lib = next((p / "lib" for p in prefixes
                if (p / "lib" / "libpinocchio_default.so").exists()), None)
    eigen = next((p / "include" / "eigen3" for p in prefixes
                  if (p / "include" / "eigen3" / "Eigen").is_dir()), None)
    if lib is None:
        raise RuntimeError("no libpinocchio_default.so in a cmeel.prefix (is `pin` installed?)")
    if eigen is None:
        raise RuntimeError("Eigen's headers are missing (pip install cmeel-eigen)")
    if os.environ.get("CXX"):
        cxx = shutil.which(os.environ["CXX"])
        if not cxx:
            raise RuntimeError(f"no C++ compiler: $CXX is {os.environ['CXX']}")
    else:
        cxx = shutil.which("g++") or shutil.which("c++")
        if not cxx:
            raise RuntimeError("no C++ compiler (g++, c++ or $CXX)")
    return cxx, lib, eigen


def _versions() -> str:
    """The versions of the wheels the library is built from (part of its cache key)."""
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for name in ("pin", "libpinocchio", "cmeel-eigen"):
        try:
            out.append(f"{name}={version(name)}")
        except PackageNotFoundError:
            out.append(f"{name}=?")
    return " ".join(out)


def build() -> Path:
    """The shared library (built, or taken from the cache: :func:`cosim.compiled.cxx_library`,
    kind ``pin``): its path. RuntimeError where it cannot be built, or where the build compiled
    one of the three algorithms itself instead of linking the ``pin`` wheel's (its numbers
    would not be ``pin``'s by construction)."""
    from mrm_cosim.cosim.compiled import cxx_library

    cxx, lib, eigen = _toolchain()
    args = [*(f"-D{d}" for d in _DEFINES), f"-I{lib.parent / 'include'}", f"-I{eigen}",
            f"-L{lib}", "-lpinocchio_default", "-lboost_serialization", f"-Wl,-rpath,{lib}"]
    return cxx_library("pin", "mrmpin", SOURCE, args, cxx=cxx, key=_versions(), check=_linked)


def _linked(so: Path) -> None:
    """Refuses a build that defines one of the three algorithms itself (``nm``, where the
    machine has it)."""
    nm = shutil.which("nm")
    if nm:
        symbols = subprocess.run([nm, "-C", "-D", "--defined-only", str(so)],
                                 capture_output=True, text=True).stdout
        inside = [s for s in _LINKED if s in symbols]
        if inside:
            raise RuntimeError(f"{', '.join(inside)} compiled into the library instead of "
                               "taken from libpinocchio_default")


class Dynamics:
    """The loaded library: :meth:`model` gives a handle for a ``pin.Model``, :attr:`fn` the
    address of ``mrm_pin`` (the kernel's ``IB[H_PIN_FN]``)."""

    def __init__(self, path: Path):
        lib = self._lib = ctypes.CDLL(str(path))
        lib.mrm_pin_new.restype = ctypes.c_void_p
        lib.mrm_pin_new.argtypes = [ctypes.c_char_p, ctypes.c_int64]
        lib.mrm_pin_free.restype = None
        lib.mrm_pin_free.argtypes = [ctypes.c_void_p]
        lib.mrm_pin_nv.restype = ctypes.c_int64
        lib.mrm_pin_nv.argtypes = [ctypes.c_void_p]
        dp = ctypes.POINTER(ctypes.c_double)
        lib.mrm_pin.restype = None
        lib.mrm_pin.argtypes = [ctypes.c_void_p, ctypes.c_int64, dp, dp, dp, dp]
        self._call = lib.mrm_pin
        #: ``mrm_pin``'s address
        self.fn = ctypes.cast(lib.mrm_pin, ctypes.c_void_p).value
        self.path = path
        self._models = weakref.WeakKeyDictionary()  # pin.Model → (its bytes' digest, handle)
        self._checked = {}          # digest of a model's bytes → what differs ('' nothing)

    def model(self, model) -> int | None:
        """A handle (an address) on a copy of ``model`` (a ``pin.Model``) as it is now, for
        :meth:`call` and the kernel, freed with ``model`` (a model changed since its last
        handle gets a new copy); None, with a warning, if pinocchio cannot read the copy back
        or the copy's three functions differ from ``pin``'s on the check states
        (:meth:`differs`, once per model's contents), anywhere, by a bit."""
        import pinocchio as pin

        buffer = pin.serialization.StreamBuffer()
        model.saveToBinary(buffer)
        raw = bytes(buffer.tobytes())
        key = hashlib.sha256(raw).digest()
        hit = self._models.get(model)
        if hit is not None and hit[0] == key:
            return hit[1] or None
        handle = self._lib.mrm_pin_new(raw, len(raw))
        bad = "its copy could not be read back" if not handle else None
        if handle:
            weakref.finalize(model, self._lib.mrm_pin_free, handle)
            bad = self._checked.get(key)
            if bad is None:
                bad = self._checked[key] = self.differs(model, handle)
        if bad:
            warnings.warn(f"model backend: pinocchio from compiled code differs from pin's "
                          f"({bad}); the fast path calls pin from Python", RuntimeWarning,
                          stacklevel=2)
            self._models[model] = (key, 0)
            return None
        self._models[model] = (key, handle)
        return handle

    def call(self, handle: int, which: int, q, v, tau, out) -> None:
        """``mrm_pin`` on float64 arrays (``q``, ``v``, ``tau`` of n, ``out`` of n or n·n,
        contiguous)."""
        dp = ctypes.POINTER(ctypes.c_double)
        self._call(handle, which, q.ctypes.data_as(dp), v.ctypes.data_as(dp),
                   tau.ctypes.data_as(dp), out.ctypes.data_as(dp))

    def differs(self, model, handle: int, states: int = 12) -> str:
        """Where the handle's ``aba``, ``nonLinearEffects`` and ``crba`` differ from ``pin``'s
        on ``states`` random states (a third at rest, a third rounded) and on ``model``'s
        neutral state: a description of the first difference, or '' if none, bit for bit."""
        import pinocchio as pin

        n = model.nv
        if self._lib.mrm_pin_nv(handle) != n:
            return f"nv {self._lib.mrm_pin_nv(handle)} against {n}"
        data = model.createData()
        rng = np.random.default_rng(20261127)
        x = np.empty((states + 1, 3, n))
        x[:-1, 0] = rng.uniform(-np.pi, np.pi, (states, n))
        x[:-1, 1] = rng.normal(0.0, 3.0, (states, n))
        x[:-1, 2] = rng.normal(0.0, 50.0, (states, n))
        x[: states // 3, 1] = 0.0
        x[states // 3: 2 * states // 3] = np.round(x[states // 3: 2 * states // 3], 1)
        x[-1] = 0.0
        a, M = np.empty(n), np.empty((n, n))
        for s in x:
            q, v, tau = (np.ascontiguousarray(r) for r in s)
            refs = (np.array(pin.aba(model, data, q, v, tau)),
                    np.array(pin.nonLinearEffects(model, data, q, v)),
                    np.triu(pin.crba(model, data, q)))
            for which, want, out in zip((ABA, NLE, CRBA), refs, (a, a, M), strict=True):
                self.call(handle, which, q, v, tau, out)
                got = np.triu(out) if which == CRBA else out
                if not np.array_equal(want.view(np.int64), got.view(np.int64)):
                    return f"{('aba', 'nonLinearEffects', 'crba')[which]} at q={q.tolist()}"
        return ""


def load() -> Dynamics | None:
    """The library, built or from the cache, or None after one warning where it cannot be
    built or loaded here (``MRM_PIN_SHIM=0`` turns it off without a warning)."""
    global _loaded
    if _loaded is None:
        if os.environ.get("MRM_PIN_SHIM", "1") == "0":
            _loaded = False
        else:
            try:
                _loaded = Dynamics(build())
            except Exception as e:      # noqa: BLE001 — any failure: pin from Python
                _loaded = False
                warnings.warn(f"model backend: pinocchio from compiled code unavailable "
                              f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})"
                              "; the fast path calls pin from Python", RuntimeWarning,
                              stacklevel=2)
    return _loaded or None
