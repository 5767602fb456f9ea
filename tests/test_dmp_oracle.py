"""Oracle for master/dmp.py (issue 17 item 6): movement_primitives' DMP, like with like.

The reference is dfki-ric ``movement_primitives`` 0.9.1 (BSD-3-Clause; Fabisch et al.,
https://github.com/dfki-ric/movement_primitives), files ``movement_primitives/dmp/_dmp.py``
(``DMP``, ``determine_forces``, ``dmp_imitate``, ``ridge_regression``, ``dmp_step_euler``,
``dmp_open_loop``), ``_forcing_term.py`` (``ForcingTerm``) and ``_canonical_system.py``
(``canonical_system_alpha``, ``phase``), after Ijspeert et al. 2013, Neural Computation
25(2) eqs. 2.1–2.3. The package is not a dependency: on PyPI it is a source distribution that
compiles a Cython extension, declares no runtime requirements (not even numpy), and its
``movement_primitives.dmp`` package does not import without ``pytransform3d`` (which it
does not declare). Its equations are therefore transcribed below (``mp_*``, numpy only), and
:func:`test_transcription_equals_the_installed_library` checks the transcription against the
library itself wherever it is installed (skipped elsewhere).

Where the formulations differ (docs/trajectories.md §4.5 has the table), the test configures
our code to the library's conventions, or uses our functions in a small adapter:

- phase: theirs ``z = exp(−α_z t/T)`` with ``α_z = −ln 0.01``; ours with ``α_s = −ln 0.01``
  and ``τ = T``;
- basis widths: theirs ``h_i`` with value ``overlap`` (0.8) *at the next centre*; ours σ_i
  with value ``overlap`` *halfway* there: our ``overlap = 0.8 ** (1/4)``, ``h = 1/(2σ²)``;
- forcing: theirs ``z Σψ_i w_i / Σψ_i`` without the ``(g − x0)`` factor: ours with
  ``goal_scaling = False`` on every DOF;
- learning: theirs fits all weights at once (least squares, ``pinv``) to finite-difference
  targets; ours is per-basis LWR on targets that invert the recurrence. Compared: the targets
  and regression are theirs, the design matrix is built from our basis and our phase;
- rollout: both are semi-implicit Euler (velocity first, then position with the new
  velocity), but theirs evaluates the forcing at the phase of the *end* of the step; the
  adapter steps our :meth:`Dmp.step` with that phase.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from mrm_cosim.master.dmp import learn_dmp

TOL = 1e-9
ALPHA_Y, BETA_Y = 25.0, 6.25           # movement_primitives' defaults
MP_OVERLAP = 0.8                       # ForcingTerm overlap set by DMP._init_forcing_term
ALPHA_Z = -math.log(0.01)              # canonical_system_alpha(0.01, T, 0)
N_WEIGHTS = 10
DT = 1.0 / 128                         # exact in binary: one Euler sub-step per step
EXECUTION_TIME = 1.5


def shared_example():
    """Two DOF, 1.5 s at 1/128 s: a minimum-jerk move and a curve with a wiggle."""
    T = np.arange(0.0, EXECUTION_TIME + DT, DT)
    u = T / EXECUTION_TIME
    Y = np.column_stack([0.2 + 0.8 * (10 * u**3 - 15 * u**4 + 6 * u**5),
                         -0.3 + 0.5 * u**2 + 0.1 * np.sin(3 * u)])
    return T, Y


# --- movement_primitives 0.9.1, transcribed ------------------------------------------------
def mp_phase(t, goal_t, start_t=0.0):
    """_canonical_system.phase."""
    return np.exp(-ALPHA_Z * (t - start_t) / (goal_t - start_t))


def mp_rbfs(goal_t, start_t=0.0):
    """ForcingTerm._init_rbfs: centres at the phase of equally spaced times, h_i such that
    the RBF at c_i has value ``overlap`` at c_{i+1}; the last copies the one before."""
    centers, widths = np.empty(N_WEIGHTS), np.empty(N_WEIGHTS)
    step = (goal_t - start_t) / (N_WEIGHTS - 1)
    centers[0] = mp_phase(start_t, goal_t, start_t)
    for i in range(1, N_WEIGHTS):
        centers[i] = mp_phase(i * step, goal_t, start_t)
        widths[i - 1] = -math.log(MP_OVERLAP) / (centers[i] - centers[i - 1]) ** 2
    widths[-1] = widths[-2]
    return centers, widths


def mp_activations(z, centers, widths):
    """ForcingTerm._activations: normalized RBFs, shape (n_weights, n_steps)."""
    z = np.atleast_2d(z)
    act = np.exp(-widths[:, None] * (z - centers[:, None]) ** 2)
    return act / act.sum(axis=0)


def mp_forcing(z, weights, centers, widths):
    """ForcingTerm.forcing_term: shape (n_dims, n_steps)."""
    z = np.atleast_1d(z)
    return z[None, :] * weights.dot(mp_activations(z, centers, widths))


def mp_determine_forces(T, Y):
    """determine_forces without final velocity or smooth scaling: np.gradient derivatives."""
    DT_ = np.gradient(T)
    Yd = np.empty_like(Y)
    for d in range(Y.shape[1]):
        Yd[:, d] = np.gradient(Y[:, d]) / DT_
    Yd[-1, :] = 0.0
    Ydd = np.empty_like(Y)
    for d in range(Y.shape[1]):
        Ydd[:, d] = np.gradient(Yd[:, d]) / DT_
    Ydd[-1, :] = 0.0
    tau = T[-1] - T[0]
    g = Y[-1]
    F = np.empty_like(Y)
    for k in range(len(T)):
        F[k] = tau**2 * Ydd[k] - ALPHA_Y * (BETA_Y * (g - Y[k]) - Yd[k] * tau)
    return F


def mp_ridge(X, F, lam=0.0):
    """ridge_regression: pinv(X Xᵀ + λI) X F, transposed to (n_dims, n_weights)."""
    return np.linalg.pinv(X.dot(X.T) + lam * np.eye(X.shape[0])).dot(X).dot(F).T


def mp_imitate(T, Y):
    """dmp_imitate: weights (n_dims, n_weights), centres, widths h."""
    centers, widths = mp_rbfs(T[-1], T[0])
    Z = mp_phase(T, T[-1], T[0])
    X = Z[None, :] * mp_activations(Z, centers, widths)
    return mp_ridge(X, mp_determine_forces(T, Y)), centers, widths


def mp_open_loop_euler(T_exec, dt, y0, g, weights, centers, widths):
    """dmp_open_loop with dmp_step_euler (int_dt = dt, no coupling, p_gain 0)."""
    y, yd = y0.copy(), np.zeros_like(y0)
    T = np.arange(0.0, T_exec + dt, dt)
    out = np.empty((len(T), len(y0)))
    out[0] = y
    for i in range(1, len(T)):
        current_t = T[i - 1]
        while current_t < T[i]:
            h = dt if T[i] - current_t >= dt else T[i] - current_t
            current_t += h
            z = mp_phase(current_t, T_exec)
            f = mp_forcing(z, weights, centers, widths)[:, 0]
            ydd = (ALPHA_Y * (BETA_Y * (g - y) - T_exec * yd) + f) / T_exec**2
            yd = yd + h * ydd
            y = y + h * yd
        out[i] = y
    return T, out


# --- our side, configured to their conventions ----------------------------------------------
def ours_learned(T, Y, overlap=MP_OVERLAP ** 0.25):
    return learn_dmp(Y, DT, N_WEIGHTS, alpha=ALPHA_Y, beta=BETA_Y, alpha_s=ALPHA_Z,
                     overlap=overlap, tau=T[-1] - T[0])


def ours_weights(T, Y):
    """Their targets and regression over the design matrix of our basis and our phase."""
    dmp = ours_learned(T, Y)
    s = dmp.rollout(DT).s                                   # our phase recurrence
    psi = dmp.basis(s)                                      # our Gaussians, (n_steps, n_basis)
    X = (s[:, None] * psi / psi.sum(axis=1, keepdims=True)).T
    return mp_ridge(X, mp_determine_forces(T, Y))


def ours_rollout_their_way(dmp, dt):
    """Our Dmp.step, fed the phase at the end of each step (their Euler's convention)."""
    s = dmp.rollout(dt).s
    x, v = dmp.x0.copy(), dmp.tau * dmp.xd0
    out = [x]
    for k in range(len(s) - 1):
        x, v, _ = dmp.step(x, v, s[k + 1], dt)
        out.append(x)
    return np.array(out)


def their_weights_in_our_dmp(T, Y):
    W, _, _ = mp_imitate(T, Y)
    dmp = ours_learned(T, Y)
    return replace(dmp, weights=W, goal_scaling=np.zeros(dmp.n_dof, dtype=bool))


# --- the comparisons -------------------------------------------------------------------------
def test_basis_placement_and_widths_agree():
    T, Y = shared_example()
    dmp = ours_learned(T, Y)
    _, centers, h = mp_imitate(T, Y)
    np.testing.assert_allclose(dmp.centers, centers, rtol=TOL, atol=0)
    np.testing.assert_allclose(1.0 / (2.0 * dmp.widths**2), h, rtol=TOL, atol=0)
    # the phase: our recurrence against their closed form
    np.testing.assert_allclose(dmp.rollout(DT).s, mp_phase(T, T[-1]), rtol=TOL, atol=0)


def test_weights_agree():
    T, Y = shared_example()
    W_theirs, _, _ = mp_imitate(T, Y)
    W_ours = ours_weights(T, Y)
    scale = np.abs(W_theirs).max()                 # ~6e3: the LS weights of wide RBFs
    np.testing.assert_allclose(W_ours, W_theirs, rtol=0, atol=TOL * scale)


def test_forcing_term_agrees():
    T, Y = shared_example()
    dmp = their_weights_in_our_dmp(T, Y)
    W, centers, h = mp_imitate(T, Y)
    z = mp_phase(T, T[-1])
    ours = dmp.forcing(z)                                       # (n_steps, n_dof)
    theirs = mp_forcing(z, W, centers, h).T
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=TOL * np.abs(theirs).max())


