"""Numba kernels are cached in a user cache folder, never next to the installed source."""

import os
import subprocess
import sys
from pathlib import Path

import pld_slam

PACKAGE = Path(pld_slam.__file__).parent

def run_python(code: str, env: dict) -> None:
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=120)


def test_a_kernel_compiled_in_one_process_is_written_to_the_cache_folder_the_user_sets(tmp_path):
    cache = tmp_path / "numba"
    code = (
        "import numpy as np\n"
        "from pld_slam.geometry.camera import StereoCamera\n"
        "from pld_slam.optim.point_reprojection import point_reprojection_error\n"
        "camera = StereoCamera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, baseline=0.5, width=640, height=480)\n"
        "point_reprojection_error(camera, np.eye(4), np.array([[0.0, 0.0, 5.0]]), np.zeros((1, 3)))\n"
    )
    run_python(code, {**os.environ, "NUMBA_CACHE_DIR": str(cache)})
    assert any(path.suffix == ".nbi" for path in cache.rglob("*"))  # numba's cache index
    assert not list(PACKAGE.rglob("*.nbi"))  # nothing written beside the source


def test_without_a_cache_folder_set_pld_slam_chooses_one_in_the_users_cache(tmp_path):
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    code = "import pld_slam, numba; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(tmp_path / "pld-slam" / "numba")
