"""A run recorded for the rerun viewer (``pld-slam run --rerun FILE.rrd``): `RerunRecording`.

The recording is an observer of the run, as the evaluation is: `RerunRecording.frame` is
a `pld_slam.system.FrameObserver` and `RerunRecording.keyframe` a
`pld_slam.system.KeyframeObserver`; they read what the system hands every observer and
change nothing. Each frame is logged at its index on the sequence timeline ``frame`` and
at its timestamp [s] on the timeline ``time``:

- ``world/camera``: the camera pose ``T_w_c`` (`Transform3D`), the left image under it
  (``world/camera/image``: the `Pinhole` of the camera, the image as a JPEG of
  `JPEG_QUALITY`), and the frame's matched features over the image, one entity per class
  (``world/camera/image/static``, ``.../dynamic``, ``.../outlier``: points as `Points2D`,
  lines as `LineStrips2D`), coloured as the dynamic overlays colour them
  (`pld_slam.io.dynamic_overlays`: static green, dynamic red) and the matches the pose
  rejected as outliers in blue (`feature_classes`);
- ``world/trajectory``: the trajectory so far, each frame's pose as tracked (the poses of
  ``trajectory.partial.tum.txt``; later corrections show in the keyframes below).

Each keyframe, once mapped and looked up for a loop: the map's points and lines
(``world/map/points``, ``world/map/lines``) and keyframe centres (``world/map/keyframes``),
as `pld_slam.io.map_ply.map_cloud` gives them, and after a loop has closed the loop edges
between the current centres of its two keyframes (``world/map/loops``). The ground truth,
when the sequence has one, is logged once (static, ``world/groundtruth``), moved into the
run's world: the camera of the first frame observed, ``x`` right, ``y`` down, ``z``
forward (`pld_slam.system`).

Pixels: ours have their centres at integer (u, v), rerun's image space has the first
pixel's centre at (0.5, 0.5); features and the principal point are shifted by
`PIXEL_CENTRE`.

Cost (README, ``--rerun``, for the measurements): loading rerun and, at the first log, pyarrow
once (about 0.6 s of CPU), then a few milliseconds per frame, most of it the image: a JPEG
of quality 75 (cv2) takes 68 of the 453 kB of a KITTI grey image and 0.6 ms to encode, so
the image is logged whole rather than subsampled. The recording is streamed to its file as
the run goes (a viewer can open it while it grows) and finished by `RerunRecording.close`.

rerun-sdk is an optional dependency (``pip install "pld-slam[viz]"``), imported when a
recording is opened: without it, `open_recording` raises a `PldSlamError` saying so.
"""

from pathlib import Path

import cv2
import numpy as np

from pld_slam.datasets import StereoFrame, StereoSequence
from pld_slam.errors import OutputError, PldSlamError
from pld_slam.frontend import StereoFeatures
from pld_slam.geometry.se3 import inverse
from pld_slam.io.dynamic_overlays import DYNAMIC_BGR, STATIC_BGR
from pld_slam.io.map_ply import map_cloud
from pld_slam.io.run_output import create_output_folder
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.system import RunResult
from pld_slam.tracking.tracker import TrackedFrame

JPEG_QUALITY = 75
"""Quality of each frame's left image as a JPEG (cv2, 0-100)."""
PIXEL_CENTRE = 0.5
"""Where rerun puts the centre of pixel (0, 0) on each axis; ours is at 0."""
OUTLIER_RGB = (0, 128, 255)
"""Blue: a match the frame's pose rejected as an outlier."""
CLASS_COLOURS = {"static": STATIC_BGR[::-1], "dynamic": DYNAMIC_BGR[::-1], "outlier": OUTLIER_RGB}
"""RGB colour of each class of features (`feature_classes`); static and dynamic as the overlays draw them."""
APPLICATION_ID = "pld-slam"
"""The rerun application a recording belongs to (the viewer groups recordings by it)."""


