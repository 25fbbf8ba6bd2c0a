"""`MotionModel`: the tracker's constant-velocity motion model.

The next frame is predicted to move as the last one did: from the last pose ``T_w_p``
(camera to world) by the last inter-frame motion ``velocity`` (``T_c_p``, previous camera to
current camera). The prediction seeds the guided search against the reference frame
(`pld_slam.matching.frames`) and is the pose a frame that cannot be tracked keeps.

The tracker trusts the model only after a frame tracked normally
(`pld_slam.tracking.tracker.TrackingState`): after a lost or recovered frame, a skipped one,
or at the start, the last motion says little about the next one. A trusted prediction is
the static world's motion when movers pull the solve (`static_world`), and a local-map pose
it predicted is not posed again from scratch (`pld_slam.tracking.tracker` module docstring);
distances from it are in units of its expected error (`static_world.motion_model_distance`).
"""

import numpy as np

from pld_slam.geometry.se3 import inverse, nearest_pose
from pld_slam.localisation.static_world import StaticWorldOptions, motion_model_distance


class MotionModel:
    """Constant-velocity prediction from the last pose and the last inter-frame motion.

    Attributes
    ----------
    T_w_p : (4, 4) camera-to-world pose of the last frame (identity before any).
    velocity : (4, 4) ``T_c_p``, the motion from the frame before the last to the last one
        (identity before any: standing still).
    """

    def __init__(self) -> None:
        self.T_w_p = np.eye(4)
        self.velocity = np.eye(4)

    def predicted_T_w_c(self) -> np.ndarray:
        """The predicted pose (4, 4) of the next frame, camera to world: ``T_w_p @ inverse(velocity)``."""
        return self.T_w_p @ inverse(self.velocity)

    def predicted_T_c_w(self) -> np.ndarray:
        """The same pose (4, 4), world to camera: ``velocity @ inverse(T_w_p)``."""
        return self.velocity @ inverse(self.T_w_p)

    def advance(self, T_w_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Take the frame at ``T_w_c`` (4, 4, camera to world) as the last one.

        Returns
        -------
        T_w_c : (4, 4) the pose re-projected onto SE(3), now ``T_w_p``.
        T_c_p : (4, 4) the motion from the previous last pose to it, now ``velocity``.
        """
        T_w_c = nearest_pose(T_w_c)
        T_c_p = nearest_pose(inverse(T_w_c) @ self.T_w_p)
        self.velocity, self.T_w_p = T_c_p, T_w_c
        return T_w_c, T_c_p

    def coast(self) -> np.ndarray:
        """Move on by the prediction over a frame without a pose (skipped).

        Returns the prediction (4, 4, camera to world, re-projected onto SE(3)), now ``T_w_p``;
        the velocity stays.
        """
        self.T_w_p = nearest_pose(self.predicted_T_w_c())
        return self.T_w_p

    def distance(self, T_c_w: np.ndarray, world: StaticWorldOptions) -> float:
        """How far a pose ``T_c_w`` (4, 4, world to camera) lies from the prediction, in units of the
        model's expected error (``world.motion_prior_m``, ``world.motion_prior_deg``)."""
        return motion_model_distance(T_c_w, self.predicted_T_c_w(), world)
