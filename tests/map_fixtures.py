"""Hand-made cameras, stereo features, keyframes and maps for the mapping tests (no images).

Features are built exactly from world points and segments seen from a pose: pixels,
disparities and camera-frame coordinates agree to rounding, and every landmark carries
its own random descriptor (two random 256-bit descriptors differ by about 128 bits, far
above the matchers' 64-bit limit), so the matchers of local mapping find exactly the
features made from the same world point.
"""

import numpy as np

from pld_slam.frontend import LeftKeypoints, StereoFeatures, StereoLines, StereoPoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, make_pose, se3_exp, transform_points
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map

CAMERA = StereoCamera(fx=300.0, fy=300.0, cx=160.0, cy=120.0, baseline=0.5, width=320, height=240)


def random_descriptors(count: int, seed: int) -> np.ndarray:
    """(count, 32) uint8 random descriptors."""
    return np.random.default_rng(seed).integers(0, 256, size=(count, 32), dtype=np.uint8)


def scene_points(count: int, seed: int) -> np.ndarray:
    """(count, 3) world points 8-20 m ahead of the world origin, inside the view of `CAMERA` from near it."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(8.0, 20.0, count)
    x = rng.uniform(-0.3, 0.3, count) * z
    y = rng.uniform(-0.2, 0.2, count) * z
    return np.column_stack([x, y, z])


def scene_lines(count: int, seed: int) -> np.ndarray:
    """(count, 2, 3) world segments, steep in the image (stereo-friendly), in view like `scene_points`."""
    starts = scene_points(count, seed)
    ends = starts + np.column_stack([np.full(count, 0.3), np.full(count, 1.0), np.zeros(count)])
    return np.stack([starts, ends], axis=1)


def pose_near_origin(seed: int, scale: float = 1.0) -> np.ndarray:
    """A world-to-camera pose ``T_c_w`` a small random motion away from the identity."""
    rng = np.random.default_rng(seed)
    twist = np.concatenate([rng.uniform(-0.5, 0.5, 3), rng.uniform(-0.03, 0.03, 3)]) * scale
    return se3_exp(twist)


def camera_at(centre: np.ndarray) -> np.ndarray:
    """``T_c_w`` of a camera at ``centre`` (3,) [m] looking along the world z axis."""
    return inverse(make_pose(np.eye(3), np.asarray(centre, dtype=np.float64)))


def camera_features(
    points_c: np.ndarray,
    point_descriptors: np.ndarray,
    lines_c: np.ndarray | None = None,
    line_descriptors: np.ndarray | None = None,
    mono_uv: np.ndarray | None = None,
    mono_descriptors: np.ndarray | None = None,
    octave: np.ndarray | None = None,
    camera: StereoCamera = CAMERA,
) -> StereoFeatures:
    """Exact `StereoFeatures` of points (N, 3) and segments (M, 2, 3) in the left camera frame.

    ``mono_uv`` (K, 2) adds keypoints without a stereo match after the N stereo points;
    ``octave`` (N + K,) sets the keypoints' ORB octaves (0 by default).
    """
    points_c = np.asarray(points_c, dtype=np.float64).reshape(-1, 3)
    lines_c = np.zeros((0, 2, 3)) if lines_c is None else np.asarray(lines_c, dtype=np.float64)
    line_descriptors = np.zeros((0, 32), dtype=np.uint8) if line_descriptors is None else line_descriptors
    mono_uv = np.zeros((0, 2)) if mono_uv is None else np.asarray(mono_uv, dtype=np.float64)
    mono_descriptors = np.zeros((0, 32), dtype=np.uint8) if mono_descriptors is None else mono_descriptors
    n_stereo, n_keypoints = len(points_c), len(points_c) + len(mono_uv)
    octave = np.zeros(n_keypoints, dtype=np.int64) if octave is None else np.asarray(octave, dtype=np.int64)
    stereo_px = camera.project_stereo(points_c)
    points = StereoPoints(
        uv=stereo_px[:, :2],
        octave=octave[:n_stereo],
        descriptors=point_descriptors,
        disparity=stereo_px[:, 0] - stereo_px[:, 2],
        u_right=stereo_px[:, 2],
        points_c=points_c,
    )
    keypoints = LeftKeypoints(
        uv=np.concatenate([stereo_px[:, :2], mono_uv]),
        octave=octave,
        descriptors=np.concatenate([point_descriptors, mono_descriptors]),
        u_right=np.concatenate([stereo_px[:, 2], np.full(len(mono_uv), np.nan)]),
        n_stereo=n_stereo,
    )
    start_px = camera.project_stereo(lines_c[:, 0])
    end_px = camera.project_stereo(lines_c[:, 1])
    lines = StereoLines(
        endpoints=np.column_stack([start_px[:, :2], end_px[:, :2]]),
        disparity=np.column_stack([start_px[:, 0] - start_px[:, 2], end_px[:, 0] - end_px[:, 2]]),
        descriptors=line_descriptors,
        endpoints_c=lines_c,
    )
    return StereoFeatures(points=points, lines=lines, keypoints=keypoints)


def world_features(
    T_c_w: np.ndarray,
    points_w: np.ndarray,
    point_descriptors: np.ndarray,
    lines_w: np.ndarray | None = None,
    line_descriptors: np.ndarray | None = None,
    **others,
) -> StereoFeatures:
    """`camera_features` of world points (N, 3) and segments (M, 2, 3) seen from ``T_c_w``."""
    lines_c = None
    if lines_w is not None:
        lines_c = transform_points(T_c_w, np.asarray(lines_w).reshape(-1, 3)).reshape(-1, 2, 3)
    return camera_features(transform_points(T_c_w, points_w), point_descriptors, lines_c, line_descriptors, **others)


def simple_features(n_points: int, n_lines: int = 0, seed: int = 0) -> StereoFeatures:
    """Stereo points and lines somewhere in front of the camera, with random descriptors."""
    rng = np.random.default_rng(seed)
    points_c = np.column_stack(
        [rng.uniform(-2, 2, n_points), rng.uniform(-1, 1, n_points), rng.uniform(5, 15, n_points)]
    )
    starts = np.column_stack([rng.uniform(-2, 2, n_lines), rng.uniform(-1, 1, n_lines), rng.uniform(5, 15, n_lines)])
    lines_c = np.stack([starts, starts + [0.2, 1.0, 0.0]], axis=1)
    return camera_features(
        points_c, random_descriptors(n_points, seed + 1000), lines_c, random_descriptors(n_lines, seed + 2000)
    )


def empty_features() -> StereoFeatures:
    """No points, no lines."""
    return camera_features(np.zeros((0, 3)), np.zeros((0, 32), dtype=np.uint8))


def make_keyframe(
    keyframe_id: int,
    features: StereoFeatures,
    T_c_w: np.ndarray | None = None,
    point_ids=None,
    line_ids=None,
    point_dynamic=None,
    line_dynamic=None,
    point_rejected=None,
    line_rejected=None,
) -> KeyFrame:
    """A keyframe of ``features``; ids default to -1 (no landmark), labels to static and not rejected."""
    n_points, n_lines = len(features.keypoints), len(features.lines)

    def ids(values, count):
        out = np.full(count, -1, dtype=np.int64)
        if values is not None:
            out[:] = values
        return out

    def flags(values, count):
        out = np.zeros(count, dtype=bool)
        if values is not None:
            out[np.asarray(values, dtype=np.int64)] = True
        return out

    return KeyFrame(
        id=keyframe_id,
        frame_index=keyframe_id,
        timestamp=0.1 * keyframe_id,
        T_c_w=np.eye(4) if T_c_w is None else np.array(T_c_w, dtype=np.float64),
        features=features,
        ggs=np.zeros((2, 1, 1), dtype=np.uint8),
        place_ggs=np.zeros((2, 1, 1), dtype=np.uint8),
        point_ids=ids(point_ids, n_points),
        line_ids=ids(line_ids, n_lines),
        point_dynamic=flags(point_dynamic, n_points),
        line_dynamic=flags(line_dynamic, n_lines),
        point_rejected=flags(point_rejected, n_points),
        line_rejected=flags(line_rejected, n_lines),
    )


def add_landmarks(world_map: Map, n_points: int, n_lines: int = 0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n_points`` points and ``n_lines`` lines added to the map's columns (no observers yet); their ids."""
    points = world_map.points.add(scene_points(n_points, seed), random_descriptors(n_points, seed + 1), 0)
    lines = world_map.lines.add(scene_lines(n_lines, seed + 2), random_descriptors(n_lines, seed + 3), 0)
    return points, lines