def open_recording(path: Path, sequence: StereoSequence) -> "RerunRecording":
    """A `RerunRecording` of a run on ``sequence`` streamed to ``path`` (an ``.rrd`` file; its folder is created).

    Raises `PldSlamError` when rerun-sdk is not installed and `OutputError` when the file
    cannot be written, before any frame is run.
    """
    try:
        import rerun
    except ImportError:
        raise PldSlamError('--rerun needs the rerun SDK: pip install "pld-slam[viz]"') from None
    create_output_folder(path.parent)
    stream = rerun.RecordingStream(APPLICATION_ID)
    try:
        stream.save(path)
    except RuntimeError as error:  # rerun says why in its message
        raise OutputError(f"{path}: cannot write ({error})") from None
    return RerunRecording(rerun, stream, sequence)


class RerunRecording:
    """The observers recording a run to a rerun stream (module docstring); `open_recording` makes one.

    Parameters
    ----------
    rerun : the ``rerun`` module (imported by `open_recording`: it is optional).
    stream : a ``rerun.RecordingStream`` with its sink set.
    sequence : the sequence run, scaled as the run's (its camera, name and ground truth).

    A context manager: leaving the ``with`` block finishes the file (`close`).
    """

    def __init__(self, rerun, stream, sequence: StereoSequence) -> None:
        self._rr, self._stream, self._sequence = rerun, stream, sequence
        self._positions: list[np.ndarray] = []
        self._loops_logged = 0
        stream.set_log_time_enabled(False)  # the sequence's timelines only
        stream.send_recording_name(sequence.name)
        stream.log("world", rerun.ViewCoordinates.RDF, static=True)  # x right, y down, z forward
        camera = sequence.camera
        stream.log("world/camera/image", rerun.Pinhole(
            focal_length=[camera.fx, camera.fy], principal_point=[camera.cx + PIXEL_CENTRE, camera.cy + PIXEL_CENTRE],
            width=camera.width, height=camera.height), static=True)

    def frame(self, frame: StereoFrame, features: StereoFeatures, tracked: TrackedFrame) -> None:
        """Log a tracked frame (a `pld_slam.system.FrameObserver`): image, features by class, pose, trajectory."""
        rr, stream = self._rr, self._stream
        if not self._positions:
            self._log_groundtruth(frame.timestamp)
        self._set_time(frame.index, frame.timestamp)
        stream.log("world/camera", rr.Transform3D(translation=tracked.T_w_c[:3, 3], mat3x3=tracked.T_w_c[:3, :3]))
        stream.log("world/camera/image", rr.EncodedImage(contents=jpeg(frame.left), media_type="image/jpeg"))
        for name, (point_uv, segments) in feature_classes(features, tracked).items():
            colour = CLASS_COLOURS[name]
            entity = f"world/camera/image/{name}"
            stream.log(entity, rr.Points2D(point_uv + PIXEL_CENTRE, colors=colour, radii=2.0))
            stream.log(entity, rr.LineStrips2D(segments.reshape(-1, 2, 2) + PIXEL_CENTRE, colors=colour))
        self._positions.append(tracked.T_w_c[:3, 3].astype(np.float32))
        stream.log("world/trajectory", rr.LineStrips3D([np.array(self._positions)], colors=(255, 255, 255)))

    def keyframe(self, keyframe: KeyFrame, result: RunResult) -> None:
        """Log the map after a keyframe (a `pld_slam.system.KeyframeObserver`), the loop edges once a loop closed."""
        rr, stream = self._rr, self._stream
        self._set_time(keyframe.frame_index, keyframe.timestamp)
        cloud = map_cloud(result.map)
        stream.log("world/map/points", rr.Points3D(cloud.points_w.astype(np.float32), colors=(200, 200, 200),
                                                   radii=rr.Radius.ui_points(1.5)))
        stream.log("world/map/lines", rr.LineStrips3D(cloud.lines_w.astype(np.float32), colors=(255, 170, 0)))
        stream.log("world/map/keyframes", rr.Points3D(cloud.keyframe_centres_w.astype(np.float32),
                                                      colors=(255, 0, 255), radii=rr.Radius.ui_points(4.0)))
        loops = [] if result.loop_closing is None else result.loop_closing.loops
        if len(loops) > self._loops_logged:
            world_map = result.map
            edges = [[world_map.keyframe_T_w_c(loop.keyframe)[:3, 3], world_map.keyframe_T_w_c(loop.candidate)[:3, 3]]
                     for loop in loops]
            stream.log("world/map/loops", rr.LineStrips3D(np.array(edges, dtype=np.float32), colors=(255, 0, 0)))
            self._loops_logged = len(loops)

    def close(self) -> None:
        """Flush what was logged and finish the file (its footer); the viewer can then seek in it."""
        self._stream.disconnect()

    def __enter__(self) -> "RerunRecording":
        return self

    def __exit__(self, *exception) -> None:
        self.close()

    def _set_time(self, index: int, timestamp: float) -> None:
        """Log what follows at frame ``index`` and time ``timestamp`` [s]."""
        self._stream.set_time("frame", sequence=index)
        self._stream.set_time("time", duration=timestamp)

    def _log_groundtruth(self, timestamp: float) -> None:
        """The ground truth's positions (static), its pose nearest ``timestamp`` [s] (the run's world) at the origin."""
        groundtruth = self._sequence.groundtruth
        if groundtruth is None or len(groundtruth) == 0:
            return
        first = int(np.argmin(np.abs(groundtruth.timestamps - timestamp)))
        positions = (inverse(groundtruth.poses[first]) @ groundtruth.poses)[:, :3, 3]
        self._stream.log("world/groundtruth", self._rr.LineStrips3D([positions.astype(np.float32)],
                                                                     colors=(0, 200, 255)), static=True)


