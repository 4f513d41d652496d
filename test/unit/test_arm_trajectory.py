"""Joint trajectories (no ROS): time parameterisation within limits, and the checks a
joint_trajectory_controller makes, against hand-worked cases."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.arm.trajectory import (
    INVALID_GOAL,
    INVALID_JOINTS,
    TrajectoryError,
    check_trajectory,
    time_parameterise,
    tolerance_violation,
)

pytest.importorskip("ruckig")


def test_one_joint_takes_the_time_optimal_jerk_limited_duration():
    """Rest to rest over d = 2 rad with v = 1, a = 2, j = 20: the profile reaches both the
    acceleration and the velocity limit, so T = d/v + v/a + a/j = 2 + 0.5 + 0.1 = 2.6 s."""
    path = time_parameterise(np.array([0.0]), np.array([2.0]), [1.0], [2.0], [20.0], dt=0.01)
    assert path.duration == pytest.approx(2.6, abs=1e-9)
    assert path.positions[0, 0] == 0.0 and path.positions[-1, 0] == 2.0
    np.testing.assert_allclose(path.velocities[[0, -1]], 0.0, atol=1e-12)
    # the middle of the cruise is at the velocity limit: position at t = 1.3 s is d / 2 by symmetry
    k = int(np.argmin(np.abs(path.times - 1.3)))
    assert path.positions[k, 0] == pytest.approx(1.0, abs=1e-9)
    assert path.velocities[k, 0] == pytest.approx(1.0, abs=1e-9)


def test_several_joints_follow_the_straight_line_within_every_limit():
    rng = np.random.default_rng(7)
    start, goal = rng.uniform(-2, 2, 6), rng.uniform(-2, 2, 6)
    vmax, amax, jmax = rng.uniform(0.5, 2.0, 6), rng.uniform(1.0, 3.0, 6), rng.uniform(5.0, 30.0, 6)
    path = time_parameterise(start, goal, vmax, amax, jmax, dt=0.005)
    np.testing.assert_array_equal(path.positions[-1], goal)
    assert np.all(np.abs(path.velocities) <= vmax * (1 + 1e-9))
    assert np.all(np.abs(path.accelerations) <= amax * (1 + 1e-9))
    # finite differences of the sampled positions stay within the limits too
    chord = np.abs(np.diff(path.positions, axis=0)) / np.diff(path.times)[:, None]
    assert np.all(chord <= vmax * (1 + 1e-6))
    # every sample lies on the segment start → goal (phase synchronisation)
    s = (path.positions - start) @ (goal - start) / np.dot(goal - start, goal - start)
    np.testing.assert_allclose(path.positions, start + s[:, None] * (goal - start), atol=1e-9)
    assert np.all(np.diff(s) >= -1e-12) and s[0] == pytest.approx(0.0) and s[-1] == pytest.approx(1.0)
    # no faster than the slowest joint allows at its velocity limit alone
    assert path.duration >= float(np.max(np.abs(goal - start) / vmax))


def test_a_zero_move_and_bad_limits():
    path = time_parameterise(np.ones(3), np.ones(3), 1.0, 1.0, 1.0)
    assert path.duration == 0.0 and path.positions.shape == (1, 3)
    with pytest.raises(ValueError, match="must be positive"):
        time_parameterise(np.zeros(2), np.ones(2), [1.0, 0.0], 1.0, 1.0)
    with pytest.raises(ValueError, match="finite"):
        time_parameterise(np.zeros(2), np.array([1.0, np.nan]), 1.0, 1.0, 1.0)


LIMITS = {"lower": {"a": -1.0, "b": -1.0}, "upper": {"a": 1.0, "b": 1.0}, "max_velocity": {"a": 1.0, "b": 0.5}}
START = {"a": 0.0, "b": 0.0}


def check(names, times, positions):
    check_trajectory(names, ["a", "b"], times, positions, start=START, **LIMITS)


def test_the_controller_checks_joints_limits_times_and_speeds():
    check(["b", "a"], [1.0, 2.0], [[0.5, 0.5], [0.0, 1.0]])  # any order; b at 0.5 rad/s, a at 0.5 rad/s
    cases = [
        (["a", "c"], [1.0], [[0.0, 0.0]], INVALID_JOINTS, r"unknown \['c'\], missing \['b'\]"),
        (["a"], [1.0], [[0.0]], INVALID_JOINTS, r"missing \['b'\]"),
        (["a", "a"], [1.0], [[0.0, 0.0]], INVALID_JOINTS, r"duplicate \['a'\]"),
        (["a", "b"], [], [], INVALID_GOAL, "at least one"),
        (["a", "b"], [1.0, 1.0], [[0.0, 0.0], [0.1, 0.1]], INVALID_GOAL, "strictly increasing"),
        (["a", "b"], [1.0], [[1.2, 0.0]], INVALID_GOAL, r"outside the joint limits for \['a'\]"),
        (["a", "b"], [1.0], [[0.0, np.inf]], INVALID_GOAL, "non-finite"),
        # b moves 0.6 rad in 1 s from the start: over its 0.5 rad/s
        (["a", "b"], [1.0], [[0.0, 0.6]], INVALID_GOAL, r"joint 'b' would move at 0.600, over its velocity limit"),
    ]
    for names, times, positions, code, reason in cases:
        with pytest.raises(TrajectoryError, match=reason) as error:
            check(names, times, positions)
        assert error.value.code == code


def test_tolerance_violation_names_the_joint():
    names = ["a", "b"]
    assert tolerance_violation(names, np.array([0.0, 0.0]), np.array([0.05, 0.2]), {"a": 0.1, "b": 0.0}) == ""
    text = tolerance_violation(names, np.array([0.0, 0.0]), np.array([0.05, 0.2]), {"a": 0.1, "b": 0.1})
    assert text.startswith("joint 'b' is 0.2000 from its setpoint")
