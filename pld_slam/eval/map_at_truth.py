"""A run's map moved onto the ground truth: its keyframes at their true poses, its landmarks
re-made from their observations there.

Bundle-adjusting such a map to convergence gives the optimum of the map's own observations
nearest the truth (`benchmarks/ba_truth.py`): if that optimum is no more accurate than
the run, the run's error is in its measurements, not in how it estimated.
"""

import numpy as np

from pld_slam.geometry.se3 import inverse, transform_points
from pld_slam.mapping.map import Map


def true_keyframe_poses(world_map: Map, groundtruth: np.ndarray) -> dict[int, np.ndarray]:
    """``T_w_c`` (4, 4) at its true pose, in the run's world frame, of every live keyframe (by id).

    ``groundtruth`` (N, 4, 4) holds one true ``T_g_c`` per frame of the sequence, in its
    own world frame ``g``. The first keyframe (the gauge every BA of the map holds fixed)
    keeps its pose; the others are placed by their true poses relative to it.
    """
    root = world_map.keyframes[world_map.covisibility.root]
    T_w_g = root.T_w_c @ inverse(groundtruth[root.frame_index])
    return {k: T_w_g @ groundtruth[keyframe.frame_index] for k, keyframe in world_map.keyframes.items()}


def move_map_to_truth(world_map: Map, groundtruth: np.ndarray) -> None:
    """Put every live keyframe at its true pose (`true_keyframe_poses`) and re-make every live landmark there, in place.

    A landmark goes where its first stereo observation puts it from that keyframe's true
    pose: a point from its stereo match, a line from the disparities of its two endpoints,
    as local mapping makes landmarks. A point no keyframe observes in stereo keeps its position.
    """
    T_w_c_true = true_keyframe_poses(world_map, groundtruth)
    ids = np.array(list(T_w_c_true), dtype=np.int64)
    world_map.set_keyframe_poses(ids, inverse(np.array(list(T_w_c_true.values())).reshape(-1, 4, 4)))
    points, lines = world_map.points, world_map.lines
    for landmark in np.flatnonzero(points.alive).tolist():
        for keyframe_id, feature in points.observers[landmark].items():
            features = world_map.keyframes[keyframe_id].features
            if feature < features.keypoints.n_stereo:
                position = transform_points(T_w_c_true[keyframe_id], features.points.points_c[feature])
                world_map.set_landmark_geometry(points, np.array([landmark]), position[None])
                break
    for landmark in np.flatnonzero(lines.alive).tolist():
        keyframe_id, feature = next(iter(lines.observers[landmark].items()))
        endpoints_c = world_map.keyframes[keyframe_id].features.lines.endpoints_c[feature]
        endpoints_w = transform_points(T_w_c_true[keyframe_id], endpoints_c)
        world_map.set_landmark_geometry(lines, np.array([landmark]), endpoints_w[None])
