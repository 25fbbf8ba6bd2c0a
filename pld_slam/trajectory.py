"""`Trajectory`: timestamped camera poses, the plain data every stage hands on.

A trajectory is ``timestamps`` (N,) [s] and ``poses`` (N, 4, 4) = ``T_w_c`` (camera to
world). Datasets give ground truth in it, the SLAM writes its estimate in it, and the
file readers/writers (`pld_slam.io.trajectory`) and metrics (`pld_slam.eval`) take it.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.errors import TrajectoryError
from pld_slam.geometry.se3 import inverse


@dataclass(frozen=True)
class Trajectory:
    """Camera poses ``T_w_c`` (N, 4, 4) at strictly increasing ``timestamps`` (N,) [s]."""

    timestamps: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        poses = np.asarray(self.poses, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise TrajectoryError(f"poses must have shape (N, 4, 4), got {poses.shape}")
        if len(timestamps) != len(poses):
            raise TrajectoryError(
                f"{len(timestamps)} timestamps for {len(poses)} poses"
            )
        if len(timestamps) > 1 and np.any(np.diff(timestamps) <= 0):
            raise TrajectoryError("timestamps must be strictly increasing")
        object.__setattr__(self, "timestamps", timestamps)
        object.__setattr__(self, "poses", poses)

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions(self) -> np.ndarray:
        """Camera centres in the world frame, shape (N, 3) [m]."""
        return self.poses[:, :3, 3]

    def path_length(self) -> float:
        """Length of the polyline through the camera centres [m]."""
        return polyline_length(self.positions)

    def relative_to_first(self) -> "Trajectory":
        """The same motion with the world moved to the first camera (first pose = identity)."""
        if len(self) == 0:
            return self
        return Trajectory(self.timestamps, inverse(self.poses[0]) @ self.poses)

    def head(self, n: int) -> "Trajectory":
        """The first ``n`` poses."""
        return Trajectory(self.timestamps[:n], self.poses[:n])


def polyline_length(points: np.ndarray) -> float:
    """Length [m] of the polyline through ``points`` (N, 3), in order; 0 for fewer than two."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
