"""Quadrature incremental encoder on the motor shaft, as the FPGA's 50 MHz logic sees it.

Each joint's motor carries a 2000-line encoder (MRM paper Table 1); with ×4 quadrature decoding
and the gear ratio of 100 that is 800,000 counts per joint revolution. Conventions (used by the
plant, the HDL encoder interface and every test):

* Count: ``c = floor(q · K)`` with ``K = counts_per_rev / (2π)`` counts/rad computed once as a
  float64 (:func:`counts_per_rad`), ``q`` the joint angle in rad. ``c = 0`` on ``[0, 1/K)``.
* Lines: the state ``c mod 4`` drives the lines as ``0 → (A, B) = (0, 0)``, ``1 → (1, 0)``,
  ``2 → (1, 1)``, ``3 → (0, 1)``: Gray code, A leads B when ``q`` increases.
* Clock: the plant advances in steps of ``dt`` (10 µs); the FPGA samples the lines every
  ``cycle`` (20 ns, 50 MHz), so ``dt / cycle`` (500) cycles per step. Cycle ``k = 0 … K−1`` of
  a step starting at ``t0`` sees the lines for the angle at ``t0 + (k + 1) · cycle``; the last
  cycle of a step therefore sees the plant's end-of-step count. Inside the step the angle is
  the integrator's own motion, ``q(s) = q0 + v0 s + ½ a s²`` with the step's constant
  acceleration ``a = (v1 − v0) / dt`` (which ends exactly at ``q1`` up to rounding; the last
  sample uses ``q1`` itself).
* Legality: a real decoder needs at most one line change per sampled cycle, i.e. a count step of
  at most 1 between consecutive cycles. That holds below ``1 / (cycle · K)`` = 392.7 rad/s at
  the joint, 65× the FHA-C's maximum speed of 6.07 rad/s (≈ 773,000 counts/s at most, one count
  every ≈ 65 cycles). Faster motion raises :class:`EncoderOverspeed` rather than producing an
  illegal line sequence.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["CYCLE", "counts_per_rad", "joint_counts", "quadrature_levels", "EncoderCycles",
           "EncoderOverspeed", "cycle_counts", "count_changes", "count_changes_lists",
           "cycle_counts_sampled",
           "decode_quadrature", "max_legal_speed"]

CYCLE = 20e-9
"""FPGA clock period, s (50 MHz)."""


class EncoderOverspeed(RuntimeError):
    """The encoder moved more than one count in one FPGA cycle (lines would be illegal)."""


class EncoderCycles(NamedTuple):
    """Encoder outputs for each FPGA cycle of one plant step.

    Attributes
    ----------
    counts : ndarray of int64, shape (cycles, n)
        Exact count seen in each cycle.
    a, b : ndarray of uint8, shape (cycles, n)
        Line levels (0/1) of channels A and B in each cycle.
    """

    counts: np.ndarray
    a: np.ndarray
    b: np.ndarray


def counts_per_rad(counts_per_rev) -> np.ndarray:
    """Counts per radian of joint angle, float64, ``counts_per_rev / (2π)``, shape like input."""
    return np.asarray(counts_per_rev, dtype=float) / (2.0 * math.pi)


def joint_counts(q, k) -> np.ndarray:
    """Encoder count ``floor(q · k)`` as int64.

    Parameters
    ----------
    q : array_like, shape (..., n), rad
    k : array_like, shape (n,), counts/rad (from :func:`counts_per_rad`)
    """
    return np.floor(np.multiply(q, k)).astype(np.int64)


def quadrature_levels(counts) -> tuple[np.ndarray, np.ndarray]:
    """Line levels ``(A, B)`` (uint8 arrays, same shape) for counts (any integers, also < 0)."""
    phase = (np.asarray(counts, dtype=np.int64) & 3).astype(np.uint8)    # c mod 4
    b = phase >> 1
    a = b ^ (phase & 1)
    return a, b


def max_legal_speed(k, cycle: float = CYCLE) -> np.ndarray:
    """Joint speed (rad/s) at which the count advances one step per FPGA cycle."""
    return 1.0 / (cycle * np.asarray(k, dtype=float))


def cycle_counts(q0, v0, acc, q1, dt: float, cycles: int, k) -> np.ndarray:
    """Counts in every FPGA cycle of one plant step (see the module docstring for timing).

    Row ``m`` is ``floor(q(s_m) · k)`` with ``s_m = (m + 1) · dt / cycles`` and
    ``q(s) = q0 + s · (v0 + 0.5 · acc · s)`` (float64, in that order), except the last row,
    which is ``floor(q1 · k)``. The result is identical to sampling every cycle
    (:func:`cycle_counts_sampled`), but only the cycles where a count can change are evaluated:
    between two samples of a monotonic stretch with equal counts nothing changes, so a joint
    with few changes in the step has them found by bisection (``O(changes · log cycles)``
    evaluations; the few samples around a turning point inside the step are evaluated one by
    one); joints with many changes are sampled every cycle, vectorised.

    Parameters
    ----------
    q0, v0 : ndarray, shape (n,)
        Angle (rad) and velocity (rad/s) at the start of the step.
    acc : ndarray, shape (n,), rad/s²
        Constant acceleration of the step, ``(v1 − v0) / dt``.
    q1 : ndarray, shape (n,), rad
        Angle at the end of the step (the last cycle's sample).
    dt : float, s
    cycles : int
        FPGA cycles per step, ``dt / cycle``.
    k : ndarray, shape (n,), counts/rad

    Returns
    -------
    ndarray of int64, shape (cycles, n)

    Raises
    ------
    EncoderOverspeed
        If the count changes by more than one between two consecutive cycles (or between the
        start of the step and its first cycle).
    """
    q0 = np.asarray(q0, dtype=float)
    c0, changes = count_changes(q0, v0, acc, q1, dt, cycles, k)
    out = np.empty((cycles, c0.size), dtype=np.int64)
    out[:] = c0
    for j, events in enumerate(changes):
        for m, c in events:
            out[m:, j] = c
    return out


def count_changes(q0, v0, acc, q1, dt: float, cycles: int, k) -> tuple[np.ndarray, list]:
    """The cycles of one plant step where each joint's count changes (what
    :func:`cycle_counts` returns, as events: the same evaluations, no per-cycle array for
    joints with few changes).

    Parameters are those of :func:`cycle_counts`.

    Returns
    -------
    c0 : ndarray of int64, shape (n,)
        Count at the start of the step (before cycle 0).
    changes : list of n lists of (int, int)
        Per joint, ``(cycle, new count)`` in increasing cycle order: the count is the new one
        from that cycle on (row ``cycle`` of :func:`cycle_counts` onwards).

    Raises
    ------
    EncoderOverspeed
        As :func:`cycle_counts`.
    """
    q0 = np.asarray(q0, dtype=float)
    c0l, changes = count_changes_lists(q0.tolist(), np.asarray(v0, dtype=float).tolist(),
                                       np.asarray(acc, dtype=float).tolist(),
                                       np.asarray(q1, dtype=float).tolist(), dt, cycles,
                                       np.asarray(k, dtype=float).tolist())
    return np.array(c0l, dtype=np.int64).reshape(q0.shape), changes


def count_changes_lists(q0, v0, acc, q1, dt: float, cycles: int, k) -> tuple[list, list]:
    """:func:`count_changes` on lists of floats (the plant's state), start counts as a list:
    ``floor(q · k)`` in Python floats is numpy's float64 product and floor, bit for bit."""
    floor = math.floor
    n = len(q0)
    c0l = [floor(q0[j] * k[j]) for j in range(n)]
    c1l = [floor(q1[j] * k[j]) for j in range(n)]
    step = dt / cycles
    changes: list = [[] for _ in range(n)]
    dense = []
    for j in range(n):
        turning = acc[j] != 0.0 and 0.0 < -v0[j] / acc[j] < dt
        if c0l[j] == c1l[j] and not turning:
            continue                            # monotonic between equal counts: constant
        if abs(c1l[j] - c0l[j]) > _FEW_CHANGES or (turning and abs(v0[j]) * dt * k[j] > 1.0):
            dense.append(j)                     # many changes: sampling every cycle is cheaper
            continue
        events = _count_changes(q0[j], v0[j], acc[j], c0l[j], c1l[j], step, cycles, k[j],
                                turning)
        prev = c0l[j]
        for m, c in events:
            if abs(c - prev) > 1:
                raise EncoderOverspeed(
                    f"joint {j + 1}: count jumps by {c - prev} in cycle {m}; the joint is "
                    f"faster than the encoder interface allows "
                    f"({float(max_legal_speed(k[j])):.1f} rad/s)")
            prev = c
        changes[j] = events
    if dense:
        idx = np.array(dense)
        sampled = cycle_counts_sampled(np.array(q0)[idx], np.array(v0)[idx], np.array(acc)[idx],
                                       np.array(q1)[idx], dt, cycles, np.array(k)[idx])
        start = np.array(c0l, dtype=np.int64)[idx]
        prev = np.concatenate([start[None, :], sampled[:-1]], axis=0)
        for col, j in enumerate(dense):
            rows = np.flatnonzero(sampled[:, col] != prev[:, col])
            changes[j] = list(zip(rows.tolist(), sampled[rows, col].tolist(), strict=True))
    return c0l, changes


_FEW_CHANGES = 2
"""Joints with at most this many count changes in a step are bisected, others sampled."""


def _count_changes(q0, v0, acc, c_start, c_end, step, cycles, k, turning):
    """Cycles at which one joint's sampled count changes, as ``[(cycle, new count), …]``."""
    half_acc = 0.5 * acc

    def count(m):
        s = (m + 1) * step
        return math.floor((q0 + s * (v0 + half_acc * s)) * k)

    events = []

    def bisect(lo, hi, c_before, c_hi):
        # samples lo..hi are monotonic; c_before is the count just before lo, c_hi at hi
        while c_before != c_hi:
            if lo == hi:
                events.append((hi, c_hi))
                return
            mid = (lo + hi) // 2
            c_mid = count(mid)
            bisect(lo, mid, c_before, c_mid)
            lo, c_before = mid + 1, c_mid

    explicit = {cycles - 1}
    if turning:
        m_turn = int(-v0 / acc / step) - 1          # last sample before the turning point
        explicit.update(m for m in range(m_turn - 1, m_turn + 3) if 0 <= m < cycles)
    prev, lo = c_start, 0
    for e in sorted(explicit):
        if lo <= e - 1:
            c_hi = count(e - 1)
            bisect(lo, e - 1, prev, c_hi)
            prev = c_hi
        c_e = c_end if e == cycles - 1 else count(e)
        if c_e != prev:
            events.append((e, c_e))
        prev, lo = c_e, e + 1
    return events


def cycle_counts_sampled(q0, v0, acc, q1, dt: float, cycles: int, k) -> np.ndarray:
    """Reference for :func:`cycle_counts`: sample every cycle (vectorised), same definition."""
    q0 = np.asarray(q0, dtype=float)
    s = _sample_times(dt, cycles)
    q = q0 + s * (v0 + 0.5 * acc * s)
    q[-1] = q1
    c = joint_counts(q, k)
    steps = np.diff(c, axis=0, prepend=joint_counts(q0, k)[None, :])
    if np.any(np.abs(steps) > 1):
        cyc, joint = np.argwhere(np.abs(steps) > 1)[0]
        raise EncoderOverspeed(f"count jumps by {int(steps[cyc, joint])} in cycle {cyc} "
                               f"(column {joint}); faster than the encoder interface allows "
                               f"({float(max_legal_speed(k)[joint]):.1f} rad/s)")
    return c


_SAMPLE_TIMES: dict[tuple[float, int], np.ndarray] = {}


def _sample_times(dt: float, cycles: int) -> np.ndarray:
    """Sample instants ``(k + 1) · dt / cycles`` inside a step, shape (cycles, 1), cached."""
    key = (dt, cycles)
    s = _SAMPLE_TIMES.get(key)
    if s is None:
        s = (np.arange(1, cycles + 1, dtype=float) * (dt / cycles))[:, None]
        s.flags.writeable = False
        _SAMPLE_TIMES[key] = s
    return s


def decode_quadrature(a, b, count0) -> np.ndarray:
    """Reference ×4 quadrature decoder: counts reconstructed from A/B line samples.

    Parameters
    ----------
    a, b : array_like of 0/1, shape (cycles, n)
        Line levels, one row per sampled cycle.
    count0 : array_like of int, shape (n,)
        Count before the first row; its ``mod 4`` must match the lines it implies.

    Returns
    -------
    ndarray of int64, shape (cycles, n)
        The decoder's count after each row.

    Raises
    ------
    ValueError
        On an illegal transition (both lines changing in one cycle).
    """
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    phase = 2 * b + (a ^ b)                                    # (A, B) → c mod 4
    c0 = np.asarray(count0, dtype=np.int64)
    prev = np.concatenate([(c0 % 4)[None, :], phase[:-1]], axis=0)
    d = (phase - prev) % 4
    if np.any(d == 2):
        cyc, joint = np.argwhere(d == 2)[0]
        raise ValueError(f"illegal quadrature transition on joint {joint + 1} at row {cyc}: "
                         "both lines changed")
    step = np.where(d == 3, -1, d)
    return c0 + np.cumsum(step, axis=0)
