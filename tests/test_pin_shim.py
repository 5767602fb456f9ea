"""Pinocchio from compiled code (:mod:`cosim.pin_shim`): the model backend's kernel runs plant
steps on through ``aba``, ``nonLinearEffects`` and ``crba`` of the ``pin`` wheel's own library,
bit for bit ``pin``'s, and falls back to calling ``pin`` from Python, with one warning, where
the library cannot be built or a model's copy differs."""

from __future__ import annotations

import runpy
import warnings

import numpy as np
import pinocchio as pin
import pytest

from mrm_cosim.cosim import model_kernel as mk
from mrm_cosim.cosim import pin_shim
from mrm_cosim.models.robot import load_robot

needs_numba = pytest.mark.skipif(mk.load() is None, reason="numba unavailable")


@pytest.fixture
def dyn():
    """The library: it builds here (the test extra brings Eigen's headers; CI has g++)."""
    d = pin_shim.load()
    assert d is not None, "the pinocchio library did not build (see the warning)"
    return d


def _model(robot: str, mass_scale: float = 1.0):
    model = pin.buildModelFromXML(load_robot(robot).urdf())
    if mass_scale != 1.0:
        for k in range(1, model.njoints):
            inertia = model.inertias[k]
            model.inertias[k] = pin.Inertia(inertia.mass * mass_scale, inertia.lever,
                                            inertia.inertia * mass_scale)
    return model


def test_the_library_links_pinocchio_s_own_algorithms(dyn):
    """The build is cached by digest, and none of the three algorithms is compiled into it
    (``build`` checks with ``nm``: they are ``libpinocchio_default``'s, the code ``pin``
    runs)."""
    from mrm_cosim.cosim.compiled import cache_dir

    assert dyn.path.parent.parent == cache_dir() / "pin"
    assert pin_shim.build() == dyn.path                     # from the cache
    import shutil
    import subprocess

    if shutil.which("nm"):
        undefined = subprocess.run(["nm", "-C", "-D", "--undefined-only", str(dyn.path)],
                                   capture_output=True, text=True).stdout
        for name in pin_shim._LINKED:
            assert name in undefined, name


@pytest.mark.parametrize("robot, scale", [("mrm3", 1.0), ("mrm6", 1.0), ("mrm3", 1.37)])
def test_the_three_algorithms_are_pin_s_bit_for_bit(dyn, robot, scale):
    """500 states (random, at rest, rounded; the neutral one) of each model, a perturbed one
    too: ``aba``, ``nonLinearEffects`` and ``crba``'s upper triangle equal ``pin``'s bits."""
    model = _model(robot, scale)
    handle = dyn.model(model)
    assert handle
    assert dyn.differs(model, handle, states=500) == ""


def test_a_copy_of_another_model_is_found_to_differ(dyn):
    """The check can fail: a handle on one model against ``pin`` on a heavier one."""
    light, heavy = _model("mrm3"), _model("mrm3", 1.01)
    assert dyn.differs(heavy, dyn.model(light)).startswith("aba at q=")


@needs_numba
def test_the_kernel_s_call_and_its_python_form_give_pin_s_numbers(dyn):
    """:func:`cosim.model_kernel_src.pin_call` compiled (the intrinsic) and as written (through
    ctypes) give what ``pin`` gives."""
    import numba

    python_form = runpy.run_path(mk.src.__file__)["pin_call"]
    compiled = mk.pin_called()

    @numba.njit
    def call(fn, model, which, q, v, tau, out):
        compiled(fn, model, which, q, v, tau, out)

    model = _model("mrm6")
    data = model.createData()
    handle = dyn.model(model)
    rng = np.random.default_rng(7)
    q, v, tau = (rng.normal(size=model.nv) for _ in range(3))
    for f in (python_form, call):
        a, b, M = np.empty(model.nv), np.empty(model.nv), np.empty(model.nv ** 2)
        f(dyn.fn, handle, pin_shim.ABA, q, v, tau, a)
        f(dyn.fn, handle, pin_shim.NLE, q, v, tau, b)
        f(dyn.fn, handle, pin_shim.CRBA, q, v, tau, M)
        assert np.array_equal(a, pin.aba(model, data, q, v, tau))
        assert np.array_equal(b, pin.nonLinearEffects(model, data, q, v))
        assert np.array_equal(np.triu(M.reshape(model.nv, model.nv)),
                              np.triu(pin.crba(model, data, q)))


