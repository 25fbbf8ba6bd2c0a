"""`System.run` and the files of a run, on a short synthetic street (``static``, 12 frames, 320 x 240).

A run keeps one `FrameRecord` per processed frame: an unreadable image is skipped (LOST,
its reason recorded) without stopping the run, and Ctrl-C or an error stops it with every
frame so far kept, which `write_run_outputs` and `summarise_run` turn into a partial
trajectory and a summary marked incomplete. Two runs on the same input write the same bytes.
With image 5 unreadable the run measured ATE 0.041 m (0.031 m intact); the bound is 0.1 m.
"""

import dataclasses
import errno
import json
import multiprocessing
import re
import shutil
import sys
import threading

import cv2
import numpy as np
import pandas as pd
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from pld_slam.config import config_to_dict, load_config
from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.errors import ConfigError, OutputError, PldSlamError, Terminated
from pld_slam.eval import evaluate
from pld_slam.eval.dynamic_labels import MaskScores
from pld_slam.eval.run_summary import summarise_run
from pld_slam.geometry.se3 import inverse, se3_exp
from pld_slam.io.run_output import FRAMES, LOOPS, PLOT, SUMMARY, TRAJECTORY_KITTI, TRAJECTORY_TUM
from pld_slam.io.trajectory import read_kitti
from pld_slam.loop.vocabulary import build_vocabulary
from pld_slam.loop.vocabulary_training import training_descriptors
from pld_slam.report import run_files
from pld_slam.report.run_files import LOOP_COLUMNS, write_run_outputs
from pld_slam.synth import write_sequence
from pld_slam.system import STAGES, System
from pld_slam.tracking.tracker import TrackingStatus

N_FRAMES = 12
ACCURACY_KEYS = (
    "ate_rmse_m", "ate_rot_rmse_deg", "ate_sim3_rmse_m", "sim3_scale", "path_ratio", "rpe_trans_rmse_m",
    "rpe_rot_rmse_deg", "t_rel_pct", "r_rel_deg_per_100m", "n_matched",
)
TRACKING_STAGES = {"matching", "filters", "pose", "dynamic", "local_map", "see_through"}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("system") / "static"
    write_sequence(out, "static", N_FRAMES, (320, 240), seed=0)
    return out


@pytest.fixture(scope="module")
def sequence(folder):
    return open_sequence(folder)


@pytest.fixture(scope="module")
def config():
    return load_config()


@pytest.fixture(scope="module")
def full_run(sequence, config):
    """A run over the whole sequence."""
    return System(sequence, config).run()


def copy_of(folder, tmp_path):
    target = tmp_path / "copy"
    shutil.copytree(folder, target)
    return target


def interrupt_at(system: System, k: int, error: BaseException, monkeypatch) -> None:
    """Make ``system.process_frame`` raise ``error`` when it reaches frame ``k``."""
    original = system.process_frame

    def process_frame(index):
        if index == k:
            raise error
        return original(index)

    monkeypatch.setattr(system, "process_frame", process_frame)


def tracked_poses(result) -> np.ndarray:
    """The poses tracking gave each frame (the written ones also carry the later corrections of BA)."""
    return np.array([r.T_w_c for r in result.records])


def read_summary(out_dir) -> dict:
    return json.loads((out_dir / SUMMARY).read_text())


# --- a whole run ----------------------------------------------------------------------


def test_a_run_keeps_one_record_per_frame_in_order(sequence, full_run):
    assert full_run.stop_reason is None
    assert [r.index for r in full_run.records] == list(range(N_FRAMES))
    assert [r.timestamp for r in full_run.records] == [float(t) for t in sequence.timestamps]
    assert all(r.skipped_reason is None for r in full_run.records)
    assert all(r.n_points > 0 and r.n_lines > 0 for r in full_run.records)
    assert full_run.wall_seconds > 0.0
    assert len(full_run.trajectory()) == N_FRAMES


