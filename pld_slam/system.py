"""`System`: the stages of PLD-SLAM wired together, run in order for each frame.

The stages: the front end (stereo points and lines of each pair, and its GGS), tracking
(against the reference frame, then the local map), and local mapping (keyframe
insertion, landmark creation and culling, local BA), which runs inline: a keyframe's
mapping work happens before the next frame is tracked. ``mapping.enabled: false`` leaves
tracking alone, a visual odometry against the reference frame. Loop closing runs after
local mapping for each keyframe (`pld_slam.loop.loop_closing`), the final global BA at the
end of `System.run`.

With ``system.prefetch`` (the default), the next frames are read and their features
extracted in a background worker, a forked process where that is safe, while this one is
tracked and mapped (`pld_slam.frame_extraction`); the output is the same. BLAS runs one
thread during the calibration and `run` (`pld_slam.blas.one_blas_thread`; a caller
stepping `process_frame` itself can wrap its loop in it).

Before the first frame, every numba kernel is compiled (`pld_slam.kernels`; seconds on a
machine's first run, outside the run's wall time), then the stereo rig's disparity offset
is estimated from frame pairs spread over the sequence (`pld_slam.stereo_calibration`,
``calibration.disparity_offset``); every stage then uses `System.camera`, the sequence's
camera with that offset, and the estimate's time counts in the run's wall time.

Every frame's pose. With a map, a frame's pose is stored relative to its reference
keyframe (the last keyframe inserted before it; a keyframe is its own), and
`RunResult.trajectory` composes it with that keyframe's pose at the time it is asked, so
the written trajectory carries every correction that BA and loop closing made to the
keyframes after the frame was tracked (ORB-SLAM2 does the same). A culled keyframe leaves its pose relative
to its spanning-tree parent (`pld_slam.mapping.map.Map.keyframe_T_w_c`).

`System` keeps a `FrameRecord` per frame, so a run stopped early (Ctrl-C, an error) still
has the trajectory of every frame it processed, and row ``i`` of the trajectory is frame ``i``.

The first usable frame. The world is the camera of the first frame whose images can be
read and have the features to be tracked against (the tracker's rule for a reference
frame), not of frame 0: a blank or unreadable frame 0 cannot define it. The frames before
that one have no pose of their own (nothing was tracked yet, there is no motion to
extrapolate), so each gets the first usable frame's pose, the identity, and is recorded
as a failure (`TrackingStatus.LOST`, ``skipped_reason`` saying why); their rows are kept so
that rows stay aligned with frames.
"""

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from pld_slam.blas import one_blas_thread
from pld_slam.config import Config
from pld_slam.datasets import StereoFrame, StereoSequence, require_cameras
from pld_slam.errors import ConfigError, Terminated
from pld_slam.frame_extraction import FramePrefetcher, background_worker, extract_frame
from pld_slam.frontend import StereoAgreement, StereoFeatures
from pld_slam.geometry.se3 import inverse
from pld_slam.kernels import compile_kernels
from pld_slam.keyframes import KeyframeReason
from pld_slam.loop.loop_closing import LoopClosing
from pld_slam.mapping.global_ba import global_bundle_adjustment
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.local_mapping import KeyframeInsertion, LocalMapping
from pld_slam.mapping.map import Map
from pld_slam.mapping.map_ba import BaReport
from pld_slam.stereo_calibration import DisparityOffsetEstimate, calibrated_camera
from pld_slam.timing import ms_since, resident_mb
from pld_slam.tracking.tracker import TrackedFrame, Tracker, TrackingCounts, TrackingStatus
from pld_slam.trajectory import Trajectory

STAGES = ("load", "frontend", "matching", "filters", "pose", "dynamic", "local_map", "see_through", "mapping", "loop",
          "total")
"""Timed stages of one frame, in order; ``see_through`` is the test of the local map's missed
points against the frame's stereo pair (`pld_slam.tracking.see_through`); ``mapping``
(keyframes only) the local mapping of a keyframe, local BA included; ``loop`` (keyframes
only) its loop detection, verification and correction; ``total`` the frame's whole wall
time in the main thread. With ``system.prefetch``, ``load`` and ``frontend`` ran in the
background while earlier frames were processed, and ``total`` holds only the wait for
them, so the stages add up to more."""


