"""PLD-SLAM: stereo point-line SLAM that stays accurate in dynamic scenes."""

from pld_slam.errors import ConfigError, DatasetError, PldSlamError, TrajectoryError

__version__ = "0.1.0"

__all__ = ["ConfigError", "DatasetError", "PldSlamError", "TrajectoryError", "__version__"]
