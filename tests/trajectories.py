"""Trajectories with known shape shared by the metric and plot tests."""

import numpy as np
from scipy.spatial.transform import Rotation

from pld_slam.geometry.se3 import make_pose
from pld_slam.trajectory import Trajectory

WORLD_CHANGE = make_pose(
    Rotation.from_euler("xyz", [0.3, -1.0, 2.0]).as_matrix(), [5.0, -3.0, 8.0]
)


def drive(n: int = 200, frame_rate_hz: float = 10.0) -> Trajectory:
    """A 284 m figure-eight drive (whatever ``n``) with yaw, pitch and height changes."""
    s = np.linspace(0.0, 2.0 * np.pi, n)
    positions = np.column_stack([30.0 * np.sin(s), 2.0 * np.sin(3.0 * s), 30.0 * np.sin(2.0 * s)])
    rotations = Rotation.from_euler("yx", np.column_stack([s, 0.1 * np.sin(s)])).as_matrix()
    poses = np.array([make_pose(R, t) for R, t in zip(rotations, positions)])
    return Trajectory(100.0 + np.arange(n) / frame_rate_hz, poses)