def test_a_config_whose_scale_the_sequence_was_not_given_is_refused(sequence, config):
    with pytest.raises(ConfigError, match="dataset.scale is 1 but .* is scaled by 0.5; run on sequence.scaled"):
        System(sequence.scaled(0.5), config)
    half = load_config(overrides=["dataset.scale=0.5"])
    assert System(sequence.scaled(0.5), half).sequence.camera.size == (160, 120)


def test_without_a_map_the_trajectory_is_the_tracked_poses(sequence):
    result = System(sequence, load_config(overrides=("mapping.enabled=false",))).run()
    assert result.map is None and all(r.reference_keyframe is None for r in result.records)
    assert np.array_equal(result.trajectory().poses, np.array([r.T_w_c for r in result.records]))


def test_a_frame_pose_follows_later_corrections_of_its_reference_keyframe(full_run):
    """Non-keyframe poses are stored relative to their reference keyframe (`System` docstring)."""
    records = full_run.records
    frame = next(r for r in records if r.keyframe is None and r.status is TrackingStatus.TRACKED)
    keyframe = full_run.map.keyframes.get(frame.reference_keyframe)
    assert keyframe is not None, "the reference keyframe of the chosen frame was culled"
    before = full_run.trajectory().poses
    correction = se3_exp(np.array([0.3, -0.1, 0.2, 0.01, 0.02, -0.03]))
    original = keyframe.T_c_w.copy()
    try:
        full_run.map.set_keyframe_poses(np.array([keyframe.id]), (original @ correction)[None])
        after = full_run.trajectory().poses
        corrected_T_w_k = keyframe.T_w_c
    finally:
        full_run.map.set_keyframe_poses(np.array([keyframe.id]), original[None])
    moved = ~np.all(np.isclose(before, after, atol=1e-12), axis=(1, 2))
    following = np.array([r.reference_keyframe == keyframe.id for r in records])
    assert np.array_equal(moved, following)
    # The frame keeps its pose relative to the corrected keyframe.
    relative = inverse(after[frame.index]) @ corrected_T_w_k
    np.testing.assert_allclose(relative, frame.T_c_r, atol=1e-9)


def test_tracked_frames_time_every_stage_and_the_first_frame_only_loading_the_front_end_and_mapping(full_run):
    first, *tracked = full_run.records
    assert set(first.stage_ms) == {"load", "frontend", "mapping", "loop", "total"}
    for record in tracked:
        expected = set(STAGES) if record.keyframe is not None else set(STAGES) - {"mapping", "loop"}
        assert set(record.stage_ms) == expected
        assert all(value >= 0.0 for value in record.stage_ms.values())
        # Tracking and mapping are disjoint slices of the frame's time; loading and the front end
        # ran ahead, in the background, while the previous frame was processed.
        parts = sum(value for stage, value in record.stage_ms.items() if stage not in ("load", "frontend", "total"))
        assert record.stage_ms["total"] >= parts - 1e-6


def test_prefetching_the_next_frame_changes_nothing_but_where_the_front_end_runs(sequence, config, full_run):
    serial_config = dataclasses.replace(config, system=dataclasses.replace(config.system, prefetch=False))
    serial = System(sequence, serial_config).run()
    assert serial.frontend_worker is None
    assert np.array_equal(serial.trajectory().poses, full_run.trajectory().poses)
    for record in serial.records[1:]:
        parts = sum(value for stage, value in record.stage_ms.items() if stage != "total")
        assert record.stage_ms["total"] >= parts - 1e-6  # without prefetching, every stage is a slice of the frame


def test_the_front_end_gives_the_same_run_in_a_forked_process_as_in_a_thread(sequence, config, full_run,
                                                                             monkeypatch):
    # Threads that earlier tests left (dask's) would make the default a thread: say none runs.
    monkeypatch.setattr(threading, "enumerate", lambda: [threading.current_thread()])
    in_process = System(sequence, config).run()
    thread_config = dataclasses.replace(config, system=dataclasses.replace(config.system, prefetch_worker="thread"))
    in_thread = System(sequence, thread_config).run()
    if sys.platform.startswith("linux"):
        assert in_process.frontend_worker == "process"  # the default, where forking is safe
    assert in_thread.frontend_worker == "thread"
    for run in (in_process, in_thread):
        assert np.array_equal(run.trajectory().poses, full_run.trajectory().poses)
        assert [r.n_lines for r in run.records] == [r.n_lines for r in full_run.records]


