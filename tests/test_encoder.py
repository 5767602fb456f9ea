"""Quadrature encoder: count convention, Gray-code lines, per-cycle interpolation, decoding."""

import math
from decimal import Decimal, getcontext
from fractions import Fraction

import numpy as np
import pytest

from mrm_cosim.models.actuators import ACTUATORS
from mrm_cosim.models.encoder import (
    CYCLE, EncoderOverspeed, count_changes, counts_per_rad, cycle_counts, cycle_counts_sampled,
    decode_quadrature, joint_counts, max_legal_speed, quadrature_levels,
)

K = counts_per_rad(np.array([800_000]))

# 2π to 40 digits, for a reference count that does not share our float rounding.
getcontext().prec = 50
TWO_PI = Decimal("6.283185307179586476925286766559005768394338798750")


def exact_count(q: float) -> tuple[int, float]:
    """floor(q · 800000 / 2π) in exact arithmetic, and the distance to the nearest boundary."""
    x = Decimal(Fraction(q).numerator) / Decimal(Fraction(q).denominator) * 800_000 / TWO_PI
    c = math.floor(x)
    return c, float(min(x - c, c + 1 - x))


def test_counts_follow_floor_convention():
    rng = np.random.default_rng(0)
    q = np.concatenate([rng.uniform(-7.0, 7.0, 3000), [0.0, -0.0, 1e-300, -1e-300, math.pi]])
    got = joint_counts(q[:, None], K)[:, 0]
    for qi, ci in zip(q, got, strict=True):
        ref, margin = exact_count(float(qi))
        if margin > 1e-6:                      # away from a boundary: exact agreement
            assert ci == ref, qi
        else:                                  # on a boundary the float product decides
            assert abs(ci - ref) <= 1
    assert got.dtype == np.int64


def test_papers_example_20000_counts():
    q = 20_000 * 2.0 * math.pi / 800_000                  # 0.15708 rad, the paper's 0.1571
    assert joint_counts(np.array([q + 1e-12]), K)[0] == 20_000
    assert joint_counts(np.array([q - 1e-12]), K)[0] == 19_999
    assert joint_counts(np.array([-1e-12]), K)[0] == -1


