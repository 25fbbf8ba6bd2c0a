"""The Argoverse 1.1 stereo loader on small log folders written in the release's layout.

The folder and JSON files follow argoverse-api (``ArgoverseStereoLoader``,
``argoverse.utils.calibration``, ``pose_loader``): rectified JPEGs named
``stereo_front_{left,right}_rect_<ns>.jpg``, ``vehicle_calibration_stereo_info.json``
with ``camera_data_`` entries and scalar-first quaternions, ``poses/city_SE3_egovehicle_<ns>.json``.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_datasets import open_error, write_images

from pld_slam.datasets import open_sequence
from pld_slam.datasets.argoverse import PAIR_TOLERANCE_NS
from pld_slam.geometry.se3 import inverse, make_pose
from pld_slam.run_config import dataset_family, load_run_config

LOG_ID = "273c1883-673a-36bf-b124-88311b1a80be"
WIDTH, HEIGHT = 32, 24
FX, FY, CX, CY = 40.0, 41.0, 15.5, 11.5
BASELINE = 0.2986
START_NS = 315_969_338_566_583_992
PERIOD_NS = 200_000_000  # 5 Hz
RIGHT_DELAY_NS = 672  # the right stamp of a real pair trails the left one by this much
R_VEHICLE_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Camera axes in the vehicle frame (x forward, y left, z up): the camera looks forward."""
T_VEHICLE_LEFT = make_pose(R_VEHICLE_CAMERA, np.array([1.6, 0.15, 1.4]))
T_VEHICLE_RIGHT = T_VEHICLE_LEFT @ make_pose(np.eye(3), np.array([BASELINE, 0.0, 0.0]))


def quaternion_wxyz(R: np.ndarray) -> list[float]:
    """Argoverse's scalar-first quaternion of a rotation matrix."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return [w, x, y, z]


def se3_json(T: np.ndarray) -> dict:
    """``vehicle_SE3_camera_`` of the calibration file."""
    return {"rotation": {"coefficients": quaternion_wxyz(T[:3, :3])}, "translation": T[:3, 3].tolist()}


def camera_entry(name: str, T_vehicle_camera: np.ndarray) -> dict:
    """One ``camera_data_`` entry as the release writes it."""
    return {
        "key": f"image_raw_{name}",
        "value": {
            "focal_length_x_px_": FX, "focal_length_y_px_": FY,
            "focal_center_x_px_": CX, "focal_center_y_px_": CY,
            "skew_": 0.0, "distortion_coefficients_": [0.0, 0.0, 0.0],
            "vehicle_SE3_camera_": se3_json(T_vehicle_camera),
        },
    }


def calibration_json(right: np.ndarray = T_VEHICLE_RIGHT) -> dict:
    """A ``vehicle_calibration_stereo_info.json`` with the two rectified cameras and a ring camera besides."""
    return {
        "camera_data_": [
            camera_entry("ring_front_center", make_pose(R_VEHICLE_CAMERA, np.array([1.7, 0.0, 1.5]))),
            camera_entry("stereo_front_left_rect", T_VEHICLE_LEFT),
            camera_entry("stereo_front_right_rect", right),
        ],
        "vehicle_SE3_down_lidar_": {"rotation": {"coefficients": [1.0, 0.0, 0.0, 0.0]}, "translation": [1.3, 0.0, 1.9]},
    }


def pose_json(T_city_vehicle: np.ndarray) -> dict:
    """A ``city_SE3_egovehicle_<ns>.json``."""
    return {"rotation": quaternion_wxyz(T_city_vehicle[:3, :3]), "translation": T_city_vehicle[:3, 3].tolist()}


def random_vehicle_poses(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) city poses of the vehicle, each turned and moved at random."""
    rng = np.random.default_rng(seed)
    rotations = Rotation.from_rotvec(rng.normal(scale=0.4, size=(n, 3))).as_matrix()
    return np.array([make_pose(R, rng.normal(scale=50.0, size=3)) for R in rotations])


def write_json(path: Path, content) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(content, indent=2))