def test_close_ends_the_front_end_process_of_a_system_stepped_frame_by_frame(sequence, config, monkeypatch):
    monkeypatch.setattr(threading, "enumerate", lambda: [threading.current_thread()])  # as in test above
    before = set(multiprocessing.active_children())
    system = System(sequence, config)
    stepped = [system.process_frame(index) for index in range(3)]
    worker = set(multiprocessing.active_children()) - before
    system.close()
    if sys.platform.startswith("linux"):
        assert len(worker) == 1
    assert not worker & set(multiprocessing.active_children())
    assert system.process_frame(3).index == 3  # extracted in this thread from then on
    assert [r.index for r in stepped] == [0, 1, 2]


def blas_threads() -> set[int]:
    return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}


def test_blas_runs_one_thread_during_a_run_whatever_the_caller_set(sequence, config):
    seen = []

    def progress(indices):
        for index in indices:
            seen.append(blas_threads())
            yield index

    with threadpool_limits(limits=2, user_api="blas"):  # as in a program that imported numpy before pld_slam
        System(sequence, config).run(max_frames=2, progress=progress)
        after = blas_threads()
    assert seen == [{1}, {1}]
    assert after == {2}


def test_max_frames_runs_only_the_first_frames(sequence, config, full_run):
    result = System(sequence, config).run(max_frames=4)
    assert result.stop_reason is None
    assert [r.index for r in result.records] == [0, 1, 2, 3]
    assert np.array_equal(tracked_poses(result), tracked_poses(full_run)[:4])


def test_run_passes_the_frame_indices_through_the_progress_wrapper(sequence, config):
    seen = []

    def progress(indices):
        for index in indices:
            seen.append(index)
            yield index

    System(sequence, config).run(max_frames=3, progress=progress)
    assert seen == [0, 1, 2]


# --- unreadable images ----------------------------------------------------------------


@pytest.mark.parametrize("camera_folder", ["image_0", "image_1"])
def test_an_unreadable_image_is_skipped_as_lost_and_the_run_goes_on(folder, tmp_path, config, camera_folder):
    copy = copy_of(folder, tmp_path)
    broken = copy / camera_folder / "000005.png"
    broken.write_bytes(b"this is not a PNG at all" * 10)
    sequence = open_sequence(copy)
    result = System(sequence, config).run()

    assert result.stop_reason is None
    assert len(result.records) == N_FRAMES
    skipped = result.records[5]
    assert skipped.status is TrackingStatus.LOST
    assert skipped.skipped_reason is not None and str(broken) in skipped.skipped_reason
    assert set(skipped.stage_ms) == {"total"}
    assert skipped.n_points == 0 and skipped.n_lines == 0
    others = [r for r in result.records if r.index != 5]
    assert all(r.skipped_reason is None for r in others)
    assert [r.status for r in others[1:]] == [TrackingStatus.TRACKED] * (N_FRAMES - 2)
    assert evaluate(sequence.groundtruth, result.trajectory()).ate_rmse_m < 0.1  # measured 0.041 m

    summary = summarise_run(sequence, result, config)
    assert summary["completed"] is True
    assert summary["tracking_failures"] == [5]
    assert summary["skipped_frames"] == [{"index": 5, "reason": skipped.skipped_reason}]
    assert summary["timing_ms"]["total"]["median"] > 0.0


