"""Segment directions, their differences (oriented and modulo pi), midpoints."""

import numpy as np

from pld_slam.geometry.segments import (
    oriented_angle_differences,
    segment_directions,
    segment_midpoints,
    unoriented_angle_differences,
)


def test_segment_directions_are_oriented_from_start_to_end():
    segments = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0], [0, 1, 0, 0]], dtype=float)
    np.testing.assert_allclose(segment_directions(segments), [0.0, np.pi / 2, np.pi, -np.pi / 2])


def test_angle_differences_wrap_around_to_at_most_pi():
    a = np.array([np.pi - 0.1, -np.pi + 0.05, 0.0, 0.0, 3.0, 0.3])
    b = np.array([-np.pi + 0.1, np.pi - 0.05, 2.0 * np.pi, np.pi, -3.0, -0.3])
    expected = np.array([0.2, 0.1, 0.0, np.pi, 2.0 * np.pi - 6.0, 0.6])
    np.testing.assert_allclose(oriented_angle_differences(a, b), expected, atol=1e-12)
    np.testing.assert_allclose(oriented_angle_differences(b, a), expected, atol=1e-12)


def test_unoriented_differences_ignore_the_orientation():
    a = np.array([0.1, 0.1, 3.0])
    b = np.array([0.1 + np.pi, -0.1, 0.0])
    np.testing.assert_allclose(unoriented_angle_differences(a, b), [0.0, 0.2, np.pi - 3.0], atol=1e-12)


def test_midpoints():
    np.testing.assert_allclose(segment_midpoints(np.array([[0.0, 2.0, 4.0, 6.0]])), [[2.0, 4.0]])