def make_log(root: Path, n: int = 3, vehicle_poses: np.ndarray | None = None) -> Path:
    """``root/LOG_ID`` with n stereo pairs at 5 Hz, its calibration and (given ``vehicle_poses``) poses/.

    Pose files are written at each left image's timestamp, as the tracking release has
    them, and halfway between (its lidar sweeps), which no frame must pick.
    """
    log = root / LOG_ID
    stamps = [START_NS + i * PERIOD_NS for i in range(n)]
    write_images(log / "stereo_front_left_rect", [f"stereo_front_left_rect_{s}.jpg" for s in stamps], seed=0,
                 size=(WIDTH, HEIGHT))
    write_images(log / "stereo_front_right_rect", [f"stereo_front_right_rect_{s + RIGHT_DELAY_NS}.jpg" for s in stamps],
                 seed=1, size=(WIDTH, HEIGHT))
    write_json(log / "vehicle_calibration_stereo_info.json", calibration_json())
    if vehicle_poses is not None:
        for stamp, T in zip(stamps, vehicle_poses, strict=True):
            write_json(log / "poses" / f"city_SE3_egovehicle_{stamp}.json", pose_json(T))
            write_json(log / "poses" / f"city_SE3_egovehicle_{stamp + PERIOD_NS // 2}.json", pose_json(np.eye(4)))
    return log


def test_argoverse_log_calibration_timestamps_and_frames(tmp_path):
    sequence = open_sequence(make_log(tmp_path, n=3))
    assert (sequence.layout, sequence.name, len(sequence)) == ("argoverse", f"argoverse_{LOG_ID}", 3)
    camera = sequence.camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (FX, FY, CX, CY)
    assert camera.baseline == pytest.approx(BASELINE, abs=1e-12)
    assert camera.size == (WIDTH, HEIGHT)  # from the JPEG header, not the release's 2464 x 2056
    np.testing.assert_array_equal(sequence.timestamps, (START_NS + PERIOD_NS * np.arange(3)) / 1e9)
    assert (sequence.frame_rate.hz, sequence.frame_rate.source) == (5.0, "Argoverse stereo nominal rate")
    assert sequence.rectifier is None and sequence.groundtruth is None
    frame = sequence[2]
    assert frame.left.shape == frame.right.shape == (HEIGHT, WIDTH)
    assert sequence.frames.right_paths[2].name == f"stereo_front_right_rect_{START_NS + 2 * PERIOD_NS + 672}.jpg"


def test_argoverse_vehicle_poses_round_trip_to_the_rectified_left_camera(tmp_path):
    T_city_vehicle = random_vehicle_poses(4)
    sequence = open_sequence(make_log(tmp_path, n=4, vehicle_poses=T_city_vehicle))
    T_city_camera = T_city_vehicle @ T_VEHICLE_LEFT
    expected = inverse(T_city_camera[0]) @ T_city_camera
    groundtruth = sequence.groundtruth
    np.testing.assert_array_equal(groundtruth.timestamps, sequence.timestamps)
    np.testing.assert_allclose(groundtruth.poses, expected, atol=1e-9)


def test_argoverse_forward_drive_moves_the_camera_along_its_optical_axis(tmp_path):
    yaw = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), np.array([100.0, -20.0, 3.0]))
    drive = np.array([yaw @ make_pose(np.eye(3), np.array([2.0 * i, 0.0, 0.0])) for i in range(3)])
    groundtruth = open_sequence(make_log(tmp_path, n=3, vehicle_poses=drive)).groundtruth
    np.testing.assert_allclose(groundtruth.positions, [[0, 0, 0], [0, 0, 2], [0, 0, 4]], atol=1e-9)
    np.testing.assert_allclose(groundtruth.poses[:, :3, :3], np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-12)