# --- runs stopped early ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("error", "reason"),
    [(KeyboardInterrupt(), "interrupted"), (Terminated(), "terminated"),
     (RuntimeError("disk on fire"), "RuntimeError: disk on fire")],
)
def test_a_run_stopped_mid_way_reraises_and_keeps_the_frames_before(sequence, config, full_run, monkeypatch,
                                                                    error, reason):
    k = 5
    system = System(sequence, config)
    interrupt_at(system, k, error, monkeypatch)
    with pytest.raises(type(error)):
        system.run()
    result = system.result
    assert result.stop_reason == reason
    assert [r.index for r in result.records] == list(range(k))
    assert np.array_equal(tracked_poses(result), tracked_poses(full_run)[:k])


def kernel_error_with(interrupt: KeyboardInterrupt) -> SystemError:
    """What a signal whose handler raised ``interrupt`` during a numba kernel's call comes back as."""
    try:
        try:
            raise interrupt
        except KeyboardInterrupt as signal_exception:
            raise SystemError("CPUDispatcher returned a result with an exception set") from signal_exception
    except SystemError as error:
        return error


@pytest.mark.parametrize(("interrupt", "reason"), [(KeyboardInterrupt(), "interrupted"), (Terminated(), "terminated")])
def test_a_signal_that_arrives_inside_a_compiled_kernel_stops_the_run_as_the_signal(sequence, config, monkeypatch,
                                                                                    interrupt, reason):
    system = System(sequence, config)
    interrupt_at(system, 3, kernel_error_with(interrupt), monkeypatch)
    with pytest.raises(type(interrupt)):
        system.run()
    assert system.result.stop_reason == reason
    assert [r.index for r in system.result.records] == [0, 1, 2]


