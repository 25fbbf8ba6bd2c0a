"""The rectified stereo camera: projection, back-projection and triangulation agree."""

import numpy as np

from pld_slam.geometry.camera import StereoCamera

CAMERA = StereoCamera(fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, baseline=0.537, width=1241, height=376)


def test_project_stereo_matches_the_right_camera_translated_by_the_baseline():
    rng = np.random.default_rng(0)
    p_c = rng.uniform([-5, -2, 3], [5, 2, 40], size=(20, 3))
    stereo = CAMERA.project_stereo(p_c)
    p_right = p_c - np.array([CAMERA.baseline, 0.0, 0.0])
    assert np.allclose(stereo[:, 2], CAMERA.project(p_right)[:, 0])
    assert np.allclose(stereo[:, :2], CAMERA.project(p_c))


def test_triangulate_inverts_projection():
    rng = np.random.default_rng(1)
    p_c = rng.uniform([-5, -2, 3], [5, 2, 40], size=(20, 3))
    stereo = CAMERA.project_stereo(p_c)
    disparity = stereo[:, 0] - stereo[:, 2]
    assert np.allclose(CAMERA.triangulate(stereo[:, :2], disparity), p_c)
    assert np.allclose(disparity, CAMERA.bf / p_c[:, 2])


def test_K_holds_the_intrinsics():
    K = CAMERA.K
    assert K[0, 0] == CAMERA.fx and K[1, 1] == CAMERA.fy
    assert K[0, 2] == CAMERA.cx and K[1, 2] == CAMERA.cy and K[2, 2] == 1.0
