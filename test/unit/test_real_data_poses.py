"""Poses of real trackers (rotation blocks orthonormal only to a few 1e-4) are repaired, not refused;
matrices that are no rotation at all still are (issue 34, item 2)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.perception.depth_camera import (
    ROTATION_TOLERANCE,
    Intrinsics,
    check_pose,
    nearest_rotation,
)

SCENES = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd" / "7scenes_redkitchen"


def rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_of(rot: np.ndarray, translation=(0.1, -0.2, 0.3)) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = translation
    return pose


def test_the_tolerance_is_at_least_the_issues():
    assert ROTATION_TOLERANCE >= 1e-3


def test_polar_factor_of_a_scaled_rotation_is_the_rotation():
    # R diag(1+e, 1-e, 1) = U S V^T with U = R, S = diag(1+e, 1-e, 1), V = I: the polar factor is R
    rot = rot_z(30.0)
    stretched = rot @ np.diag([1.0004, 0.9996, 1.0])
    np.testing.assert_allclose(nearest_rotation(stretched), rot, atol=1e-14)


def test_polar_factor_removes_a_symmetric_error():
    # R (I + S), S symmetric: polar factor R exactly (I + S is the positive-definite factor)
    rot = rot_z(-75.0) @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    sym = np.array([[2e-4, 1e-4, -3e-4], [1e-4, -1e-4, 2e-4], [-3e-4, 2e-4, 4e-4]])
    np.testing.assert_allclose(nearest_rotation(rot @ (np.eye(3) + sym)), rot, atol=1e-14)


def test_near_orthonormal_pose_is_repaired_and_keeps_its_translation():
    rot = rot_z(30.0)
    # the size of the error the 7-Scenes files carry (their rotations are orthonormal to 4e-4)
    noisy = rot + np.array([[4e-4, 0.0, -1e-4], [0.0, -2e-4, 3e-4], [1e-4, 0.0, 2e-4]])
    assert np.abs(noisy @ noisy.T - np.eye(3)).max() > 1e-5  # the check of before refused it
    fixed = check_pose(pose_of(noisy), "pose")
    r = fixed[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(r, rot, atol=5e-4)  # moved by no more than the error itself
    np.testing.assert_array_equal(fixed[:3, 3], [0.1, -0.2, 0.3])
    np.testing.assert_array_equal(fixed[3], [0.0, 0.0, 0.0, 1.0])


def test_exact_rotation_is_returned_bit_for_bit():
    pose = pose_of(rot_z(17.0))
    np.testing.assert_array_equal(check_pose(pose), pose)
    np.testing.assert_array_equal(check_pose(check_pose(pose)), pose)


def test_input_is_not_modified():
    noisy = pose_of(rot_z(10.0) @ np.diag([1.001, 1.0, 1.0]))
    before = noisy.copy()
    check_pose(noisy)
    np.testing.assert_array_equal(noisy, before)


@pytest.mark.parametrize(
    ("matrix", "reason"),
    [
        (2.0 * np.eye(3), "max |R R^T - I| = 3 exceeds the tolerance"),
        (np.diag([1.0, 1.0, 1.1]), "max |R R^T - I| = 0.21 exceeds"),
        (np.array([[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "a scaled or sheared matrix"),
        (np.diag([1.0, 1.0, -1.0]), "a reflection (determinant -1)"),
        (np.zeros((3, 3)), "not a rotation"),
    ],
)
def test_grossly_wrong_rotations_are_refused_with_the_reason(matrix, reason):
    with pytest.raises(ValueError, match="pose_world_from_optical: ") as info:
        check_pose(pose_of(matrix), "pose_world_from_optical")
    assert reason in str(info.value)


def test_nearest_rotation_refuses_a_reflection():
    with pytest.raises(ValueError, match="determinant -1 is not positive"):
        nearest_rotation(np.diag([1.0, -1.0, 1.0]))


def test_other_checks_are_kept():
    with pytest.raises(ValueError, match="expected a 4x4 matrix"):
        check_pose(np.eye(3))
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN or infinite"):
        check_pose(bad)
    bad = np.eye(4)
    bad[3, 0] = 0.5
    with pytest.raises(ValueError, match="last row"):
        check_pose(bad)


def test_integrator_fuses_a_near_orthonormal_pose_as_its_repair():
    from nbv_prob_cnn.perception import TsdfIntegrator

    intrinsics = Intrinsics.from_hfov(32, 24, 60.0)
    depth = np.full(intrinsics.shape, 0.5, dtype=np.float32)
    # camera at the box centre looking along +x (optical z = world x)
    rot = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    noisy = pose_of(rot @ np.diag([1.0003, 0.9998, 1.0]) + 1e-4, (0.05, 0.32, 0.32))
    grids = []
    for pose in (noisy, check_pose(noisy)):
        integrator = TsdfIntegrator((0.0, 0.0, 0.0), (64, 64, 64), 0.01)
        used = integrator.integrate(depth, intrinsics, pose)
        np.testing.assert_allclose(used, check_pose(noisy), atol=0)
        grids.append(integrator.ternary())
    np.testing.assert_array_equal(grids[0], grids[1])
    assert np.count_nonzero(grids[0] == 1) > 0


@pytest.mark.skipif(not SCENES.is_dir(), reason=f"the shared 7-Scenes recording is absent ({SCENES})")
def test_every_7scenes_pose_is_accepted():
    files = sorted(SCENES.glob("frame-*.pose.txt"))
    assert len(files) == 200
    worst = 0.0
    for path in files:
        raw = np.loadtxt(path)
        worst = max(worst, float(np.abs(raw[:3, :3] @ raw[:3, :3].T - np.eye(3)).max()))
        fixed = check_pose(raw, str(path))
        assert np.abs(fixed[:3, :3] - raw[:3, :3]).max() < 1e-3
    assert 1e-5 < worst < ROTATION_TOLERANCE  # refused before, repaired now