def test_argoverse_family_config_halves_the_frames(tmp_path):
    sequence = open_sequence(make_log(tmp_path, n=2))
    run_config = load_run_config(sequence)
    assert dataset_family(sequence) == "argoverse"
    assert run_config.sources == ("defaults", "family: argoverse.yaml")
    assert run_config.config.dataset.scale == 0.5
    half = sequence.scaled(run_config.config.dataset.scale)
    assert half[0].left.shape == (HEIGHT // 2, WIDTH // 2)
    assert (half.camera.fx, half.camera.baseline) == (FX / 2, sequence.camera.baseline)


def rewrite_json(relative: str, content):
    return lambda log: write_json(log / relative, content)


def edit_calibration(change):
    """A log change: apply ``change`` to the calibration's content and write it back."""
    def apply(log: Path) -> None:
        content = calibration_json()
        change(content)
        write_json(log / "vehicle_calibration_stereo_info.json", content)
    return apply


def move_right_image(shift_ns: int):
    """A log change: restamp the first right image by ``shift_ns``."""
    def apply(log: Path) -> None:
        first = sorted((log / "stereo_front_right_rect").iterdir())[0]
        stamp = int(first.stem.rsplit("_", 1)[1])
        first.rename(first.with_name(f"stereo_front_right_rect_{stamp + shift_ns}.jpg"))
    return apply


CALIBRATION = "vehicle_calibration_stereo_info.json"


@pytest.mark.parametrize(
    "break_it, expected",
    [
        (lambda log: (log / CALIBRATION).unlink(), f"{CALIBRATION}: Argoverse calibration file not found"),
        (rewrite_json(CALIBRATION, {"cameras": []}), f"{CALIBRATION}: missing key 'camera_data_'"),
        (rewrite_json(CALIBRATION, {"camera_data_": {"stereo_front_left_rect": {}}}),
         "'camera_data_' is not a list of {\"key\": ..., \"value\": ...} camera entries"),
        (edit_calibration(lambda c: c["camera_data_"].pop(2)),
         f"{CALIBRATION}: missing key 'stereo_front_right_rect.vehicle_SE3_camera_.rotation.coefficients'"),
        (edit_calibration(lambda c: c["camera_data_"][1]["value"].pop("focal_length_x_px_")),
         "missing key 'stereo_front_left_rect.focal_length_x_px_'"),
        (edit_calibration(lambda c: c["camera_data_"][1]["value"]["vehicle_SE3_camera_"]["rotation"].update(
            coefficients=[0.0, 0.0, 0.0, 0.0])),
         "'stereo_front_left_rect.vehicle_SE3_camera_.rotation.coefficients' quaternion norm is 0, not 1"),
        (edit_calibration(lambda c: c["camera_data_"].__setitem__(
            2, camera_entry("stereo_front_right_rect", T_VEHICLE_LEFT @ make_pose(np.eye(3), np.array([-0.3, 0, 0]))))),
         "puts the right camera at x = -0.3 m of the left one, not to its right"),
        (edit_calibration(lambda c: c["camera_data_"][1]["value"].update(focal_center_x_px_=float("nan"))),
         f"{CALIBRATION}: stereo_front_left_rect.focal_center_x_px_ is nan, not a finite number"),
        (edit_calibration(lambda c: c["camera_data_"][1]["value"].update(focal_length_y_px_=0.0)),
         f"{CALIBRATION}: fy of stereo_front_left_rect is 0; a focal length must be positive"),
        (lambda log: (log / CALIBRATION).write_text("{\"camera_data_\": ["), f"{CALIBRATION}: not valid JSON"),
        (move_right_image(PAIR_TOLERANCE_NS + 1),
         f"stereo_front_left_rect_{START_NS}.jpg: no image with the same timestamp (within 5 ms) in "),
        (lambda log: (log / "stereo_front_right_rect" / f"stereo_front_right_rect_{START_NS + 672}.jpg").rename(
            log / "stereo_front_right_rect" / "right_0.jpg"),
         "right_0.jpg: expected the name stereo_front_right_rect_<timestamp ns>.jpg"),
        (lambda log: [p.unlink() for p in (log / "stereo_front_right_rect").iterdir()],
         "stereo_front_right_rect: no .jpg images"),
        (rewrite_json(f"poses/city_SE3_egovehicle_{START_NS}.json", {"rotation": [1.0, 0.0, 0.0, 0.0]}),
         f"city_SE3_egovehicle_{START_NS}.json: missing key 'translation'"),
        (rewrite_json("poses/city_SE3_egovehicle_latest.json", pose_json(np.eye(4))),
         "city_SE3_egovehicle_latest.json: expected the name city_SE3_egovehicle_<timestamp ns>.json"),
    ],
)
def test_argoverse_bad_input_is_one_line_naming_the_file(tmp_path, break_it, expected):
    log = make_log(tmp_path, n=3, vehicle_poses=random_vehicle_poses(3))
    break_it(log)
    assert expected in open_error(log)


def test_a_right_image_just_within_the_pair_tolerance_still_pairs(tmp_path):
    log = make_log(tmp_path, n=3)
    move_right_image(PAIR_TOLERANCE_NS - RIGHT_DELAY_NS)(log)
    assert len(open_sequence(log)) == 3
