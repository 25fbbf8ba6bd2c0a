"""Trajectory error on the real extracts stays within the figures of the mapping issue's runs.

CI's guard against accuracy regressions: the whole pipeline (mapping on, the family
config of each extract) on each extract, bounded a little above what
`benchmarks/mapping.py` measured when the bounds were set (no timing here). Skipped
where ``$PLD_SLAM_DATA`` lacks the extract.

KITTI 06 frames 0-50 are bounded twice. Before the disparity offset was self-calibrated
(`pld_slam.stereo_calibration`), the error after SE(3) alignment (the paper's ATE) was
dominated by scale: the estimate was 1.0 % longer than the ground truth, which alone made
0.17 m of the 0.19 m ATE. The images of these frames measure disparities about 0.15-0.2 px
too large (-0.146 px fitted against the ground-truth motion, -0.197 px found by the
self-calibration); with that offset removed the bound below holds the issue's figure
(0.035 m); KITTI 04 holds it (0.05 m) since its estimate is applied shrunk towards zero
(the KITTI family's prior, `pld_slam.stereo_calibration` step 5). After Sim(3) alignment,
which removes any scale error left, the shape of the trajectory is bounded tightly, so
that a regression in tracking or mapping shows even if one in the calibration hides it.
"""

from pathlib import Path

import numpy as np
import pytest
from conftest import require

from pld_slam.datasets import open_sequence
from pld_slam.eval.metrics import evaluate
from pld_slam.run_config import load_run_config
from pld_slam.system import System
from pld_slam.tracking.tracker import TrackingStatus


def run_extract(folder: Path):
    sequence = open_sequence(folder)
    system = System(sequence, load_run_config(sequence).config)
    result = system.run()
    assert all(r.status is not TrackingStatus.LOST for r in result.records), "tracking failed on a frame"
    return sequence, result.trajectory()


@pytest.mark.parametrize(
    "extract, max_ate_m, max_sim3_ate_m",
    [
        ("kitti_odometry/sequences/06", 0.035, 0.025),  # measured 0.0235, 0.0220
        ("kitti_odometry/sequences/04", 0.05, 0.045),  # measured 0.0442, 0.0376 (0.168 before the prior)
        ("kitti_raw/2011_09_26/2011_09_26_drive_0005_sync", 0.095, 0.09),  # measured 0.0888, 0.0776
    ],
)
def test_kitti_ate_within_the_measured_bounds(data_dir, extract, max_ate_m, max_sim3_ate_m):
    sequence, trajectory = run_extract(require(data_dir / extract))
    assert len(trajectory) == len(sequence)
    assert evaluate(sequence.groundtruth, trajectory).ate_rmse_m <= max_ate_m
    assert evaluate(sequence.groundtruth, trajectory, align="sim3").ate_rmse_m <= max_sim3_ate_m


def test_euroc_standing_still_drifts_under_2_mm(data_dir):
    sequence, trajectory = run_extract(require(data_dir / "euroc" / "V1_01_easy_static"))
    assert len(trajectory) == 40
    assert np.linalg.norm(trajectory.positions, axis=1).max() < 0.002  # measured 1.3 mm


def test_euroc_flight_tracks_every_frame_within_3_mm(data_dir):
    sequence, trajectory = run_extract(require(data_dir / "euroc" / "V1_01_easy_flight"))
    assert len(trajectory) == 10
    assert evaluate(sequence.groundtruth, trajectory).ate_rmse_m < 0.003  # measured 0.9 mm