def test_the_outputs_of_an_interrupted_run_hold_its_frames_and_say_it_did_not_complete(
        sequence, config, monkeypatch, tmp_path):
    k = 5
    system = System(sequence, config)
    interrupt_at(system, k, KeyboardInterrupt(), monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        system.run()
    result = system.result
    summary = summarise_run(sequence, result, config)
    out = tmp_path / "run"
    written = write_run_outputs(out, result.trajectory(), summary, sequence.groundtruth, "interrupted")

    assert {p.name for p in written} == {TRAJECTORY_KITTI, TRAJECTORY_TUM, SUMMARY, LOOPS, PLOT}
    kitti_rows = (out / TRAJECTORY_KITTI).read_text().splitlines()
    assert len(kitti_rows) == k
    np.testing.assert_allclose(read_kitti(out / TRAJECTORY_KITTI).poses, result.trajectory().poses, atol=1e-8)
    tum_rows = [line for line in (out / TRAJECTORY_TUM).read_text().splitlines() if not line.startswith("#")]
    assert len(tum_rows) == k
    on_disk = read_summary(out)
    assert on_disk["completed"] is False
    assert on_disk["stop_reason"] == "interrupted"
    assert on_disk["frames"] == k and on_disk["frames_in_sequence"] == N_FRAMES
    assert on_disk["n_matched"] == k
    assert on_disk["ate_rmse_m"] == pytest.approx(evaluate(sequence.groundtruth, result.trajectory()).ate_rmse_m)


def test_a_run_stopped_after_one_frame_writes_one_row_and_no_accuracy(sequence, config, monkeypatch, tmp_path):
    system = System(sequence, config)
    interrupt_at(system, 1, KeyboardInterrupt(), monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        system.run()
    summary = summarise_run(sequence, system.result, config)
    written = write_run_outputs(tmp_path, system.result.trajectory(), summary, sequence.groundtruth, "one")
    assert PLOT not in {p.name for p in written}
    assert len((tmp_path / TRAJECTORY_KITTI).read_text().splitlines()) == 1
    assert all(summary[key] is None for key in ACCURACY_KEYS)
    assert summary["real_time_factor"] is None
    assert summary["features_median"]["point_inliers"] is None


def test_a_run_stopped_before_the_first_frame_writes_only_the_summary(sequence, config, monkeypatch, tmp_path):
    system = System(sequence, config)
    interrupt_at(system, 0, KeyboardInterrupt(), monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        system.run()
    assert system.result.records == []
    summary = summarise_run(sequence, system.result, config)
    written = write_run_outputs(tmp_path, system.result.trajectory(), summary, sequence.groundtruth, "none")
    assert [p.name for p in written] == [SUMMARY]
    assert read_summary(tmp_path)["frames"] == 0
    assert all(summary[key] is None for key in ACCURACY_KEYS)


@pytest.mark.parametrize(("name", "writer"), [(PLOT, "plot_trajectory_top_view"), (SUMMARY, "write_summary"),
                                              (LOOPS, "write_loop_candidates")])
def test_a_run_file_that_cannot_be_written_is_an_error_naming_that_file(sequence, config, full_run, tmp_path,
                                                                        monkeypatch, name, writer):
    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")  # as a writer's own buffer flush: no file name

    monkeypatch.setattr(run_files, writer, full_disk)
    with pytest.raises(OutputError, match=f"^{re.escape(str(tmp_path / name))}: cannot write"):
        write_run_outputs(tmp_path, full_run.trajectory(), summarise_run(sequence, full_run, config),
                          sequence.groundtruth, "full disk")


# --- determinism ----------------------------------------------------------------------


def test_two_fresh_systems_give_bit_identical_trajectories_and_files(sequence, config, full_run, tmp_path):
    again = System(sequence, config).run()
    assert np.array_equal(again.trajectory().poses, full_run.trajectory().poses)
    assert [r.counts for r in again.records] == [r.counts for r in full_run.records]
    for name, result in (("a", full_run), ("b", again)):
        write_run_outputs(tmp_path / name, result.trajectory(), summarise_run(sequence, result, config),
                          sequence.groundtruth, "same")
    for file in (TRAJECTORY_KITTI, TRAJECTORY_TUM):
        assert (tmp_path / "a" / file).read_bytes() == (tmp_path / "b" / file).read_bytes()


def test_frames_csv_has_a_row_per_frame_with_its_stage_times_and_the_map_growing(sequence, config, full_run,
                                                                                 tmp_path):
    summary = summarise_run(sequence, full_run, config)
    written = write_run_outputs(tmp_path, full_run.trajectory(), summary, sequence.groundtruth, "frames",
                                records=full_run.records)
    assert tmp_path / FRAMES in written
    table = pd.read_csv(tmp_path / FRAMES, keep_default_na=False, na_values=[""])
    assert list(table["index"]) == list(range(N_FRAMES))
    assert [f"{stage}_ms" for stage in STAGES] == [c for c in table.columns if c.endswith("_ms")]
    assert np.allclose(table["total_ms"], [r.stage_ms["total"] for r in full_run.records], atol=1e-3)
    keyframes = table["keyframe"].fillna("") != ""
    assert keyframes.sum() == summary["mapping"]["keyframes"]
    assert table.loc[keyframes, "mapping_ms"].notna().all() and table.loc[~keyframes, "mapping_ms"].isna().all()
    assert (table["keyframes"] <= keyframes.cumsum()).all()
    assert table["keyframes"].iloc[-1] == summary["mapping"]["keyframes_alive"]
    assert (table["point_landmarks"].iloc[1:] > 0).all() and (table["rss_mb"] > 50).all()
    assert list(table["points"]) == [r.n_points for r in full_run.records]


# --- evaluation as an observer --------------------------------------------------------


def test_a_run_reads_no_mask_unless_an_observer_scores_its_labels(folder, config, monkeypatch):
    """The moving-object masks are ground truth: the pipeline reads none (``dynamic.from_masks``
    off), so a run without `MaskScores` costs no mask read and its summary has no scores."""
    sequence = open_sequence(folder)
    assert sequence.dynamic_mask_paths is not None  # a synthetic sequence: it has masks

    def no_mask(self, index: int) -> np.ndarray:
        raise AssertionError(f"the mask of frame {index} was read")

    monkeypatch.setattr(StereoSequence, "dynamic_mask", no_mask)
    result = System(sequence, config).run(max_frames=3)
    assert summarise_run(sequence, result, config)["dynamic"]["points"]["precision"] is None


def test_mask_scores_score_every_frame_with_images_for_the_summary(sequence, config):
    scores = MaskScores(sequence)
    result = System(sequence, config, [scores]).run(max_frames=4)
    assert list(scores.points) == list(scores.lines) == [r.index for r in result.records]
    points = summarise_run(sequence, result, config, mask_scores=scores)["dynamic"]["points"]
    assert points["on_moving_objects"] == 0  # the static street: nothing moves
    assert points["flagged"] == sum(r.counts.dynamic_points for r in result.records)


# --- summarise_run --------------------------------------------------------------------


def test_the_summary_of_a_whole_run(sequence, config, full_run):
    summary = summarise_run(sequence, full_run, config)
    json.dumps(summary)  # JSON-ready
    assert summary["sequence"] == sequence.name and summary["layout"] == "kitti_odometry"
    assert summary["frames"] == summary["frames_in_sequence"] == N_FRAMES
    assert summary["completed"] is True and summary["stop_reason"] is None
    assert summary["tracking_failures"] == [] and summary["skipped_frames"] == []
    assert summary["config"] == config_to_dict(config)

    timing = summary["timing_ms"]
    assert list(timing) == list(STAGES)
    for stage in STAGES:
        values = [r.stage_ms[stage] for r in full_run.records if stage in r.stage_ms]
        keyframes = sum(r.keyframe is not None for r in full_run.records)
        per_frame = N_FRAMES - 1 if stage in TRACKING_STAGES else N_FRAMES
        expected = {"mapping": keyframes, "loop": keyframes}.get(stage, per_frame)
        assert len(values) == expected
        assert timing[stage] == {"median": pytest.approx(np.median(values)), "mean": pytest.approx(np.mean(values))}

    assert summary["frame_rate"] == {"hz": 10.0, "source": "frame_rate of synth.json"}
    assert summary["real_time_factor"] > 0.0
    assert summary["real_time_factor"] == pytest.approx(N_FRAMES / 10.0 / full_run.wall_seconds)
    offset = summary["disparity_offset"]
    assert offset == full_run.disparity_offset.as_dict()
    assert offset["ms"] / 1e3 < full_run.wall_seconds  # the self-calibration counts in the run's wall time
    assert offset["used"] is False and offset["reason"]  # 12 frames of an exact rig: nothing to correct

    expected = evaluate(sequence.groundtruth, full_run.trajectory()).as_dict()
    assert {key: summary[key] for key in ACCURACY_KEYS} == expected
    assert summary["n_matched"] == N_FRAMES

    medians = summary["features_median"]
    assert medians["stereo_points"] == np.median([r.n_points for r in full_run.records])
    assert medians["line_inliers"] == np.median([r.counts.line_inliers for r in full_run.records[1:]])


def test_the_summary_lists_loop_candidates_and_the_final_global_ba(sequence, config, full_run):
    loop = summarise_run(sequence, full_run, config)["loop"]
    assert loop["detector"] == "ggs"
    assert loop["candidates"] == [] and loop["loops"] == []  # a short straight drive: nothing to close
    truth = loop["ground_truth"]
    assert truth["revisits"] == 0 and truth["recall"] is None and truth["precision"] is None
    assert loop["global_ba"]["keyframes"] == len(full_run.map.keyframes)
    assert loop["global_ba"]["points"] > 0


def test_global_ba_moves_the_keyframes_only_at_the_end(sequence, config):
    without = System(sequence, dataclasses.replace(config, optimize=dataclasses.replace(config.optimize,
                                                                                        global_ba=False))).run()
    with_ba = System(sequence, config).run()
    assert without.global_ba is None and with_ba.global_ba is not None
    np.testing.assert_array_equal(tracked_poses(without), tracked_poses(with_ba))
    assert not np.allclose(without.trajectory().poses, with_ba.trajectory().poses, atol=1e-9)


def test_the_bag_of_words_detector_needs_a_vocabulary(sequence, config, tmp_path):
    bow = dataclasses.replace(config, loop=dataclasses.replace(config.loop, detector="bow"))
    with pytest.raises(ConfigError, match="needs a vocabulary.*pld-slam vocabulary build"):
        System(sequence, bow)
    missing = dataclasses.replace(bow, loop=dataclasses.replace(bow.loop, vocabulary=str(tmp_path / "v.npz")))
    with pytest.raises(PldSlamError, match="v.npz: no such vocabulary file"):
        System(sequence, missing)


def test_a_bag_of_words_run_indexes_every_keyframe_and_writes_loops_csv(folder, sequence, config, tmp_path):
    vocabulary = build_vocabulary(training_descriptors([folder], config.points, every=3), branching=6, depth=3)
    vocabulary.save(tmp_path / "v.npz")
    bow = dataclasses.replace(config, loop=dataclasses.replace(config.loop, detector="bow",
                                                               vocabulary=str(tmp_path / "v.npz")))
    system = System(sequence, bow)
    result = system.run()
    detector = system.loop_closing.detector
    assert sorted(detector.vectors) == [k for k, _ in system.loop_closing.queries]
    assert len(detector.vectors) >= len(result.map.keyframes) > 1
    summary = summarise_run(sequence, result, bow)
    assert summary["loop"]["detector"] == "bow"
    written = write_run_outputs(tmp_path / "out", result.trajectory(), summary, sequence.groundtruth, "bow")
    assert (tmp_path / "out" / LOOPS) in written
    assert (tmp_path / "out" / LOOPS).read_text().splitlines()[0] == ",".join(LOOP_COLUMNS)


def test_a_sequence_without_ground_truth_has_null_accuracy(folder, tmp_path, config):
    copy = copy_of(folder, tmp_path)
    (copy / "poses.txt").unlink()
    sequence = open_sequence(copy)
    assert sequence.groundtruth is None
    result = System(sequence, config).run(max_frames=3)
    summary = summarise_run(sequence, result, config)
    assert all(summary[key] is None for key in ACCURACY_KEYS)
    assert summary["frames"] == 3 and summary["completed"] is True
    assert summary["real_time_factor"] > 0.0
    written = write_run_outputs(tmp_path / "out", result.trajectory(), summary, None, "no truth")
    assert len((tmp_path / "out" / TRAJECTORY_KITTI).read_text().splitlines()) == 3
    assert read_summary(tmp_path / "out")["ate_rmse_m"] is None
    assert (tmp_path / "out" / PLOT) in written


@pytest.mark.parametrize("damage", ["unreadable", "blank"])
def test_frames_before_the_first_usable_one_keep_their_rows_at_identity_and_are_the_failures(
    folder, tmp_path, config, damage
):
    copy = copy_of(folder, tmp_path)
    if damage == "unreadable":
        (copy / "image_1" / "000000.png").write_bytes(b"not a PNG" * 10)
    else:
        for side in ("image_0", "image_1"):
            cv2.imwrite(str(copy / side / "000000.png"), np.zeros((240, 320), dtype=np.uint8))
    sequence = open_sequence(copy)
    result = System(sequence, config).run()

    assert [r.index for r in result.records] == list(range(N_FRAMES))
    assert [r.status for r in result.records[:2]] == [TrackingStatus.LOST, TrackingStatus.FIRST]
    assert "000000.png" in result.records[0].skipped_reason
    trajectory = result.trajectory()
    np.testing.assert_array_equal(trajectory.timestamps, sequence.timestamps)
    np.testing.assert_array_equal(trajectory.poses[:2], np.stack([np.eye(4)] * 2))
    summary = summarise_run(sequence, result, config)
    assert summary["tracking_failures"] == [0]
    assert [frame["index"] for frame in summary["skipped_frames"]] == [0]
    assert summary["world_frame"] == 1
    assert summary["n_matched"] == N_FRAMES - 1
    assert summary["ate_rmse_m"] < 0.05  # measured 0.022 m; the identity placeholder counted made it 0.22 m