@dataclass(frozen=True)
class FrameRecord:
    """What the system produced for one frame.

    Attributes
    ----------
    index, timestamp : frame number in the sequence and time [s].
    T_w_c : (4, 4) camera-to-world pose when the frame was tracked.
    reference_keyframe : id of the keyframe the pose is stored relative to (None without a map).
    T_c_r : (4, 4) the frame's pose relative to that keyframe's (identity for a keyframe).
    keyframe : why the frame became a keyframe, None for the others.
    status : how tracking obtained the pose.
    counts : matches, filter survivors and inliers.
    stage_ms : wall time per stage [ms] (keys from `STAGES`).
    n_points, n_lines : stereo points and lines the front end found.
    skipped_reason : why the frame's images could not be used, or None.
    map_size : keyframes, point landmarks and line landmarks alive once the frame was
        mapped ((0, 0, 0) without a map).
    rss_mb : the main process's resident memory then [MiB] (`pld_slam.timing.resident_mb`).
    stereo : how well the frame's pair agrees with a rectified, synchronised rig (None when
        its images could not be read).
    """

    index: int
    timestamp: float
    T_w_c: np.ndarray
    status: TrackingStatus
    counts: TrackingCounts
    stage_ms: dict[str, float]
    n_points: int = 0
    n_lines: int = 0
    skipped_reason: str | None = None
    reference_keyframe: int | None = None
    T_c_r: np.ndarray | None = None
    keyframe: KeyframeReason | None = None
    map_size: tuple[int, int, int] = (0, 0, 0)
    rss_mb: float = 0.0
    stereo: StereoAgreement | None = None


@dataclass
class RunResult:
    """The records of a run so far, and whether it went to the end.

    ``map`` is the run's map (None without mapping); ``insertions`` what local mapping did
    at each keyframe; ``loop_closing`` the loop stage (its candidates and closed loops; None
    without one); ``global_ba`` the final global BA (None when it did not run);
    ``disparity_offset`` the self-calibration before the run (None when switched off);
    ``frontend_worker`` where the next frames were extracted ahead: ``"process"``,
    ``"thread"`` (`pld_slam.frame_extraction.background_worker`; a thread from the start or
    after the forked child died), or None without prefetching; ``kernels_seconds`` the
    time taken to compile the numba kernels before the run (`pld_slam.kernels`; not in
    ``wall_seconds``: seconds once per machine, about 0.01 s from the cache).
    """

    records: list[FrameRecord] = field(default_factory=list)
    wall_seconds: float = 0.0
    stop_reason: str | None = None
    map: Map | None = None
    insertions: list[KeyframeInsertion] = field(default_factory=list)
    loop_closing: LoopClosing | None = None
    global_ba: BaReport | None = None
    disparity_offset: DisparityOffsetEstimate | None = None
    frontend_worker: str | None = None
    kernels_seconds: float = 0.0

    def trajectory(self) -> Trajectory:
        """``T_w_c`` of every processed frame, through its reference keyframe's current pose where it has one."""
        return Trajectory(
            np.array([r.timestamp for r in self.records]),
            np.array([self._final_pose(r) for r in self.records]).reshape(-1, 4, 4),
        )

    def _final_pose(self, record: FrameRecord) -> np.ndarray:
        if self.map is None or record.reference_keyframe is None:
            return record.T_w_c
        return self.map.keyframe_T_w_c(record.reference_keyframe) @ inverse(record.T_c_r)


FrameObserver = Callable[[StereoFrame, StereoFeatures, TrackedFrame], None]
"""Called with each frame that had images, its features and what tracking made of it (e.g. to draw
overlays, or to score the dynamic labels against ground-truth masks,
`pld_slam.eval.dynamic_labels.MaskScores`)."""

KeyframeObserver = Callable[[KeyFrame, RunResult], None]
"""Called with each new keyframe once local mapping inserted it and loop closing looked it up, and
the run so far (its map and loop closing: e.g. to record the map as it grows)."""

RecordObserver = Callable[[FrameRecord], None]
"""Called with the record of every frame as it is kept, skipped frames included (e.g. to
stream the poses to disk while the run goes)."""


