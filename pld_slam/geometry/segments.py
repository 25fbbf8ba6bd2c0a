"""Image line segments as plain arrays: directions, direction differences, midpoints.

A segment is ``(u_s, v_s, u_e, v_e)`` [px]: a row of an (M, 4) array. LSD orients each
segment by its gradient (dark on one side), so the direction from start to end is
meaningful: the same edge seen again keeps its orientation.
"""

import numpy as np


def segment_directions(segments: np.ndarray) -> np.ndarray:
    """Oriented direction (M,) [rad, -pi..pi] from start to end of segments (M, 4), from the +u axis."""
    return np.arctan2(segments[:, 3] - segments[:, 1], segments[:, 2] - segments[:, 0])


def oriented_angle_differences(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``|a - b|`` of oriented angles [rad] wrapped to [0, pi] (broadcasting)."""
    return np.abs((a - b + np.pi) % (2.0 * np.pi) - np.pi)


def unoriented_angle_differences(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``|a - b|`` of line angles [rad] modulo pi, in [0, pi/2] (broadcasting)."""
    change = np.mod(a - b, np.pi)
    return np.minimum(change, np.pi - change)


def segment_midpoints(segments: np.ndarray) -> np.ndarray:
    """Midpoints (M, 2) [px] of segments (M, 4)."""
    return 0.5 * (segments[:, :2] + segments[:, 2:])
