"""Pinocchio's forward dynamics called from compiled code: the same numbers bit for bit as
``pin.aba`` from Python, and what a call costs each way (issue 18, goal 1's 0.5).

Run on purpose, not in CI; it needs Eigen's headers (``cmeel-eigen``, in the ``fast`` and
``test`` extras) and a C++ compiler::

    .venv/bin/python benchmarks/aba_from_cpp.py [--states 20000] [--robot mrm3 --robot mrm6]

This measurement led to :mod:`cosim.pin_shim`, which the model backend now builds and runs
(``benchmarks/model_speed.py --pin`` measures what it gives). Before it, the model backend's
fast path called ``pin.aba`` from Python once a plant step (then the compiled kernel), so
every step returned to Python. A loop of steps in compiled code needs the
dynamics there too, and the model backend is only worth having bit for bit: this builds a
small C++ program against the ``pin`` wheel's own headers and ``libpinocchio_default`` (with
``PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION``, as the wheel's CMake target says: the call links
to the library's instantiation of ``aba`` for ``Eigen::Ref`` vectors, the one the Python
binding runs — checked with ``nm``), loads each robot's model as Python built it (pinocchio's
binary serialisation: the same doubles), runs ``aba`` on random states (and states rounded to
0.1) and compares every result with ``pin.aba``'s, bit for bit; then times a call from Python
and from C++, side by side in this run.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

_PROGRAM = r"""
#include <pinocchio/multibody.hpp>
#include <pinocchio/serialization.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <vector>

int main(int argc, char** argv) {
  pinocchio::Model model;
  model.loadFromBinary(argv[1]);
  pinocchio::Data data(model);
  const int nv = model.nv, n = std::atoi(argv[2]), reps = std::atoi(argv[5]);
  std::vector<double> x(3 * nv * (size_t)n);
  std::ifstream in(argv[3], std::ios::binary);
  in.read((char*)x.data(), x.size() * sizeof(double));
  std::ofstream out(argv[4], std::ios::binary);
  typedef Eigen::Ref<const Eigen::VectorXd> R;
  typedef Eigen::Map<const Eigen::VectorXd> M;
  for (int k = 0; k < n; k++) {
    const double* p = &x[3 * nv * (size_t)k];
    const Eigen::VectorXd& a = pinocchio::aba(model, data, R(M(p, nv)), R(M(p + nv, nv)),
                                              R(M(p + 2 * nv, nv)), pinocchio::Convention::LOCAL);
    out.write((const char*)a.data(), nv * sizeof(double));
  }
  double sink = 0;
  auto t0 = std::chrono::steady_clock::now();
  for (int r = 0; r < reps; r++) {
    const double* p = &x[3 * nv * (size_t)(r % n)];
    sink += pinocchio::aba(model, data, R(M(p, nv)), R(M(p + nv, nv)), R(M(p + 2 * nv, nv)),
                           pinocchio::Convention::LOCAL)[0];
  }
  auto t1 = std::chrono::steady_clock::now();
  std::printf("%.1f %g\n", std::chrono::duration<double, std::nano>(t1 - t0).count() / reps,
              sink);
  return 0;
}
"""


def build(work: Path) -> Path:
    from mrm_cosim.cosim.pin_shim import _DEFINES, _toolchain   # (the library's own: one place)

    try:
        cxx, lib, eigen = _toolchain()
    except RuntimeError as e:
        raise SystemExit(str(e)) from None
    (work / "aba.cpp").write_text(_PROGRAM)
    cmd = [cxx, "-O2", "-std=c++17", *(f"-D{d}" for d in _DEFINES),
           f"-I{lib.parent / 'include'}", f"-I{eigen}", "aba.cpp", "-o", "aba",
           f"-L{lib}", "-lpinocchio_default", "-lboost_serialization", f"-Wl,-rpath,{lib}"]
    t = time.perf_counter()
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"{cxx} failed:\n{proc.stderr[-3000:]}")
    symbols = subprocess.run(["nm", "-C", str(work / "aba")], capture_output=True,
                             text=True).stdout
    linked = [line for line in symbols.splitlines() if " pinocchio::aba<" in line]
    if not linked or not all(line.split()[0] == "U" for line in linked):
        raise SystemExit("aba was compiled into the program, not taken from "
                         "libpinocchio_default: the comparison would not be of one code")
    print(f"built in {time.perf_counter() - t:.1f} s ({cxx}); aba is the library's "
          f"instantiation (undefined in the program: {len(linked)} symbol)")
    return work / "aba"


def main(argv=None) -> int:
    import pinocchio as pin

    from mrm_cosim.models.robot import load_robot

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", help="robots (default mrm3 and mrm6)")
    ap.add_argument("--states", type=int, default=20_000)
    ap.add_argument("--reps", type=int, default=200_000)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        exe = build(work)
        print(f"{'robot':<6} {'nv':>3} {'states':>7} {'bit for bit':>12} "
              f"{'Python ns/call':>15} {'C++ ns/call':>12}")
        for name in args.robot or ["mrm3", "mrm6"]:
            model = pin.buildModelFromXML(load_robot(name).urdf())
            data = model.createData()
            model.saveToBinary(str(work / "m.bin"))
            rng = np.random.default_rng(1)
            n, nv = args.states, model.nv
            x = np.empty((n, 3, nv))
            x[:, 0] = rng.uniform(-np.pi, np.pi, (n, nv))
            x[:, 1] = rng.normal(0.0, 3.0, (n, nv))
            x[:, 2] = rng.normal(0.0, 50.0, (n, nv))
            x[: n // 100] = np.round(x[: n // 100], 1)
            x.tofile(work / "x.bin")
            ref = np.array([pin.aba(model, data, s[0], s[1], s[2]) for s in x])
            m = min(n, 20_000)
            t = time.perf_counter()
            for s in x[:m]:
                pin.aba(model, data, s[0], s[1], s[2])
            py_ns = (time.perf_counter() - t) / m * 1e9
            run = subprocess.run([str(exe), str(work / "m.bin"), str(n), str(work / "x.bin"),
                                  str(work / "a.bin"), str(args.reps)], capture_output=True,
                                 text=True, check=True)
            cpp_ns = float(run.stdout.split()[0])
            got = np.fromfile(work / "a.bin").reshape(n, nv)
            same = np.array_equal(ref.view(np.int64), got.view(np.int64))
            print(f"{name:<6} {nv:>3} {n:>7} {'yes' if same else 'NO':>12} {py_ns:>15,.0f} "
                  f"{cpp_ns:>12,.0f}")
            if not same:
                k = int(np.argmax((ref != got).any(axis=1)))
                print(f"  first difference at state {k}: {ref[k]} against {got[k]}")
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