def interrupt_behind(error: Exception) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM (`pld_slam.errors.Terminated`) that ``error`` stands for, if any: a signal whose
    handler raised while a compiled kernel was being called comes back as a ``SystemError`` ("returned a
    result with an exception set") caused by it."""
    cause = error.__cause__ or error.__context__
    while cause is not None and not isinstance(cause, KeyboardInterrupt):
        cause = cause.__cause__ or cause.__context__
    return cause


def stop_reason(interrupt: KeyboardInterrupt) -> str:
    """``stop_reason`` of a run a Ctrl-C (``interrupted``) or a SIGTERM (`Terminated`: ``terminated``) stopped."""
    return "terminated" if isinstance(interrupt, Terminated) else "interrupted"


class System:
    """PLD-SLAM on one stereo sequence: call `run`, or `process_frame` frame by frame and then `close`.

    ``observers`` see each frame with images, its features and its `TrackedFrame`, in order;
    ``keyframe_observer`` each new keyframe after its mapping and loop lookup, with the
    `RunResult` so far; ``record_observer`` sees every frame's `FrameRecord`, a frame whose
    images could not be read included, which is what a stream of the trajectory needs (the
    written trajectory has a row for every frame). Observers run after the frame's record is
    kept: their time is not in the frame's ``stage_ms`` nor in ``wall_seconds``.
    """

    def __init__(self, sequence: StereoSequence, config: Config, observers: Sequence[FrameObserver] = (),
                 record_observer: RecordObserver | None = None,
                 keyframe_observer: KeyframeObserver | None = None) -> None:
        self.sequence = sequence
        self.config = config
        if sequence.scale != config.dataset.scale:
            raise ConfigError(
                f"dataset.scale is {config.dataset.scale:g} but {sequence.root} is scaled by {sequence.scale:g}; "
                "run on sequence.scaled(config.dataset.scale)"
            )
        require_cameras(sequence, config.dataset.cameras,
                        "run on pld_slam.datasets.with_cameras(sequence, config.dataset.cameras)")
        if config.dynamic.from_masks and sequence.dynamic_mask_paths is None:
            raise ConfigError(
                f"dynamic.from_masks is set but {sequence.root} has no dynamic_masks/ folder (one mask per left image)"
            )
        kernels_seconds = compile_kernels()
        with one_blas_thread():
            self.camera, disparity_offset = calibrated_camera(sequence, config)
        world_map = Map(config.mapping.covisibility_min_shared) if config.mapping.enabled else None
        self.local_mapping = None if world_map is None else LocalMapping(world_map, self.camera, config)
        self.loop_closing = None
        if self.local_mapping is not None and config.loop.detector != "none":
            self.loop_closing = LoopClosing(world_map, self.camera, config)
        self.tracker = Tracker(self.camera, config, world_map)
        with_ggs = self.local_mapping is not None
        worker = background_worker(config.system.prefetch_worker, sequence.frames) if config.system.prefetch else None
        self._frames = FramePrefetcher(lambda index: extract_frame(sequence, index, self.camera, config, with_ggs),
                                       worker)
        self.result = RunResult(map=world_map, loop_closing=self.loop_closing, disparity_offset=disparity_offset,
                                wall_seconds=0.0 if disparity_offset is None else disparity_offset.ms / 1e3,
                                frontend_worker=self._frames.worker, kernels_seconds=kernels_seconds)
        self._observers = tuple(observers)
        self._record_observer = record_observer
        self._keyframe_observer = keyframe_observer
        self._started = False  # whether the first usable frame (module docstring) was tracked

    def process_frame(self, index: int) -> FrameRecord:
        """Load, extract and track frame ``index``; an unreadable frame is skipped, not fatal.

        The dataset raises `DatasetError` for an unreadable image (or one of another size
        than the calibration's) when it is read; the run goes on (the motion model gives
        that frame's pose, flagged in its record), because one corrupt file in a
        4,541-frame sequence should not cost the rest. Before the first usable frame
        (module docstring), an unreadable frame or one with too few features gets the
        identity instead (`_before_first_usable`).
        """
        start = time.perf_counter()
        timestamp = float(self.sequence.timestamps[index])
        extracted = self._frames.take(index)
        ahead = self.config.system.prefetch_frames
        self._frames.prefetch(range(index + 1, min(index + 1 + ahead, len(self.sequence))))
        if extracted.error is not None:
            error = extracted.error
            if not self._started:
                return self._before_first_usable(index, timestamp, str(error), start)
            tracked = self.tracker.skip()
            reference = self.tracker.reference_keyframe_id
            record = FrameRecord(index, timestamp, tracked.T_w_c, tracked.status, tracked.counts,
                                 {"total": ms_since(start)}, skipped_reason=str(error), reference_keyframe=reference,
                                 T_c_r=self._pose_to_reference(tracked.T_w_c, reference))
            return self._add(record, start)
        frame, features = extracted.frame, extracted.features
        if not self._started:
            if not self.tracker.can_be_reference(features):
                reason = (f"{self.sequence.frames.describe(index)}: too few features to start the trajectory on "
                          f"({len(features.points)} stereo points, {len(features.lines)} lines)")
                return self._before_first_usable(index, timestamp, reason, start, features)
            self._started = True
        moving_mask = self.sequence.dynamic_mask(index) if self.config.dynamic.from_masks else None
        tracked = self.tracker.track(features, moving_mask, (frame.left, frame.right))
        stage_ms = {**extracted.stage_ms, **tracked.stage_ms}
        reference = self._map_frame(index, timestamp, features, tracked, stage_ms)
        T_c_r = self._pose_to_reference(tracked.T_w_c, reference)
        if tracked.keyframe is not None:
            T_c_r = np.eye(4)
        stage_ms["total"] = ms_since(start)
        record = FrameRecord(index, timestamp, tracked.T_w_c, tracked.status, tracked.counts, stage_ms,
                             n_points=len(features.points), n_lines=len(features.lines),
                             reference_keyframe=reference, T_c_r=T_c_r, stereo=features.agreement,
                             keyframe=tracked.keyframe if self.local_mapping is not None else None)
        record = self._add(record, start)
        for observer in self._observers:
            observer(frame, features, tracked)
        if record.keyframe is not None and self._keyframe_observer is not None:
            self._keyframe_observer(self.result.map.keyframes[reference], self.result)
        return record

    def _before_first_usable(
        self, index: int, timestamp: float, reason: str, start: float, features: StereoFeatures | None = None,
    ) -> FrameRecord:
        """The record of a frame before the first usable one: the identity, LOST, ``reason`` as why it was skipped
        (``features``: its stereo points and lines and its pair's agreement, when it was read; they tell
        why a run lost it, `pld_slam.eval.tracked_frames`).

        The tracker never sees the frame, so the next frame is tracked as the first
        (the world); the record keeps the frame's row (module docstring).
        """
        read = {} if features is None else {"n_points": len(features.points), "n_lines": len(features.lines),
                                            "stereo": features.agreement}
        record = FrameRecord(index, timestamp, np.eye(4), TrackingStatus.LOST, TrackingCounts(),
                             {"total": ms_since(start)}, skipped_reason=reason, **read)
        return self._add(record, start)

    def _map_frame(
        self, index: int, timestamp: float, features: StereoFeatures, tracked: TrackedFrame,
        stage_ms: dict[str, float],
    ) -> int | None:
        """Local mapping's and loop closing's share of a tracked frame; returns the frame's reference
        keyframe (None without a map). Their times go into ``stage_ms``.

        The frame's sightings of landmarks go to local mapping's counters; a frame the
        tracker names a keyframe is inserted, looked up for a loop, and becomes the
        tracker's reference keyframe (at its pose after any correction).
        """
        mapping = self.local_mapping
        if mapping is None:
            return None
        if tracked.map is not None and tracked.status is TrackingStatus.TRACKED:
            found = tracked.map
            mapping.record_tracking(
                visible=(found.visible_point_ids, found.visible_line_ids),
                found=(found.point_ids[found.point_ids >= 0], found.line_ids[found.line_ids >= 0]),
                missed=(found.missed_point_ids, found.missed_line_ids),
                dynamic=(found.dynamic_point_ids, found.dynamic_line_ids),
            )
        if tracked.keyframe is None:
            return self.tracker.reference_keyframe_id
        start = time.perf_counter()
        keyframe = _new_keyframe(mapping.map.next_keyframe_id(), index, timestamp, features, tracked)
        self.result.insertions.append(mapping.insert_keyframe(keyframe))
        stage_ms["mapping"] = ms_since(start)
        if self.loop_closing is not None:
            start = time.perf_counter()
            self.loop_closing.process(keyframe)
            stage_ms["loop"] = ms_since(start)
        self.tracker.use_keyframe(keyframe)
        return keyframe.id

    def _pose_to_reference(self, T_w_c: np.ndarray, reference: int | None) -> np.ndarray | None:
        """``T_c_r``: the frame's pose relative to its reference keyframe's current pose (None without one)."""
        if reference is None:
            return None
        return inverse(T_w_c) @ self.local_mapping.map.keyframe_T_w_c(reference)

    def run(self, max_frames: int | None = None,
            progress: Callable[[Iterable[int]], Iterable[int]] = iter) -> RunResult:
        """Process the frames in order (the first ``max_frames`` if given).

        ``progress`` wraps the frame indices (e.g. ``tqdm``). Ctrl-C, SIGTERM (as
        `pld_slam.errors.Terminated`) or an error stops the loop with `result` holding every
        frame processed so far and ``stop_reason`` set (``interrupted``, ``terminated``, or the
        error); the exception is re-raised for the caller to report.
        """
        n_frames = len(self.sequence) if max_frames is None else min(max_frames, len(self.sequence))
        try:
            with one_blas_thread():
                for index in progress(range(n_frames)):
                    self.process_frame(index)
                self._finish()
        except KeyboardInterrupt as interrupt:
            self.result.stop_reason = stop_reason(interrupt)
            raise
        except Exception as error:
            interrupt = interrupt_behind(error)
            if interrupt is not None:
                self.result.stop_reason = stop_reason(interrupt)
                raise interrupt from None
            self.result.stop_reason = f"{type(error).__name__}: {error}"
            raise
        finally:
            self.close()
        return self.result

    def close(self) -> None:
        """Stop the front end's background worker (`run` does, at its end); after `process_frame`
        calls of one's own, call it to end the worker's process or thread. Frames processed later
        are extracted in the caller's thread. ``result.frontend_worker`` then says where the
        worker ran at the end (a thread when a forked child died during the run)."""
        self.result.frontend_worker = self._frames.worker
        self._frames.close()

    def _finish(self) -> None:
        """Global BA over the whole map (``optimize.global_ba``), once the last frame is processed."""
        if self.result.map is not None and self.config.optimize.global_ba:
            start = time.perf_counter()
            self.result.global_ba = global_bundle_adjustment(self.result.map, self.camera, self.config)
            self.result.wall_seconds += time.perf_counter() - start

    def _add(self, record: FrameRecord, start: float) -> FrameRecord:
        """Keep ``record`` with the map's size and the memory now; return what was kept."""
        world_map = self.result.map
        map_size = (0, 0, 0) if world_map is None else (
            len(world_map.keyframes), world_map.points.n_alive, world_map.lines.n_alive)
        record = replace(record, map_size=map_size, rss_mb=resident_mb())
        self.result.records.append(record)
        self.result.wall_seconds += time.perf_counter() - start
        if self._record_observer is not None:
            self._record_observer(record)
        return record


def _new_keyframe(
    keyframe_id: int, index: int, timestamp: float, features: StereoFeatures, tracked: TrackedFrame
) -> KeyFrame:
    """The keyframe of a tracked frame: its features, the landmarks it tracked, its dynamic labels."""
    found = tracked.map
    return KeyFrame(
        id=keyframe_id,
        frame_index=index,
        timestamp=timestamp,
        T_c_w=inverse(tracked.T_w_c),
        features=features,
        ggs=features.ggs,
        place_ggs=features.place_ggs,
        point_ids=np.full(len(features.keypoints), -1) if found is None else found.point_ids.copy(),
        line_ids=np.full(len(features.lines), -1) if found is None else found.line_ids.copy(),
        point_dynamic=tracked.point_dynamic,
        line_dynamic=tracked.line_dynamic,
        point_rejected=tracked.point_rejected,
        line_rejected=tracked.line_rejected,
    )

