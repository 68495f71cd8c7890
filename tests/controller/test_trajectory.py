"""The contract's trajectory: MotoROS' Hermite interpolation, its exact segment bounds, dense sampling."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.controller.trajectory import JointTrajectory, hermite, sample, segment_extrema


def test_hermite_matches_endpoints():
    rng = np.random.default_rng(1)
    for _ in range(200):
        p0, v0, p1, v1 = rng.normal(size=(4, 13))
        T = rng.uniform(0.01, 3.0)
        p, v, _ = hermite(p0, v0, p1, v1, T, 0.0)
        assert np.allclose(p, p0) and np.allclose(v, v0)
        p, v, _ = hermite(p0, v0, p1, v1, T, T)
        assert np.allclose(p, p1) and np.allclose(v, v1)


def test_hermite_formula_and_derivatives():
    p0, v0, p1, v1, T = 0.3, -0.2, 1.1, 0.5, 0.8
    a1 = 6 * (p1 - p0) / T**2 - 2 * (v1 + 2 * v0) / T
    a2 = -12 * (p1 - p0) / T**3 + 6 * (v1 + v0) / T**2
    tau = np.linspace(0, T, 50)
    p, v, a = hermite(p0, v0, p1, v1, T, tau)
    assert np.allclose(p, p0 + v0 * tau + a1 * tau**2 / 2 + a2 * tau**3 / 6)
    h = 1e-6
    pp, _, _ = hermite(p0, v0, p1, v1, T, tau + h)
    pm, _, _ = hermite(p0, v0, p1, v1, T, tau - h)
    assert np.allclose((pp - pm) / (2 * h), v, atol=1e-6)
    assert np.allclose(a, a1 + a2 * tau)


def test_sample_passes_through_points_and_clamps():
    rng = np.random.default_rng(2)
    times = np.cumsum(np.r_[0.0, rng.uniform(0.1, 1.0, 9)])
    pos = rng.normal(size=(10, 3))
    vel = rng.normal(size=(10, 3))
    vel[-1] = 0
    p, v, _ = sample(times, pos, vel, times)
    assert np.allclose(p, pos) and np.allclose(v, vel)
    p, v, a = sample(times, pos, vel, times[-1] + 5.0)
    assert np.allclose(p, pos[-1]) and np.allclose(v, 0) and np.allclose(a, 0)


def test_segment_extrema_bound_dense_samples():
    rng = np.random.default_rng(3)
    for _ in range(100):
        k = rng.integers(2, 8)
        times = np.cumsum(np.r_[0.0, rng.uniform(0.05, 1.0, k - 1)])
        pos = rng.normal(size=(k, 4))
        vel = rng.normal(size=(k, 4))
        pmin, pmax, vmax, amax = segment_extrema(times, pos, vel)
        for s in range(k - 1):
            tau = np.linspace(times[s], times[s + 1], 2001)
            p, v, a = sample(times, pos, vel, tau)
            assert (p.min(axis=0) >= pmin[s] - 1e-9).all() and (p.max(axis=0) <= pmax[s] + 1e-9).all()
            assert (np.abs(v).max(axis=0) <= vmax[s] + 1e-9).all()
            # the acceleration jumps at a point: the end sample belongs to the next segment
            assert (np.abs(a[:-1]).max(axis=0) <= amax[s] + 1e-9).all()
            # and the bounds are tight (reached within the sampling resolution)
            assert np.allclose(p.max(axis=0), pmax[s], atol=1e-3 * (1 + np.abs(pmax[s])))
            assert np.allclose(np.abs(v).max(axis=0), vmax[s], rtol=1e-3, atol=1e-3)


def test_dense_positions_follow_the_hermite_formula_at_most_a_period_apart():
    rng = np.random.default_rng(4)
    times = np.array([0.0, 0.01, 0.5, 1.3])
    pos = rng.normal(size=(4, 3))
    vel = rng.normal(size=(4, 3))
    vel[-1] = 0.0
    period = 0.004
    dense = JointTrajectory(("a", "b", "c"), times, pos, vel).dense_positions(period)
    # the reference: each segment cut into ceil(T / period) equal steps, the formula of the module doc
    expected = [pos[:1]]
    for k in range(3):
        T = times[k + 1] - times[k]
        steps = int(np.ceil(T / period))
        tau = (np.arange(1, steps + 1) / steps * T)[:, None]
        a1 = 6 * (pos[k + 1] - pos[k]) / T**2 - 2 * (vel[k + 1] + 2 * vel[k]) / T
        a2 = -12 * (pos[k + 1] - pos[k]) / T**3 + 6 * (vel[k + 1] + vel[k]) / T**2
        expected.append(pos[k] + vel[k] * tau + a1 * tau**2 / 2 + a2 * tau**3 / 6)
    expected = np.vstack(expected)
    assert dense.shape == expected.shape and len(dense) >= 1 + times[-1] / period
    np.testing.assert_allclose(dense, expected, atol=1e-12)


def test_missing_velocities_are_zero_and_the_duration_is_the_last_time():
    traj = JointTrajectory(("a",), np.array([0.0, 2.5]), np.array([[0.0], [1.0]]))
    assert traj.duration == 2.5
    np.testing.assert_array_equal(traj.point_velocities, np.zeros((2, 1)))
    mid = traj.dense_positions(1.25)[1]
    assert mid[0] == pytest.approx(0.5)  # zero velocities at both ends: a symmetric cubic