def test_rollout_agrees():
    T, Y = shared_example()
    dmp = their_weights_in_our_dmp(T, Y)
    W, centers, h = mp_imitate(T, Y)
    _, theirs = mp_open_loop_euler(T[-1], DT, Y[0], Y[-1], W, centers, h)
    ours = ours_rollout_their_way(dmp, DT)
    assert ours.shape == theirs.shape == Y.shape
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=TOL)


def test_the_oracle_sees_each_convention():
    """Each mapped convention matters far beyond the tolerance: left unmapped, it fails."""
    T, Y = shared_example()
    dmp = their_weights_in_our_dmp(T, Y)
    W, centers, h = mp_imitate(T, Y)
    _, theirs = mp_open_loop_euler(T[-1], DT, Y[0], Y[-1], W, centers, h)
    native = dmp.rollout(DT).x                      # our phase at the start of the step
    assert np.abs(native - theirs).max() > 1e3 * TOL
    scaled = replace(dmp, goal_scaling=np.ones(dmp.n_dof, dtype=bool))   # (g − x0) factor
    assert np.abs(ours_rollout_their_way(scaled, DT) - theirs).max() > 1e3 * TOL
    unmapped = ours_learned(T, Y, overlap=MP_OVERLAP)          # overlap at half the spacing
    assert np.abs(1.0 / (2.0 * unmapped.widths**2) / h - 1.0).max() > 0.1


def test_transcription_equals_the_installed_library():
    """The mp_* transcription against movement_primitives itself (when it is installed)."""
    mp_dmp = pytest.importorskip("movement_primitives.dmp")
    T, Y = shared_example()
    W, centers, h = mp_imitate(T, Y)
    ref = mp_dmp.DMP(n_dims=2, execution_time=T[-1], dt=DT, n_weights_per_dim=N_WEIGHTS,
                     int_dt=DT)
    ref.imitate(T, Y)
    np.testing.assert_allclose(ref.forcing_term.centers, centers, rtol=1e-15)
    np.testing.assert_allclose(ref.forcing_term.widths, h, rtol=1e-15)
    np.testing.assert_allclose(ref.forcing_term.weights_, W, rtol=0,
                               atol=1e-12 * np.abs(W).max())
    T_ref, Y_ref = ref.open_loop(step_function="euler")
    _, Y_mp = mp_open_loop_euler(T[-1], DT, Y[0], Y[-1], W, centers, h)
    np.testing.assert_array_equal(T_ref, T)
    np.testing.assert_allclose(Y_ref, Y_mp, rtol=0, atol=1e-12)