def _loop_run(robot: str, joints: str, cycles: int = 300_000):
    from mrm_cosim.cosim.bench import bench_master_and_plant
    from mrm_cosim.cosim.closed_loop import ClosedLoop
    from mrm_cosim.cosim.model import ModelBackend
    from mrm_cosim.master.uploads import Gains, node_uploads, pid_shifts
    from mrm_cosim.models.plant import PlantConfig, make_plant

    robot_ = load_robot(robot)
    master, plant = bench_master_and_plant(robot_)
    if joints != "rigid":
        plant = make_plant(robot_, PlantConfig(joints=joints), seed=0)
        plant.reset(robot_.home)
    backend = ModelBackend(kernel="numba", pid_shift=pid_shifts(robot_))
    loop = ClosedLoop(robot_, backend, master, plant, 50_000,
                      node_uploads(robot_, "vdc", Gains()))
    result = loop.run(cycles)
    return (result.trace_sha256, dict(backend.fast_steps), backend.stick_cached,
            [(r.index, r.events, r.arrivals) for r in master.records]), backend.pin_steps


@needs_numba
@pytest.mark.parametrize("joints", ["rigid", "compliant"])
def test_the_kernel_runs_on_through_pinocchio_with_the_same_trace(dyn, monkeypatch, joints):
    """``mrm bench``'s window on ``mrm6`` with the library and without it (the kernel returning
    to Python for ``pin`` every step, as before it): the same trace, the same steps of each
    kind (free, stick-slip, general solve, from the cache), the same master records; with it,
    most steps ran on in the kernel. (tests/test_model_kernel.py compares the kernel, with the
    library, against the pure-Python path on both plants and all three controllers.)"""
    with_it, pin_steps = _loop_run("mrm6", joints)
    monkeypatch.setattr(pin_shim, "_loaded", False)
    without, none = _loop_run("mrm6", joints)
    assert with_it == without
    assert none == 0
    assert pin_steps > 0.3 * sum(with_it[1].values()), (pin_steps, with_it[1])
    if joints == "rigid":
        assert with_it[1]["stick-slip"] > 0 and with_it[1]["solve"] > 0, with_it[1]


@needs_numba
def test_a_model_whose_copy_differs_is_refused_with_one_warning(dyn, monkeypatch):
    """Where the check finds a difference, the handle is refused (a warning names the
    function), and the fast path calls ``pin`` from Python: the same trace, no step run on
    through the library."""
    want, _ = _loop_run("mrm3", "rigid", 150_000)
    monkeypatch.setattr(pin_shim.Dynamics, "differs",
                        lambda self, model, handle, states=12: "aba at q=[0.0]")
    monkeypatch.setattr(dyn, "_checked", {})
    with pytest.warns(RuntimeWarning, match=r"pinocchio from compiled code differs from pin's "
                      r"\(aba at q=\[0.0\]\); the fast path calls pin from Python"):
        got, steps = _loop_run("mrm3", "rigid", 150_000)
    assert got == want and steps == 0