def feature_classes(features: StereoFeatures, tracked: TrackedFrame) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The frame's matched features by class: ``static``, ``dynamic``, ``outlier``; each the pixels (K, 2)
    of its points and the segments (L, 4) ``(u_s, v_s, u_e, v_e)`` of its lines, in the left image.

    The classes part the features of the tracker's dynamic labels (``tracked.dynamic``, those
    the overlays draw): dynamic as labelled; outliers those the pose rejected
    (``tracked.point_rejected``, ``line_rejected`` over all of the frame's ``features``, never
    dynamic), found among the labelled ones by their pixels; static the rest. Empty classes
    for a frame without labels (the first).
    """
    labels = tracked.dynamic
    if labels is None:
        return dict.fromkeys(CLASS_COLOURS, (np.zeros((0, 2)), np.zeros((0, 4))))
    point_outlier = rows_among(labels.point_uv, features.keypoints.uv[tracked.point_rejected])
    line_outlier = rows_among(labels.line_segments, features.lines.endpoints[tracked.line_rejected])
    return {
        "static": (labels.point_uv[~labels.point_dynamic & ~point_outlier],
                   labels.line_segments[~labels.line_dynamic & ~line_outlier]),
        "dynamic": (labels.point_uv[labels.point_dynamic], labels.line_segments[labels.line_dynamic]),
        "outlier": (labels.point_uv[point_outlier], labels.line_segments[line_outlier]),
    }


def rows_among(rows: np.ndarray, among: np.ndarray) -> np.ndarray:
    """(N,) bool: whether each row of ``rows`` (N, D) equals a row of ``among`` (M, D)."""
    return (rows[:, None, :] == among[None, :, :]).all(axis=2).any(axis=1)


def jpeg(image: np.ndarray) -> bytes:
    """``image`` (H, W) uint8 encoded as a JPEG of `JPEG_QUALITY`."""
    _, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return encoded.tobytes()
