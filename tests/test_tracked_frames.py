"""A run that tracks only a few of its frames ends with an error naming the likely cause; one that loses a
few frames goes on with a warning (`pld_slam.eval.tracked_frames`, record 0024; issue 43, item 5)."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pld_slam.eval.tracked_frames import tracked_frames_summary, tracked_frames_verdict
from pld_slam.frontend import StereoAgreement
from pld_slam.synth.writer import write_sequence
from pld_slam.system import FrameRecord
from pld_slam.tracking.reference_tracking import TrackingCounts
from pld_slam.tracking.tracker import TrackingStatus
from pld_slam_cli.main import EXIT_USER_ERROR, cli

FRAMES = 24
BROKEN_FROM = 12
"""The fixture's right images from this frame on are copies of the left: the run tracks a few frames
more on its map, then loses the rest (16 of 24 tracked at 640 x 480)."""


@pytest.fixture(scope="module")
def street(tmp_path_factory) -> Path:
    """A static synthetic street, 24 frames at 640 x 480: every frame tracked."""
    folder = tmp_path_factory.mktemp("tracked") / "seq"
    write_sequence(folder, "static", FRAMES, size=(640, 480), seed=0)
    return folder


def run(sequence: Path, out: Path):
    return CliRunner().invoke(cli, ["run", str(sequence), "--out", str(out)])


def summary_of(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def test_a_run_that_tracks_its_frames_has_neither_error_nor_warning(street, tmp_path):
    result = run(street, tmp_path / "run")
    assert result.exit_code == 0, result.output
    tracking = summary_of(tmp_path / "run")["tracking"]
    assert tracking["verdict"] == "tracked" and tracking["tracked"] == FRAMES and tracking["message"] is None
    assert "error" not in result.output and "warning" not in result.output


def test_a_run_whose_later_right_images_are_the_left_ones_ends_with_an_error_and_keeps_its_files(street, tmp_path):
    sequence = shutil.copytree(street, tmp_path / "seq")
    for right in sorted((sequence / "image_1").glob("*.png"))[BROKEN_FROM:]:
        shutil.copyfile(sequence / "image_0" / right.name, right)
    out = tmp_path / "run"
    result = run(sequence, out)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    lines = result.output.splitlines()
    assert [line for line in lines if line.startswith(("error:", "warning:"))] == [lines[-1]]
    tracking = summary_of(out)["tracking"]
    assert tracking["verdict"] == "few_tracked"
    assert BROKEN_FROM <= tracking["tracked"] < 0.9 * FRAMES and tracking["first_lost"] >= BROKEN_FROM
    assert tracking["stereo_points_median"]["lost"] < 0.1 * tracking["stereo_points_median"]["tracked"]
    assert lines[-1] == f"error: {sequence}: {tracking['message']}"
    assert tracking["message"].startswith(f"tracked {tracking['tracked']} of the {FRAMES} frames (")
    assert "the lost frames have few stereo points" in lines[-1]
    assert "likely causes: their right images do not match the left" in lines[-1]
    # nothing is lost: every frame's pose is written, and the partial file gave way to the final ones
    rows = (out / "trajectory.tum.txt").read_text().splitlines()
    assert len([row for row in rows if not row.startswith("#")]) == FRAMES
    assert (out / "trajectory.kitti.txt").is_file() and (out / "frames.csv").is_file()
    assert not (out / "trajectory.partial.tum.txt").exists() and not (out / "run.lock").exists()


def test_a_run_with_two_unreadable_frames_goes_on_with_a_warning_naming_them(street, tmp_path):
    sequence = shutil.copytree(street, tmp_path / "seq")
    for index in (7, 15):
        (sequence / "image_0" / f"{index:06d}.png").write_bytes(b"")
    result = run(sequence, tmp_path / "run")
    assert result.exit_code == 0, result.output
    tracking = summary_of(tmp_path / "run")["tracking"]
    assert tracking["verdict"] == "some_lost" and tracking["lost"] == 2 and tracking["unreadable"] == 2
    warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: {sequence}: {tracking['message']}"]
    assert tracking["message"].startswith(f"lost 2 of the {FRAMES} frames (8 %), the first at frame 7; ")
    assert f"2 of them unreadable (frame 7: {sequence / 'image_0' / '000007.png'}" in tracking["message"]
    assert "error" not in result.output


@pytest.mark.parametrize(
    ("frames", "lost", "verdict"),
    [
        (0, 0, "unknown"), (1, 0, "tracked"), (1, 1, "none_tracked"),
        (2, 1, "some_lost"),  # one lost frame never fails a run, however short
        (3, 1, "some_lost"), (3, 2, "few_tracked"), (3, 3, "none_tracked"),
        (10, 1, "some_lost"), (10, 2, "few_tracked"),
        (20, 1, "tracked"), (20, 2, "some_lost"), (20, 3, "few_tracked"),
        (60, 1, "tracked"),  # the synthetic highway: 59 of 60
        (100, 5, "tracked"), (100, 6, "some_lost"), (100, 10, "some_lost"), (100, 11, "few_tracked"),
    ],
)
def test_the_verdict_from_the_frames_run_and_lost(frames, lost, verdict):
    assert tracked_frames_verdict(frames, lost) == verdict


def record(index: int, status: TrackingStatus, points: int = 600, read: bool = True) -> FrameRecord:
    return FrameRecord(index, 0.1 * index, np.eye(4), status, TrackingCounts(), {}, n_points=points if read else 0,
                       skipped_reason=None if read else f"frame{index}.png: not a PNG image",
                       stereo=StereoAgreement() if read else None)


def test_the_likely_cause_from_what_the_lost_frames_show():
    tracked = [record(0, TrackingStatus.FIRST)] + [record(i, TrackingStatus.TRACKED) for i in range(1, 6)]
    no_depth = tracked + [record(i, TrackingStatus.LOST, points=4) for i in range(6, 10)]
    assert "few stereo points (median 4, the tracked frames 600); likely causes: their right images" \
        in tracked_frames_summary(no_depth)["message"]
    with_depth = tracked + [record(i, TrackingStatus.LOST, points=500) for i in range(6, 10)]
    assert "have their stereo points (median 500, the tracked frames 600); likely causes: motion too fast" \
        in tracked_frames_summary(with_depth)["message"]
    unreadable = tracked + [record(i, TrackingStatus.LOST, read=False) for i in range(6, 10)]
    summary = tracked_frames_summary(unreadable)
    assert summary["message"] == ("tracked 6 of the 10 frames (60 %; a run must track 90 %): 4 lost, the first at "
                                  "frame 6; 4 of them unreadable (frame 6: frame6.png: not a PNG image); "
                                  "likely cause: image files missing, empty or corrupt")
    assert summary["unreadable"] == 4 and summary["stereo_points_median"] == {"tracked": 600.0, "lost": None}


def test_a_run_that_tracks_none_keeps_its_message():
    records = [record(i, TrackingStatus.LOST, read=False) for i in range(3)]
    assert tracked_frames_summary(records)["message"] == (
        "tracked none of the 3 frames (frame 0: frame0.png: not a PNG image); likely causes: left and right "
        "images swapped or the same, images too dark (e.g. 12-bit data in 16-bit PNGs), or a calibration "
        "that does not fit them")