def insert_observer(
    world_map: Map, point_ids=(), line_ids=(), T_c_w: np.ndarray | None = None, seed: int | None = None
) -> KeyFrame:
    """Insert the map's next keyframe, its feature ``i`` observing ``point_ids[i]`` / ``line_ids[i]``."""
    keyframe_id = world_map.next_keyframe_id()
    features = simple_features(len(point_ids), len(line_ids), seed=keyframe_id if seed is None else seed)
    keyframe = make_keyframe(keyframe_id, features, T_c_w, point_ids=list(point_ids), line_ids=list(line_ids))
    world_map.add_keyframe(keyframe)
    return keyframe


def check_map_consistency(world_map: Map) -> None:
    """Assert the invariants the map's methods keep (`pld_slam.mapping.map` docstring)."""
    for kind in world_map.kinds:
        assert len(kind.observers) == len(kind)
        for landmark, observers in enumerate(kind.observers):
            assert kind.n_observers[landmark] == len(observers), f"{kind.IDS_FIELD} {landmark}"
            if not kind.alive[landmark]:
                assert observers == {}, f"dead {kind.IDS_FIELD} {landmark} still observed"
            for keyframe_id, feature in observers.items():
                assert keyframe_id in world_map.keyframes
                assert getattr(world_map.keyframes[keyframe_id], kind.IDS_FIELD)[feature] == landmark
        for keyframe in world_map.keyframes.values():
            ids = getattr(keyframe, kind.IDS_FIELD)
            for feature in np.flatnonzero(ids >= 0).tolist():
                landmark = int(ids[feature])
                assert kind.alive[landmark], f"keyframe {keyframe.id} names dead {kind.IDS_FIELD} {landmark}"
                assert kind.observers[landmark].get(keyframe.id) == feature
    graph = world_map.covisibility
    assert set(graph.parent) == set(world_map.keyframes)
    for keyframe_id in world_map.keyframes:
        for other, count in graph.shared(keyframe_id).items():
            assert graph.shared(other)[keyframe_id] == count
    assert_tree(graph)


def reaches_root(graph, keyframe: int) -> bool:
    """Whether following ``graph.parent`` from ``keyframe`` reaches the root (no cycle, no dead end)."""
    seen = set()
    while keyframe != graph.root:
        if keyframe in seen or graph.parent.get(keyframe) is None:
            return False
        seen.add(keyframe)
        keyframe = graph.parent[keyframe]
    return True


def assert_tree(graph) -> None:
    """Every linked keyframe of the graph reaches the root, and parent and children agree.

    A keyframe that has never had a link (no parent, no link) has not joined the tree yet.
    """
    assert graph.parent[graph.root] is None
    for keyframe, parent in graph.parent.items():
        if parent is None and keyframe != graph.root and not graph.shared(keyframe):
            continue
        assert reaches_root(graph, keyframe), f"keyframe {keyframe} does not reach the root {graph.root}"
        if parent is not None:
            assert keyframe in graph.children[parent]
    for parent, children in graph.children.items():
        assert all(graph.parent[child] == parent for child in children)
