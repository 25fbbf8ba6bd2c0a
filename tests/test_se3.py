"""SE(3)/SO(3) maps against scipy's rotations and against each other."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from pld_slam.geometry import se3
from pld_slam.geometry.se3 import inverse, se3_exp, se3_left_jacobian, se3_log

vectors = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@given(vectors)
def test_so3_exp_matches_scipy(phi):
    assert np.allclose(se3.so3_exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)


@given(vectors)
def test_so3_log_inverts_exp_up_to_pi(phi):
    angle = np.linalg.norm(phi)
    if angle >= np.pi - 1e-6:
        phi = phi / angle * (2 * np.pi - angle) * -1.0  # same rotation, angle < pi
    R = se3.so3_exp(phi)
    assert np.allclose(se3.so3_exp(se3.so3_log(R)), R, atol=1e-9)


def test_so3_log_near_pi_keeps_the_axis():
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    for angle in (np.pi, np.pi - 1e-6, np.pi - 1e-3):
        phi = se3.so3_log(se3.so3_exp(angle * axis))
        assert np.isclose(np.linalg.norm(phi), angle, atol=1e-6)
        assert np.allclose(se3.so3_exp(phi), se3.so3_exp(angle * axis), atol=1e-9)


@settings(max_examples=50)
@given(vectors, vectors)
def test_se3_log_inverts_exp(rho, phi):
    angle = np.linalg.norm(phi)
    if angle > 3.0:
        phi = phi / angle * 3.0  # keep the angle below pi, where log is unique
    xi = np.concatenate([rho, phi])
    assert np.allclose(se3.se3_log(se3.se3_exp(xi)), xi, atol=1e-8)


def test_se3_exp_of_small_twist_is_first_order():
    xi = np.array([1e-9, -2e-9, 3e-9, 1e-10, 0.0, -1e-10])
    T = se3.se3_exp(xi)
    assert np.allclose(T[:3, 3], xi[:3], atol=1e-15)
    assert np.allclose(T[:3, :3], np.eye(3) + se3.hat(xi[3:]), atol=1e-15)


@given(vectors, vectors)
def test_inverse_composes_to_identity_for_stacks(rho, phi):
    T = se3.make_pose(Rotation.from_rotvec(phi).as_matrix(), rho)
    stack = np.stack([T, np.eye(4), se3.inverse(T)])
    assert np.allclose(se3.inverse(stack) @ stack, np.eye(4), atol=1e-12)


def test_rotation_angle_and_transform_points():
    R = Rotation.from_rotvec([0.0, 0.3, 0.0]).as_matrix()
    assert se3.rotation_angle(R) == pytest.approx(0.3)
    T = se3.make_pose(R, [1.0, 2.0, 3.0])
    p = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    expected = (T @ np.c_[p, np.ones(2)].T).T[:, :3]
    assert np.allclose(se3.transform_points(T, p), expected)


@pytest.mark.parametrize("seed", range(3))
def test_se3_left_jacobian_matches_central_differences(seed):
    # se3_exp(xi + h) @ se3_exp(xi - h)^-1 = se3_exp(2 J h) to second order; a larger step than
    # the residual tests' because se3_log loses digits on the tiny composed motion.
    h = 1e-4
    rng = np.random.default_rng(seed)
    for xi in (rng.normal(0.0, 1.0, 6), np.concatenate([rng.normal(0.0, 1.0, 3), rng.normal(0.0, 1e-3, 3)])):
        numeric = np.column_stack(
            [
                se3_log(se3_exp(xi + h * axis) @ inverse(se3_exp(xi - h * axis))) / (2.0 * h)
                for axis in np.eye(6)
            ]
        )
        assert np.allclose(numeric, se3_left_jacobian(xi), rtol=0.0, atol=1e-8)


def test_se3_left_jacobian_series_meets_the_closed_form_at_the_switch():
    rho, axis = np.array([0.3, -1.2, 2.0]), np.array([1.0, 2.0, 2.0]) / 3.0
    below = se3_left_jacobian(np.concatenate([rho, (1e-2 - 1e-12) * axis]))
    above = se3_left_jacobian(np.concatenate([rho, (1e-2 + 1e-12) * axis]))
    assert np.allclose(below, above, rtol=0.0, atol=1e-10)


def test_nearest_pose_repairs_a_drifted_rotation_and_keeps_translation():
    rng = np.random.default_rng(4)
    T = se3.se3_exp(rng.normal(size=6))
    drifted = T.copy()
    drifted[:3, :3] += 1e-3 * rng.normal(size=(3, 3))
    repaired = se3.nearest_pose(drifted)
    assert np.allclose(repaired[:3, :3] @ repaired[:3, :3].T, np.eye(3), atol=1e-14)
    assert np.allclose(repaired[:3, :3], T[:3, :3], atol=5e-3)
    assert np.array_equal(repaired[:3, 3], T[:3, 3])
    assert np.allclose(se3.nearest_pose(T), T, atol=1e-14)


def test_se3_left_jacobian_stays_accurate_at_small_angles():
    """Continuous down to phi = 0 (no cancellation in the closed form): within O(|rho| |phi|)."""
    rho, axis = np.array([0.3, -1.2, 2.0]), np.array([1.0, 2.0, 2.0]) / 3.0
    at_zero = se3_left_jacobian(np.concatenate([rho, np.zeros(3)]))
    assert np.allclose(at_zero[:3, 3:], 0.5 * se3.hat(rho))
    for angle in (1e-3, 1e-5, 1e-7):
        xi = np.concatenate([rho, angle * axis])
        assert np.abs(se3_left_jacobian(xi) - at_zero).max() < 2.0 * angle * (1.0 + np.linalg.norm(rho))


def test_stacked_maps_equal_the_maps_of_each_element():
    rng = np.random.default_rng(3)
    twists = np.vstack([rng.normal(0.0, 1.0, (20, 6)), np.zeros((1, 6)), [[1.0, 2.0, 3.0, 1e-9, 0.0, 0.0]],
                        [[0.5, 0.0, 0.0, 0.0, np.pi - 1e-6, 0.0]]])
    poses = se3_exp(twists)
    for twist, pose in zip(twists, poses):
        np.testing.assert_allclose(pose, se3_exp(twist), atol=1e-14)
    np.testing.assert_allclose(se3_log(poses), [se3_log(pose) for pose in poses], atol=1e-12)
    np.testing.assert_allclose(se3_left_jacobian(twists), [se3_left_jacobian(t) for t in twists], atol=1e-14)
    np.testing.assert_allclose(se3_exp(se3_log(poses)), poses, atol=1e-9)


def test_adjoint_moves_a_twist_between_frames():
    rng = np.random.default_rng(4)
    T = se3_exp(rng.normal(0.0, 1.0, 6))
    xi = rng.normal(0.0, 0.5, 6)
    np.testing.assert_allclose(T @ se3_exp(xi) @ inverse(T), se3_exp(se3.se3_adjoint(T) @ xi), atol=1e-12)


def test_motion_size_is_the_translation_length_and_the_rotation_angle_in_degrees():
    T = se3.make_pose(se3.so3_exp(np.array([0.0, 0.0, np.radians(30.0)])), np.array([3.0, 4.0, 0.0]))
    metres, degrees = se3.motion_size(T)
    assert np.isclose(metres, 5.0) and np.isclose(degrees, 30.0)
    assert se3.motion_size(inverse(T))[1] == pytest.approx(30.0)


def test_interpolate_poses_is_exact_for_constant_velocities_and_extrapolates_at_the_ends():
    # Constant linear velocity (world) and angular velocity (body): what the interpolation
    # assumes. The start orientation makes the rotations' order matter.
    w, v, start = np.array([0.1, -0.3, 0.2]), np.array([1.0, 0.5, -2.0]), se3.so3_exp(np.array([0.4, 1.1, -0.7]))

    def pose(t: float) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = start @ se3.so3_exp(w * t), v * t
        return T

    times = np.array([0.0, 0.1, 0.25, 0.3])
    at = np.array([-0.02, 0.0, 0.05, 0.2, 0.3, 0.33])
    interpolated = se3.interpolate_poses(times, np.array([pose(t) for t in times]), at)
    np.testing.assert_allclose(interpolated, [pose(t) for t in at], atol=1e-12)


def test_interpolate_poses_needs_two_samples():
    with pytest.raises(ValueError, match="two samples"):
        se3.interpolate_poses(np.array([0.0]), np.eye(4)[None], np.array([0.0]))