@needs_numba
def test_without_a_compiler_pin_is_called_from_python_with_one_warning(monkeypatch, tmp_path):
    """No C++ compiler (``$CXX`` names none): one warning, the same trace as with the
    library, no step run on through it."""
    want, _ = _loop_run("mrm3", "rigid", 150_000)
    monkeypatch.setattr(pin_shim, "_loaded", None)
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-c++"))
    monkeypatch.setenv("MRM_CACHE_DIR", str(tmp_path / "cache"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got, steps = _loop_run("mrm3", "rigid", 150_000)
    msgs = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert msgs == ["model backend: pinocchio from compiled code unavailable (RuntimeError: "
                    f"no C++ compiler: $CXX is {tmp_path / 'no-such-c++'}); the fast path "
                    "calls pin from Python"], msgs
    assert got == want and steps == 0
    assert not (tmp_path / "cache" / "pin").exists()


def test_it_can_be_turned_off(monkeypatch):
    monkeypatch.setattr(pin_shim, "_loaded", None)
    monkeypatch.setenv("MRM_PIN_SHIM", "0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pin_shim.load() is None


@needs_numba
@pytest.mark.parametrize("plain_end, drawn_end, want_k, want_r", [
    (3, 5, 2, 24),      # rows 1, 2 run on; row 3 (the step with node events) is the caller's
    (5, 5, 4, 0),       # rows 1 … 4 run on, the last without the next step's pre
    (1, 5, 0, 24),      # none: the next row is already the caller's
])
def test_the_compliant_kernel_runs_on_to_its_bounds_and_no_further(dyn, plain_end, drawn_end,
                                                                   want_k, want_r):
    """``fast_step_compliant`` with the library: from row 0 it runs on through the rows below
    ``IB[H_C_PLAIN_END]`` (each with the next step's ``pre`` where the row after it is below
    ``IB[H_C_DRAWN_END]``), and returns ``r + 64 k`` with the last row's ``r``; each step run
    on writes its trace row."""
    from mrm_cosim.models import compliant_kernel_src as ck

    kern = mk.load()
    a = mk._throw_away()
    model = pin.Model()
    model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "j")
    model.appendBodyToJoint(1, pin.Inertia.FromBox(1.0, 0.1, 0.1, 0.1), pin.SE3.Identity())
    handle = dyn.model(model)
    src = mk.src
    a.IB[src.H_PIN_FN], a.IB[src.H_PIN_MODEL] = dyn.fn, handle
    a.IB[src.H_C_FIRST], a.IB[src.H_C_PLAIN_END], a.IB[src.H_C_DRAWN_END] = 0, plain_end, \
        drawn_end
    F = np.zeros(src.f_size(1))
    F[src.F_H], F[src.F_HH] = 1e-5, 5e-6
    rec = np.full((2, 8, 1), np.nan)
    r = kern.fast_step_compliant(a.IB, F, np.zeros((ck.S_ROWS, 1)), np.zeros(1), rec, 0, 0,
                                 np.ones((ck.C_ROWS, 1)), np.zeros((drawn_end, 1)), 1)
    assert (r >> 6, r & 63) == (want_k, want_r)
    assert a.IB[src.H_RUN_PIN] == want_k
    assert not np.isnan(rec[:, :want_k + 1]).any() and np.isnan(rec[:, want_k + 1:]).all()


def test_a_model_changed_after_its_handle_gets_a_new_copy(dyn):
    """A handle is a copy of the model as it was: the same object changed in place (a link
    made heavier) gets a new copy, which is the changed model's, and the old one is not."""
    model = _model("mrm3")
    first = dyn.model(model)
    assert dyn.model(model) == first                        # unchanged: the same copy
    inertia = model.inertias[2]
    model.inertias[2] = pin.Inertia(inertia.mass * 1.5, inertia.lever, inertia.inertia * 1.5)
    second = dyn.model(model)
    assert second and second != first
    assert dyn.differs(model, second) == ""
    assert dyn.differs(model, first).startswith("aba at q=")


def _build_in(cache: str, out) -> None:
    import os

    os.environ["MRM_CACHE_DIR"] = cache
    try:
        out.put(str(pin_shim.build()))
    except Exception as e:                       # noqa: BLE001 — reported to the test
        out.put(f"error: {e}")


def test_processes_building_at_once_compile_once(tmp_path, monkeypatch):
    """A sweep's workers start together: the first to build holds the cache folder's lock,
    the others wait and take its library (a stand-in compiler counts the compilations)."""
    import multiprocessing as mp
    import stat

    log = tmp_path / "compilations"
    fake = tmp_path / "fake-c++"
    fake.write_text("#!/bin/sh\n"
                    "if [ \"$1\" = --version ]; then echo fake 1.0; exit 0; fi\n"
                    f"echo run >> {log}\n"
                    "sleep 1\n"
                    "for a in \"$@\"; do case $prev in -o) : > \"$a\";; esac; prev=$a; done\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("CXX", str(fake))
    ctx = mp.get_context("fork")
    out = ctx.Queue()
    procs = [ctx.Process(target=_build_in, args=(str(tmp_path / "cache"), out))
             for _ in range(3)]
    for p in procs:
        p.start()
    got = [out.get(timeout=60) for _ in procs]
    for p in procs:
        p.join(timeout=60)
    assert len(set(got)) == 1 and got[0].endswith("libmrmpin.so"), got
    assert log.read_text().splitlines() == ["run"]


def test_a_build_that_compiles_an_algorithm_itself_is_refused(tmp_path):
    """``build``'s check (``_linked``): a library defining one of the three algorithms (here a
    stand-in ``pinocchio::aba`` instantiated in it) is refused, so its numbers could not pass
    for ``pin``'s; one that only calls them is taken."""
    import shutil
    import subprocess

    if not (shutil.which("nm") and shutil.which("g++")):
        pytest.skip("needs nm and g++")
    src = tmp_path / "own.cpp"
    src.write_text("namespace pinocchio { template<class T> T aba(T x) { return x; }\n"
                   "template int aba<int>(int); }\n")
    own = tmp_path / "libown.so"
    subprocess.run(["g++", "-shared", "-fPIC", str(src), "-o", str(own)], check=True)
    with pytest.raises(RuntimeError, match="::aba< compiled into the library"):
        pin_shim._linked(own)
    pin_shim._linked(pin_shim.build())                   # the real one: only references
