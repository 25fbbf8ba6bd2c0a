"""True depths from LiDAR scans (`pld_slam.eval.lidar_depth`): projection, plane fit, refusals."""

import numpy as np
import pytest

from pld_slam.errors import DatasetError
from pld_slam.eval.lidar_depth import (
    ScanInImage,
    inverse_depth_at,
    lidar_to_camera,
    project_scan,
    read_scan,
    scanned_frames,
)
from pld_slam.geometry.camera import StereoCamera

CAMERA = StereoCamera(fx=700.0, fy=700.0, cx=600.0, cy=180.0, baseline=0.54, width=1200, height=370)


def scan_lines(depth_of, rows=range(100, 300, 5), columns=np.arange(0, 1200, 1.0)) -> ScanInImage:
    """A synthetic scan: points on horizontal lines 5 px apart (as KITTI's), 1 px along each line."""
    u, v = np.meshgrid(columns, np.array(list(rows), dtype=float))
    u, v = u.ravel(), v.ravel()
    return ScanInImage(np.column_stack([u, v]), 1.0 / depth_of(u, v))


def test_a_slanted_plane_gives_the_exact_depth_between_scan_lines():
    # the ground plane y = 1.6 m: 1/z = (v - cy) / (fy * 1.6), affine in the pixel
    scan = scan_lines(lambda u, v: 1.6 * CAMERA.fy / (v - CAMERA.cy), rows=range(200, 370, 5))
    pixels = np.array([[300.3, 252.5], [900.7, 301.2]])
    expected = (pixels[:, 1] - CAMERA.cy) / (CAMERA.fy * 1.6)
    np.testing.assert_allclose(inverse_depth_at(scan, pixels), expected, rtol=1e-9)


def test_no_depth_across_a_depth_edge_or_on_one_scan_line_or_without_neighbours():
    scan = scan_lines(lambda u, v: np.where(u < 600, 10.0, 20.0))
    on_the_edge = np.array([[600.0, 152.0]])
    assert np.isnan(inverse_depth_at(scan, on_the_edge)).all()
    one_line = ScanInImage(np.column_stack([np.arange(0, 1200.0), np.full(1200, 100.0)]), np.full(1200, 0.1))
    assert np.isnan(inverse_depth_at(one_line, np.array([[500.0, 100.0]]))).all()
    assert np.isnan(inverse_depth_at(scan, np.array([[500.0, 20.0]]))).all()  # above the scanned rows


def test_a_point_on_the_plane_away_from_the_edge_keeps_its_depth():
    scan = scan_lines(lambda u, v: np.where(u < 600, 10.0, 20.0))
    np.testing.assert_allclose(inverse_depth_at(scan, np.array([[300.0, 152.0], [900.0, 152.0]])), [0.1, 0.05])


def test_project_scan_keeps_points_in_front_and_inside(tmp_path):
    T_c_l = np.eye(4)
    points = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, -5.0], [100.0, 0.0, 1.5], [1.0, 0.5, 20.0]])
    projected = project_scan(points, T_c_l, CAMERA)
    np.testing.assert_allclose(projected.uv, [[600.0, 180.0], [635.0, 197.5]])
    np.testing.assert_allclose(projected.inverse_depth, [0.1, 0.05])


def test_reading_scans_and_calibration(tmp_path):
    sequence = tmp_path / "04"
    (sequence / "velodyne").mkdir(parents=True)
    np.arange(8, dtype=np.float32).tofile(sequence / "velodyne" / "000005.bin")
    np.arange(8, dtype=np.float32).tofile(sequence / "velodyne" / "000000.bin")
    assert scanned_frames(sequence) == [0, 5]
    np.testing.assert_array_equal(read_scan(sequence / "velodyne" / "000005.bin"), [[0, 1, 2], [4, 5, 6]])
    np.arange(7, dtype=np.float32).tofile(sequence / "velodyne" / "000010.bin")
    with pytest.raises(DatasetError, match="000010.bin"):
        read_scan(sequence / "velodyne" / "000010.bin")
    projection = " ".join(["1"] * 12)
    (sequence / "calib.txt").write_text(f"P0: {projection}\nP1: {projection}\n")
    with pytest.raises(DatasetError, match="Tr"):
        lidar_to_camera(sequence)
    (sequence / "calib.txt").write_text(f"P0: {projection}\nTr: 0 -1 0 0.1 0 0 -1 0.2 1 0 0 0.3\n")
    np.testing.assert_allclose(lidar_to_camera(sequence)[:3, 3], [0.1, 0.2, 0.3])