def test_lines_are_gray_code_with_a_leading():
    c = np.arange(-9, 10)
    a, b = quadrature_levels(c)
    table = {0: (0, 0), 1: (1, 0), 2: (1, 1), 3: (0, 1)}
    for ci, ai, bi in zip(c, a, b, strict=True):
        assert (ai, bi) == table[int(ci) % 4]
    changes = np.abs(np.diff(a.astype(int))) + np.abs(np.diff(b.astype(int)))
    assert np.all(changes == 1)                            # exactly one line per count
    # counting up from state 0, A rises first: A leads B
    assert (a[9], b[9], a[10], b[10]) == (0, 0, 1, 0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_decoder_reconstructs_random_walk_both_directions(seed):
    rng = np.random.default_rng(seed)
    steps = rng.choice([-1, 0, 1], size=(5000, 3))
    count0 = np.array([0, -123, 987_654])
    counts = count0 + np.cumsum(steps, axis=0)
    a, b = quadrature_levels(counts)
    np.testing.assert_array_equal(decode_quadrature(a, b, count0), counts)


def test_decoder_rejects_double_line_change():
    a, b = quadrature_levels(np.array([[0], [2]]))
    with pytest.raises(ValueError, match="both lines"):
        decode_quadrature(a, b, [0])


def test_cycle_counts_constant_velocity_matches_exact_motion():
    dt, cycles = 1e-5, 500
    k = np.repeat(K, 2)
    q0 = np.array([0.1234, -0.5])
    v0 = np.array([5.9, -6.0])                          # near the actuators' max speed
    acc = np.zeros(2)
    q1 = q0 + v0 * dt
    c = cycle_counts(q0, v0, acc, q1, dt, cycles, k)
    s = np.arange(1, cycles + 1) * CYCLE
    for j in range(2):
        ref = [exact_count(float(q0[j]) + float(v0[j]) * float(si))[0] for si in s]
        # the float motion model and the exact one may differ right at a boundary only
        assert np.sum(c[:, j] != ref) <= 1
    assert np.array_equal(c[-1], joint_counts(q1, k))
    assert np.all(np.abs(np.diff(c, axis=0)) <= 1)


def test_cycle_counts_reversal_inside_a_step_is_legal():
    dt, cycles = 1e-5, 500
    k = K
    q0 = np.array([1.0 / K[0] * 10.5])                   # middle of count 10
    v0 = np.array([0.05])
    acc = np.array([-2.0 * 0.05 / dt])                   # ends at −v0: turns at mid-step
    q1 = q0 + v0 * dt + 0.5 * acc * dt**2
    c = cycle_counts(q0, v0, acc, q1, dt, cycles, k)
    assert np.all(np.abs(np.diff(c[:, 0])) <= 1)
    a, b = quadrature_levels(c)
    np.testing.assert_array_equal(decode_quadrature(a, b, joint_counts(q0, k)), c)


def test_bisection_equals_sampling_every_cycle():
    """The fast per-cycle counts are those of sampling all 500 cycles, bit for bit, for
    motions from rest to 50 rad/s, with and without a turning point, on and off boundaries."""
    rng = np.random.default_rng(4)
    k = np.repeat(K, 6)
    dt = 1e-5
    turning = 0
    for trial in range(600):
        q0 = rng.uniform(-3.0, 3.0, 6)
        if trial % 3 == 0:                                    # start on or next to a boundary
            q0 = np.round(q0 * k) / k + rng.choice([0.0, 1e-15, -1e-15, 1e-12], 6)
        v0 = rng.choice([0.0, 1e-6, 1e-3, 0.3, 1.0, 6.0, 50.0], 6) * rng.choice([-1, 1], 6)
        acc = rng.choice([0.0, 1.0, 1e2, 1e4, 1e6], 6) * rng.choice([-1, 1], 6)
        q1 = q0 + dt * (v0 + 0.5 * acc * dt)
        turning += int(np.sum((acc != 0) & (-v0 / np.where(acc != 0, acc, 1) > 0)
                              & (-v0 / np.where(acc != 0, acc, 1) < dt)))
        fast = cycle_counts(q0, v0, acc, q1, dt, 500, k)
        sampled = cycle_counts_sampled(q0, v0, acc, q1, dt, 500, k)
        np.testing.assert_array_equal(fast, sampled)
        # the change events are exactly the cycles where the sampled count differs
        c0, changes = count_changes(q0, v0, acc, q1, dt, 500, k)
        prev = np.vstack([c0[None, :], sampled[:-1]])
        for j in range(6):
            rows = np.flatnonzero(sampled[:, j] != prev[:, j])
            assert changes[j] == list(zip(rows.tolist(), sampled[rows, j].tolist(),
                                              strict=True)), trial
    assert turning > 50


def test_overspeed_is_reported_not_hidden():
    k = K
    v_max = max_legal_speed(k)[0]
    assert v_max == pytest.approx(1.0 / (CYCLE * 800_000 / (2.0 * math.pi)))
    for fn in (cycle_counts, cycle_counts_sampled, count_changes):
        with pytest.raises(EncoderOverspeed, match="faster than the encoder"):
            fn(np.array([0.0]), np.array([1.5 * v_max]), np.zeros(1),
               np.array([1.5 * v_max * 1e-5]), 1e-5, 500, k)
    # just below the limit is legal: at most one count per cycle
    c = cycle_counts(np.array([0.0]), np.array([0.99 * v_max]), np.zeros(1),
                     np.array([0.99 * v_max * 1e-5]), 1e-5, 500, k)
    assert np.abs(np.diff(c[:, 0])).max() == 1


def test_legal_speed_far_above_actuator_max_speed():
    for spec in ACTUATORS.values():
        k = counts_per_rad(spec.counts_per_rev)
        assert max_legal_speed(k) > 60.0 * spec.max_speed
