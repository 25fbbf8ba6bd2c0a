"""Dataset loaders: the real extracts, small generated folders of each layout, bad input.

Real-data tests take the ``data_dir`` fixture of ``conftest.py`` and skip, naming the
extract, when it is missing. Generated folders hold a few 32x24 images written here.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from conftest import require

from pld_slam.datasets import open_sequence
from pld_slam.datasets.base import read_grey
from pld_slam.datasets.kitti_raw import EARTH_RADIUS
from pld_slam.errors import DatasetError, TrajectoryError
from pld_slam.geometry.se3 import make_pose, rotation_angle

WIDTH, HEIGHT = 32, 24
FX, FY, CX, CY = 50.0, 52.0, 16.0, 12.0
BASELINE = 0.25

# ---------------------------------------------------------------- helpers: generated folders


def write_images(folder: Path, names: list[str], seed: int = 0, size=(WIDTH, HEIGHT), colour: bool = False) -> None:
    """Random grey (or BGR ``colour``) images ``folder/name`` of ``size`` = (width, height)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    shape = (size[1], size[0], 3) if colour else (size[1], size[0])
    for name in names:
        cv2.imwrite(str(folder / name), rng.integers(0, 256, shape, dtype=np.uint8))


def write_lines(path: Path, lines: list[str]) -> Path:
    """Write ``lines`` as the text file ``path`` (parents created)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def numbers(values) -> str:
    """``values`` written as KITTI calibration numbers, space-separated."""
    return " ".join(f"{v:.12e}" for v in np.ravel(values))


def projection(baseline: float = 0.0) -> np.ndarray:
    """(3, 4) projection matrix of a rectified camera ``baseline`` to the right of the left one."""
    K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
    return K @ np.hstack([np.eye(3), [[-baseline], [0.0], [0.0]]])


COLOUR_CX, COLOUR_CY = CX + 1.5, CY - 1.0
"""The generated colour cameras' principal point [px], not the grey pair's."""
COLOUR_LEFT_T = np.array([0.06, -0.004, 0.03])
"""``t`` [m] of the generated colour left camera (cam2): where cam0's origin lies in cam2,
whose centre is 6 cm left of cam0's (x < 0), as in KITTI, and a few cm off in y and z."""
COLOUR_BASELINE = 0.3
"""Distance [m] along x from the generated colour left camera to the right one, which also
sits 1 cm further back (KITTI's sit a few mm apart along the optical axis)."""


def colour_projections() -> tuple[np.ndarray, np.ndarray]:
    """(3, 4) ``P2``, ``P3`` of the generated colour pair: ``K [I | t]`` of points in cam0's frame."""
    K = np.array([[FX, 0.0, COLOUR_CX], [0.0, FY, COLOUR_CY], [0.0, 0.0, 1.0]])
    t_right = COLOUR_LEFT_T - [COLOUR_BASELINE, 0.0, -0.01]
    return K @ make_pose(np.eye(3), COLOUR_LEFT_T)[:3], K @ make_pose(np.eye(3), t_right)[:3]


def translation(x: float, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """(4, 4) pure translation [m]."""
    return make_pose(np.eye(3), np.array([x, y, z]))


def kitti_pose_rows(poses: np.ndarray) -> list[str]:
    """KITTI pose-file rows of poses (N, 4, 4)."""
    return [numbers(T[:3]) for T in poses]


def make_kitti_odometry(root: Path, n: int = 3, pairs: tuple[str, ...] = ("grey",)) -> Path:
    """``root/sequences/00`` with n frames, calib.txt, times.txt and no ground truth; the
    grey pair (``image_0/``, ``image_1/``) and/or the colour pair (``image_2/``,
    ``image_3/``, `colour_projections`) as ``pairs`` says; ``calib.txt`` has ``P0``-``P3``
    with the colour pair, as KITTI's."""
    folder = root / "sequences" / "00"
    names = [f"{i:06d}.png" for i in range(n)]
    calibration = [f"P0: {numbers(projection())}", f"P1: {numbers(projection(BASELINE))}"]
    if "grey" in pairs:
        write_images(folder / "image_0", names, seed=0)
        write_images(folder / "image_1", names, seed=1)
    if "colour" in pairs:
        write_images(folder / "image_2", names, seed=2, colour=True)
        write_images(folder / "image_3", names, seed=3, colour=True)
        calibration += [f"P{i}: {numbers(P)}" for i, P in enumerate(colour_projections(), start=2)]
    write_lines(folder / "calib.txt", calibration)
    write_lines(folder / "times.txt", [f"{0.1 * i:.6e}" for i in range(n)])
    return folder


def make_kitti_raw(
    root: Path, n: int = 3, metres_east_per_frame: float = 1.0, east: list[float] | None = None,
    packet_times: list[str] | None = None, pairs: tuple[str, ...] = ("grey",), yaws: list[float] | None = None,
) -> Path:
    """A raw drive with n frames, one a second, whose OXTS unit drives east (yaw 0, or
    ``yaws`` [rad] if given) at a constant step, or to the positions ``east`` [m] if given;
    with ``oxts/timestamps.txt`` if ``packet_times`` are given; the grey pair
    (``image_00/``, ``image_01/``) and/or the colour pair (``image_02/``, ``image_03/``,
    `colour_projections`) as ``pairs`` says.

    The calibration puts the camera looking along the IMU's x axis (forward), so the
    camera moves along its own z axis.
    """
    date = root / "2011_01_01"
    folder = date / "2011_01_01_drive_0001_sync"
    names = [f"{i:010d}.png" for i in range(n)]
    times = [f"2011-01-01 00:00:{i:02d}.100000001" for i in range(n)]
    for pair, (left, right) in (("grey", ("image_00", "image_01")), ("colour", ("image_02", "image_03"))):
        if pair in pairs:
            for seed, camera in enumerate((left, right), start=0 if pair == "grey" else 2):
                write_images(folder / camera / "data", names, seed=seed, colour=pair == "colour")
            write_lines(folder / left / "timestamps.txt", times)
    P_rect_02, P_rect_03 = colour_projections()
    write_lines(
        date / "calib_cam_to_cam.txt",
        [
            "calib_time: 01-Jan-2011 00:00:00",
            f"S_rect_00: {WIDTH} {HEIGHT}",
            f"R_rect_00: {numbers(np.eye(3))}",
            f"P_rect_00: {numbers(projection())}",
            f"P_rect_01: {numbers(projection(BASELINE))}",
            f"S_rect_02: {WIDTH} {HEIGHT}",
            f"P_rect_02: {numbers(P_rect_02)}",
            f"P_rect_03: {numbers(P_rect_03)}",
        ],
    )
    camera_from_velodyne = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    write_lines(date / "calib_velo_to_cam.txt", [f"R: {numbers(camera_from_velodyne)}", "T: 0.1 -0.2 0.3"])
    write_lines(date / "calib_imu_to_velo.txt", [f"R: {numbers(np.eye(3))}", "T: 0.5 0 0.2"])
    lat0, lon0 = 49.0, 8.4
    degrees_per_metre = 180.0 / (np.cos(np.deg2rad(lat0)) * EARTH_RADIUS * np.pi)
    east = [i * metres_east_per_frame for i in range(n)] if east is None else east
    yaws = [0.0] * n if yaws is None else yaws
    for i in range(n):
        packet = [lat0, lon0 + east[i] * degrees_per_metre, 110.0, 0, 0, yaws[i]] + [0] * 24
        write_lines(folder / "oxts" / "data" / f"{i:010d}.txt", [" ".join(f"{v:.15g}" for v in packet)])
    if packet_times is not None:
        write_lines(folder / "oxts" / "timestamps.txt", packet_times)
    return folder


B_FROM_CAM0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Rotation of the generated EuRoC camera in the body: it looks along the body's x axis."""


def sensor_yaml(T_B_S: np.ndarray, distortion_model: str = "radial-tangential") -> str:
    """An EuRoC ``sensor.yaml`` (with OpenCV's ``%YAML:1.0`` line) of a camera at ``T_B_S``."""
    return (
        "%YAML:1.0\n"
        "sensor_type: camera\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{', '.join(f'{v:.12g}' for v in T_B_S.ravel())}]\n"
        f"resolution: [{WIDTH}, {HEIGHT}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{FX}, {FY}, {CX}, {CY}]\n"
        f"distortion_model: {distortion_model}\n"
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )


def make_euroc(root: Path, n: int = 3, start_ns: int = 1_403_715_273_262_142_976) -> Path:
    """``root/MH_00/mav0`` with n frames 50 ms apart and body ground truth at the frame times.

    The body moves 0.1 m per frame along its x axis, which is the left camera's z axis.
    """
    mav0 = root / "MH_00" / "mav0"
    stamps = [start_ns + i * 50_000_000 for i in range(n)]
    T_B_c0 = make_pose(B_FROM_CAM0, np.array([0.01, -0.02, 0.03]))
    T_B_c1 = T_B_c0 @ translation(BASELINE)
    for camera, T_B_S, seed in (("cam0", T_B_c0, 0), ("cam1", T_B_c1, 1)):
        write_images(mav0 / camera / "data", [f"{s}.png" for s in stamps], seed=seed)
        write_lines(mav0 / camera / "data.csv", ["#timestamp [ns],filename"] + [f"{s},{s}.png" for s in stamps])
        (mav0 / camera / "sensor.yaml").write_text(sensor_yaml(T_B_S))
    write_lines(
        mav0 / "state_groundtruth_estimate0" / "data.csv",
        ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"]
        + [f"{s},{0.1 * i + 2.0},1.0,0.5,1.0,0.0,0.0,0.0" for i, s in enumerate(stamps)],
    )
    return mav0.parent


def rectified_calibration() -> dict:
    """A generic ``calib.yaml`` of an already rectified WIDTH x HEIGHT pair."""
    K = [[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]]
    return {"image_size": [WIDTH, HEIGHT], "left": {"K": K}, "t": [-BASELINE, 0.0, 0.0], "rectified": True}


RAW_WIDTH, RAW_HEIGHT = 320, 240
RAW_RIG = {  # a distorted, slightly rotated rig: rows differ by several pixels before rectifying
    "image_size": [RAW_WIDTH, RAW_HEIGHT],
    "left": {"K": [[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]],
             "distortion": [-0.2, 0.05, 0.001, -0.001]},
    "right": {"K": [[305.0, 0.0, 158.0], [0.0, 302.0, 126.0], [0.0, 0.0, 1.0]],
              "distortion": [-0.18, 0.04, -0.001, 0.0005, 0.0]},
    "R": cv2.Rodrigues(np.array([0.03, -0.04, 0.05]))[0].tolist(),
    "t": [-0.12, 0.003, 0.002],
}


def make_generic(root: Path, calibration: dict, n: int = 3, suffix: str = ".png", size=(WIDTH, HEIGHT)) -> Path:
    """``root/my_rig`` with n random image pairs of ``size`` and ``calibration`` as calib.yaml."""
    folder = root / "my_rig"
    names = [f"{i:04d}{suffix}" for i in range(n)]
    write_images(folder / "left", names, seed=0, size=size)
    write_images(folder / "right", names, seed=1, size=size)
    (folder / "calib.yaml").write_text(yaml.safe_dump(calibration))
    return folder


def remove(relative: str):
    """A folder change: delete the file ``relative``."""
    return lambda folder: (folder / relative).unlink()


def rewrite(relative: str, *lines: str):
    """A folder change: replace the file ``relative`` by ``lines``."""
    return lambda folder: write_lines(folder / relative, list(lines))


def empty(relative: str):
    """A folder change: delete every file of the folder ``relative``."""
    return lambda folder: [path.unlink() for path in (folder / relative).iterdir()]


def open_error(path: Path, error=DatasetError) -> str:
    """The one-line message of the error raised by opening ``path``."""
    with pytest.raises(error) as caught:
        open_sequence(path)
    message = str(caught.value)
    assert "\n" not in message
    return message


# ---------------------------------------------------------------- real extracts


def test_kitti_odometry_extract(data_dir):
    sequence = open_sequence(require(data_dir / "kitti_odometry" / "sequences" / "06"))
    assert (sequence.name, sequence.layout, len(sequence)) == ("kitti_06", "kitti_odometry", 51)
    assert sequence.camera.fx == pytest.approx(707.0912)
    assert sequence.camera.baseline == pytest.approx(0.537, abs=1e-3)
    # Sequence 06 is 1226x370 (sequences 00-02 are 1241x376).
    frame = sequence[50]
    assert frame.left.shape == frame.right.shape == (370, 1226)
    assert (sequence.camera.width, sequence.camera.height) == (1226, 370)
    assert len(sequence.groundtruth) == 51
    assert np.allclose(sequence.groundtruth.poses[0], np.eye(4))
    assert np.array_equal(sequence.groundtruth.timestamps, sequence.timestamps)
    assert sequence.rectifier is None and sequence.dynamic_mask_paths is None


def test_kitti_raw_extract_oxts_path(data_dir):
    drive = data_dir / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0005_sync"
    sequence = open_sequence(require(drive))
    assert (sequence.name, sequence.layout) == ("kitti_raw_2011_09_26_drive_0005", "kitti_raw")
    assert len(sequence) == 45
    assert sequence.camera.baseline == pytest.approx(0.537, abs=1e-3)
    assert sequence[0].left.shape == (375, 1242)
    # 2011-09-26 13:04:32.351950336 UTC
    assert sequence.timestamps[0] == pytest.approx(1317042272.351950336, abs=1e-6)
    groundtruth = sequence.groundtruth
    assert len(groundtruth) == 45
    assert np.allclose(groundtruth.poses[0], np.eye(4), atol=1e-12)
    assert groundtruth.path_length() == pytest.approx(15.2, abs=0.1)
    assert np.allclose(groundtruth.positions[-1], [-4.29, -0.12, 14.28], atol=0.03)


def median_row_offset(left: np.ndarray, right: np.ndarray) -> float:
    """Median |v_left - v_right| [px] of cross-checked ORB matches between two images."""
    orb = cv2.ORB_create(1000)
    keys_left, descriptors_left = orb.detectAndCompute(left, None)
    keys_right, descriptors_right = orb.detectAndCompute(right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(descriptors_left, descriptors_right)
    rows = [keys_left[m.queryIdx].pt[1] - keys_right[m.trainIdx].pt[1] for m in matches]
    return float(np.median(np.abs(rows)))


def test_euroc_static_extract_is_rectified_and_still(data_dir):
    sequence = open_sequence(require(data_dir / "euroc" / "V1_01_easy_static"))
    assert (sequence.name, sequence.layout, len(sequence)) == ("euroc_V1_01_easy_static", "euroc", 40)
    assert sequence.camera.baseline == pytest.approx(0.110, abs=2e-3)
    frame = sequence[0]
    raw = cv2.imread(str(sequence.frames.left_paths[0]), cv2.IMREAD_GRAYSCALE)
    assert frame.left.shape == frame.right.shape == raw.shape == (480, 752)
    assert median_row_offset(frame.left, frame.right) < 0.5
    groundtruth = sequence.groundtruth
    assert len(groundtruth) == 40
    assert np.allclose(groundtruth.poses[0], np.eye(4))
    assert np.abs(groundtruth.positions).max() < 0.01
    assert rotation_angle(groundtruth.poses[:, :3, :3]).max() < 0.01
    assert np.diff(sequence.timestamps) == pytest.approx(0.05, abs=1e-6)


def test_euroc_flight_extract_opens_from_mav0(data_dir):
    sequence = open_sequence(require(data_dir / "euroc" / "V1_01_easy_flight" / "mav0"))
    assert (sequence.name, len(sequence), len(sequence.groundtruth)) == ("euroc_V1_01_easy_flight", 10, 10)
    assert sequence.timestamps[0] == pytest.approx(1403715297.312143104, abs=1e-6)


# ---------------------------------------------------------------- layout detection


def test_each_generated_layout_is_detected(tmp_path):
    folders = {
        "kitti_odometry": make_kitti_odometry(tmp_path / "a"),
        "kitti_raw": make_kitti_raw(tmp_path / "b"),
        "euroc": make_euroc(tmp_path / "c"),
        "generic": make_generic(tmp_path / "d", rectified_calibration()),
    }
    for layout, folder in folders.items():
        assert open_sequence(folder).layout == layout
    assert open_sequence(str(folders["euroc"] / "mav0")).layout == "euroc"


def test_missing_or_empty_folder_raises(tmp_path):
    assert "no such file or folder" in open_error(tmp_path / "nowhere")
    (tmp_path / "file.txt").write_text("x")
    assert "not a folder" in open_error(tmp_path / "file.txt")
    (tmp_path / "empty").mkdir()
    assert "empty" in open_error(tmp_path / "empty")


def test_unknown_layout_lists_the_layouts_expected(tmp_path):
    write_images(tmp_path / "pictures", ["a.png"])
    message = open_error(tmp_path)
    assert str(tmp_path) in message
    for layout in ("KITTI odometry", "KITTI raw", "EuRoC", "generic"):
        assert layout in message


# ---------------------------------------------------------------- KITTI odometry, generated


def test_kitti_odometry_generated_sequence(tmp_path):
    folder = make_kitti_odometry(tmp_path, n=3)
    poses = np.array([translation(5.0 + i, 1.0, 2.0) for i in range(3)])
    write_lines(folder / "poses.txt", kitti_pose_rows(poses))
    write_images(folder / "dynamic_masks", [f"{i:06d}.png" for i in range(3)])
    sequence = open_sequence(folder)
    camera = sequence.camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (FX, FY, CX, CY)
    assert camera.baseline == pytest.approx(BASELINE)
    assert (camera.width, camera.height) == (WIDTH, HEIGHT)
    assert sequence.name == "kitti_00"
    assert np.allclose(sequence.timestamps, [0.0, 0.1, 0.2])
    assert np.allclose(sequence.groundtruth.positions, [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert sequence.dynamic_mask(2).shape == (HEIGHT, WIDTH)
    assert sequence[1].left.shape == (HEIGHT, WIDTH)


def test_kitti_official_poses_win_and_longer_files_are_cut(tmp_path):
    folder = make_kitti_odometry(tmp_path, n=3)
    write_lines(folder / "poses.txt", kitti_pose_rows(np.array([np.eye(4)] * 3)))
    official = np.array([translation(0.0, 0.0, 2.0 * i) for i in range(5)])
    write_lines(tmp_path / "poses" / "00.txt", kitti_pose_rows(official))
    groundtruth = open_sequence(folder).groundtruth
    assert len(groundtruth) == 3
    assert np.allclose(groundtruth.positions[:, 2], [0.0, 2.0, 4.0])


def test_kitti_shorter_poses_cover_the_first_frames(tmp_path):
    folder = make_kitti_odometry(tmp_path, n=3)
    write_lines(folder / "poses.txt", kitti_pose_rows(np.array([np.eye(4), translation(1.0)])))
    groundtruth = open_sequence(folder).groundtruth
    assert np.allclose(groundtruth.timestamps, [0.0, 0.1])


@pytest.mark.parametrize(
    "break_it, expected",
    [
        (remove("calib.txt"), "calib.txt: KITTI calibration file not found"),
        (rewrite("calib.txt", f"P0: {numbers(projection())}"), "calib.txt: missing key 'P1'"),
        (rewrite("calib.txt", "P0: 1 2 3", "P1: 1 2 3"), "'P0' has 3 numbers, expected 12"),
        (rewrite("calib.txt", "P0 1 2 3"), "calib.txt:1: expected 'KEY: values'"),
        (remove("times.txt"), "times.txt: times file not found"),
        (rewrite("times.txt", "0.0", "0.1"), "times.txt: 2 times for 3 image pairs"),
        (rewrite("times.txt", "0.0", "zero", "0.2"), "times.txt:2: not a time"),
        (rewrite("times.txt", "0.0", "0.2", "0.1"), "times.txt:3: times must increase"),
        (rewrite("times.txt", "0.0", "0.1", "inf"), "times.txt:3: not a finite time: 'inf'"),
        (rewrite("times.txt", "0.0", "nan", "0.2"), "times.txt:2: not a finite time: 'nan'"),
        (remove("image_1/000002.png"), "image_0/000002.png: no image with the same name in "),
        (empty("image_1"), "image_1: no .png images"),
        (lambda f: write_images(f / "dynamic_masks", ["000000.png"]), "dynamic_masks: 1 masks for 3 frames"),
        (lambda f: [rewrite(f"image_0/{i:06d}.png", "not a png")(f) for i in range(3)],
         "image_0: no image whose size can be read, the first: "),
    ],
)
def test_kitti_odometry_bad_input(tmp_path, break_it, expected):
    folder = make_kitti_odometry(tmp_path, n=3)
    break_it(folder)
    assert expected in open_error(folder)


def test_kitti_malformed_pose_row_names_file_and_line(tmp_path):
    folder = make_kitti_odometry(tmp_path, n=3)
    write_lines(folder / "poses.txt", kitti_pose_rows(np.array([np.eye(4)])) + ["1 2 3"])
    assert "poses.txt:2" in open_error(folder, TrajectoryError)


def test_kitti_opening_reads_no_image_and_a_corrupt_frame_raises_when_read(tmp_path):
    folder = make_kitti_odometry(tmp_path, n=3)
    corrupt = folder / "image_1" / "000001.png"
    corrupt.write_bytes(b"\x89PNG garbage")
    sequence = open_sequence(folder)
    assert sequence[0].left.shape == (HEIGHT, WIDTH)
    with pytest.raises(DatasetError, match="000001.png: cannot read image"):
        sequence[1]


@pytest.mark.parametrize("sides", [("image_0", "image_1"), ("image_0",), ("image_1",)])
def test_an_image_of_another_size_than_the_calibration_raises_naming_the_file_that_differs(tmp_path, sides):
    folder = make_kitti_odometry(tmp_path, n=3)
    for side in sides:
        write_images(folder / side, ["000001.png"], size=(2 * WIDTH, HEIGHT))
    sequence = open_sequence(folder)
    with pytest.raises(DatasetError) as raised:
        sequence[1]
    assert str(raised.value) == (
        f"{folder / sides[0] / '000001.png'}: image is {2 * WIDTH}x{HEIGHT} "
        f"but the calibration is for {WIDTH}x{HEIGHT}"
    )
    assert sequence[2].left.shape == (HEIGHT, WIDTH)


@pytest.mark.parametrize(
    ("damage", "problem"),
    [("empty", "empty file"), ("missing", "No such file or directory"), ("truncated", "not an image, or corrupt")],
)
def test_an_unreadable_image_is_one_line_naming_it_and_nothing_on_stderr(tmp_path, capfd, damage, problem):
    write_images(tmp_path, ["a.png"])
    image = tmp_path / "a.png"
    if damage == "missing":
        image.unlink()
    else:  # truncated: libpng prints "libpng error: ..." itself when it decodes this
        image.write_bytes(b"" if damage == "empty" else image.read_bytes()[:-40])
    with pytest.raises(DatasetError) as raised:
        read_grey(image)
    assert str(raised.value) == f"{image}: cannot read image ({problem})"
    assert capfd.readouterr().err == ""


# ---------------------------------------------------------------- KITTI raw, generated


def test_kitti_raw_generated_drive_moves_forward_along_camera_z(tmp_path):
    sequence = open_sequence(make_kitti_raw(tmp_path, n=3, metres_east_per_frame=1.5))
    assert sequence.name == "kitti_raw_2011_01_01_drive_0001"
    assert sequence.camera.baseline == pytest.approx(BASELINE)
    assert (sequence.camera.width, sequence.camera.height) == (WIDTH, HEIGHT)
    assert sequence.timestamps[1] - sequence.timestamps[0] == pytest.approx(1.0, abs=1e-6)
    assert sequence.timestamps[0] % 60 == pytest.approx(0.100000001, abs=1e-6)
    assert np.allclose(sequence.groundtruth.positions, [[0, 0, 0], [0, 0, 1.5], [0, 0, 3.0]], atol=1e-6)
    assert np.allclose(sequence.groundtruth.poses[:, :3, :3], np.eye(3), atol=1e-9)


def test_kitti_raw_groundtruth_is_interpolated_from_the_packet_times_to_the_image_times(tmp_path):
    # Packets 1 m then 2 m apart; packet 1 was taken 40 ms after image 1, so at image 1's
    # time the unit was 1 / 1.04 of the way from packet 0 to packet 1.
    times = ["2011-01-01 00:00:00.100000001", "2011-01-01 00:00:01.140000001", "2011-01-01 00:00:02.100000001"]
    folder = make_kitti_raw(tmp_path, n=3, east=[0.0, 1.0, 3.0], packet_times=times)
    groundtruth = open_sequence(folder).groundtruth
    np.testing.assert_allclose(groundtruth.positions, [[0, 0, 0], [0, 0, 1.0 / 1.04], [0, 0, 3.0]], atol=1e-6)
    np.testing.assert_array_equal(groundtruth.timestamps, open_sequence(folder).timestamps)


def test_kitti_raw_without_oxts_has_no_groundtruth(tmp_path):
    folder = make_kitti_raw(tmp_path)
    for packet in (folder / "oxts" / "data").iterdir():
        packet.unlink()
    (folder / "oxts" / "data").rmdir()
    assert open_sequence(folder).groundtruth is None


@pytest.mark.parametrize(
    "break_it, expected",
    [
        (remove("../calib_cam_to_cam.txt"), "calib_cam_to_cam.txt: KITTI calibration file not found"),
        (remove("../calib_velo_to_cam.txt"), "calib_velo_to_cam.txt: KITTI calibration file not found"),
        (rewrite("../calib_cam_to_cam.txt", f"S_rect_00: {WIDTH} {HEIGHT}",
                 f"P_rect_00: {numbers(projection())}"),
         "calib_cam_to_cam.txt: missing key 'P_rect_01'"),
        (rewrite("image_00/timestamps.txt", "2011-01-01 00:00:00.1"),
         "timestamps.txt: 1 times for 3 image pairs"),
        (rewrite("image_00/timestamps.txt", "2011-01-01 00:00:00.1", "yesterday", "2011-01-01 00:00:02"),
         "timestamps.txt:2: not a time"),
        (rewrite("image_00/timestamps.txt", "2011-01-01 00:00:00.1", "NaT", "2011-01-01 00:00:02"),
         "timestamps.txt:2: not a time: 'NaT'"),
        (rewrite("oxts/data/0000000001.txt", "49.0 nan 110 0 0 0"),
         "0000000001.txt: OXTS packet's lon is 'nan', not a finite number"),
        (remove("oxts/data/0000000002.txt"), "oxts/data: 2 OXTS packets for 3 frames"),
        (rewrite("oxts/data/0000000001.txt", "49.0 8.4"), "0000000001.txt: OXTS packet has 2 fields"),
        (rewrite("oxts/timestamps.txt", "2011-01-01 00:00:00.100000001", "2011-01-01 00:00:01.160000001",
                 "2011-01-01 00:00:02.100000001"),
         "oxts/timestamps.txt: packet 1 is 60 ms from image 1 (of "),
        (rewrite("oxts/timestamps.txt", "2011-01-01 00:00:00.100000001"), "oxts/timestamps.txt: 1 times for 3"),
        (empty("image_01/data"), "image_01/data: no .png images"),
        (rewrite("../calib_cam_to_cam.txt", f"S_rect_00: {WIDTH} {HEIGHT}", f"R_rect_00: {numbers(np.eye(3))}",
                 f"P_rect_00: {numbers(projection())}",
                 f"P_rect_01: {numbers(projection(BASELINE)).replace(numbers(FY), 'nan', 1)}"),
         "calib_cam_to_cam.txt: fy of P_rect_01 is nan, not a finite number"),
        (rewrite("../calib_cam_to_cam.txt", f"S_rect_00: {CX - 1:g} {HEIGHT}", f"R_rect_00: {numbers(np.eye(3))}",
                 f"P_rect_00: {numbers(projection())}", f"P_rect_01: {numbers(projection(BASELINE))}"),
         f"calib_cam_to_cam.txt: cx of P_rect_00 is {CX:g}, outside the image (0 to its width, {CX - 1:g} px)"),
    ],
)
def test_kitti_raw_bad_input(tmp_path, break_it, expected):
    folder = make_kitti_raw(tmp_path)
    break_it(folder)
    assert expected in open_error(folder)


# ---------------------------------------------------------------- EuRoC, generated


def test_euroc_generated_sequence_groundtruth_in_the_rectified_left_camera(tmp_path):
    sequence = open_sequence(make_euroc(tmp_path, n=3))
    assert sequence.name == "euroc_MH_00"
    assert sequence.camera.baseline == pytest.approx(BASELINE)
    assert sequence[2].left.shape == (HEIGHT, WIDTH)
    assert np.allclose(np.diff(sequence.timestamps), 0.05, atol=1e-6)
    assert np.allclose(sequence.groundtruth.positions, [[0, 0, 0], [0, 0, 0.1], [0, 0, 0.2]], atol=1e-6)


def test_euroc_groundtruth_rows_are_matched_to_frames_within_5_ms(tmp_path):
    folder = make_euroc(tmp_path, n=3)
    start = int((folder / "mav0" / "cam0" / "data.csv").read_text().splitlines()[1].split(",")[0])
    offsets_ns = [3_000_000, 50_000_000 - 4_000_000, 100_000_000 + 20_000_000]
    write_lines(
        folder / "mav0" / "state_groundtruth_estimate0" / "data.csv",
        [f"{start + offset},{i},0,0,1,0,0,0" for i, offset in enumerate(offsets_ns)],
    )
    sequence = open_sequence(folder)
    assert np.array_equal(sequence.groundtruth.timestamps, sequence.timestamps[:2])
    far = [f"{start + 10**9 * (i + 1)},0,0,0,1,0,0,0" for i in range(2)]
    write_lines(folder / "mav0" / "state_groundtruth_estimate0" / "data.csv", far)
    assert "no ground-truth pose within 5 ms" in open_error(folder)


def drop_last_row(relative: str):
    """A folder change: delete the last line of the file ``relative``."""

    def change(folder: Path) -> None:
        path = folder / relative
        path.write_text("\n".join(path.read_text().splitlines()[:-1]) + "\n")

    return change


def shift_first_timestamp(relative: str):
    """A folder change: move the first timestamp of the image list ``relative`` by 1 ns."""

    def change(folder: Path) -> None:
        path = folder / relative
        path.write_text(path.read_text().replace("976,", "977,", 1))

    return change


@pytest.mark.parametrize(
    "break_it, expected",
    [
        (drop_last_row("cam1/data.csv"), "cam0/data/1403715273362142976.png: no image with the same timestamp in "),
        (shift_first_timestamp("cam1/data.csv"), "cam0/data/1403715273262142976.png: no image with the same timestamp"),
        (remove("cam0/data.csv"), "cam0/data.csv: image list not found"),
        (rewrite("cam0/data.csv", "#timestamp [ns],filename", "12;a.png"), "cam0/data.csv:2: expected"),
        (remove("cam1/sensor.yaml"), "cam1/sensor.yaml: YAML calibration file not found"),
        (rewrite("cam0/sensor.yaml", sensor_yaml(np.eye(4)).replace("intrinsics", "intrinsic")),
         "sensor.yaml: missing key 'intrinsics'"),
        (rewrite("cam0/sensor.yaml", sensor_yaml(np.eye(4), "equidistant")),
         "'distortion_model' is 'equidistant'"),
        (rewrite("cam0/sensor.yaml", "%YAML:1.0", "T_BS: [1, 2"), "sensor.yaml: not valid YAML"),
        (rewrite("cam1/sensor.yaml", sensor_yaml(translation(BASELINE)).replace(f"[{WIDTH},", "[64,")),
         "cam1/sensor.yaml: resolution (64, 24) differs from cam0's (32, 24)"),
        (rewrite("cam1/sensor.yaml", sensor_yaml(translation(BASELINE)).replace(f"[{FX},", "[.nan,")),
         "cam1/sensor.yaml: fu of intrinsics is nan, not a finite number"),
        (rewrite("cam0/sensor.yaml", sensor_yaml(np.eye(4)).replace(f"{CY}]", f"{HEIGHT + 1.0}]")),
         f"cam0/sensor.yaml: cy of intrinsics is {HEIGHT + 1}, outside the image (0 to its height, {HEIGHT} px)"),
    ],
)
def test_euroc_bad_input(tmp_path, break_it, expected):
    folder = make_euroc(tmp_path, n=3)
    break_it(folder / "mav0")
    assert expected in open_error(folder)


def test_euroc_malformed_groundtruth_row_names_file_and_line(tmp_path):
    folder = make_euroc(tmp_path, n=3)
    with (folder / "mav0" / "state_groundtruth_estimate0" / "data.csv").open("a") as file:
        file.write("123,not,a,pose,1,0,0,0\n")
    assert "data.csv:5" in open_error(folder, TrajectoryError)


# ---------------------------------------------------------------- generic, generated


def test_generic_rectified_rig(tmp_path):
    calibration = rectified_calibration() | {"fps": 20}
    sequence = open_sequence(make_generic(tmp_path, calibration, n=3, suffix=".jpg"))
    assert (sequence.name, sequence.layout, sequence.rectifier) == ("my_rig", "generic", None)
    camera = sequence.camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (FX, FY, CX, CY)
    assert (camera.width, camera.height) == (WIDTH, HEIGHT)
    assert camera.baseline == pytest.approx(BASELINE)
    assert np.allclose(sequence.timestamps, [0.0, 0.05, 0.1])
    assert sequence.groundtruth is None
    assert sequence[2].left.shape == (HEIGHT, WIDTH)


def test_generic_times_default_to_10_hz_and_times_txt_wins(tmp_path):
    folder = make_generic(tmp_path, rectified_calibration(), n=3)
    assert np.allclose(open_sequence(folder).timestamps, [0.0, 0.1, 0.2])
    write_lines(folder / "times.txt", ["10.0", "10.5", "11.25"])
    assert np.allclose(open_sequence(folder).timestamps, [10.0, 10.5, 11.25])


def gaussian_blobs(centres: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """A raw (RAW_HEIGHT, RAW_WIDTH) uint8 image of bright Gaussian blobs at subpixel ``centres`` (N, 2)."""
    v, u = np.mgrid[0:RAW_HEIGHT, 0:RAW_WIDTH]
    image = np.zeros((RAW_HEIGHT, RAW_WIDTH))
    for cu, cv in centres:
        image += 255.0 * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2.0 * sigma**2))
    return np.clip(image, 0, 255).astype(np.uint8)


def blob_centres(image: np.ndarray) -> np.ndarray:
    """Intensity-weighted centres (N, 2) of the bright blobs of ``image``, sorted by u."""
    count, labels = cv2.connectedComponents((image > 20).astype(np.uint8))
    v, u = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    weights = image.astype(np.float64)
    centres = []
    for label in range(1, count):
        w = weights * (labels == label)
        centres.append([(w * u).sum() / w.sum(), (w * v).sum() / w.sum()])
    return np.array(sorted(centres))


def test_generic_unrectified_rig_is_rectified_row_aligned(tmp_path):
    folder = make_generic(tmp_path, RAW_RIG, n=2, size=(RAW_WIDTH, RAW_HEIGHT))
    points_left = np.array([[-0.6, -0.3, 3.0], [0.0, 0.2, 4.0], [0.7, 0.1, 5.0]])
    R, t = np.array(RAW_RIG["R"]), np.array(RAW_RIG["t"])
    raw = {}
    for side, rvec, tvec in (("left", np.zeros(3), np.zeros(3)), ("right", cv2.Rodrigues(R)[0], t)):
        K, distortion = np.array(RAW_RIG[side]["K"]), np.array(RAW_RIG[side]["distortion"])
        raw[side] = cv2.projectPoints(points_left, rvec, tvec, K, distortion)[0].reshape(-1, 2)
        cv2.imwrite(str(folder / side / "0000.png"), gaussian_blobs(raw[side]))
    assert np.abs(raw["left"][:, 1] - raw["right"][:, 1]).max() > 2.0  # not aligned before

    sequence = open_sequence(folder)
    camera = sequence.camera
    assert camera.baseline == pytest.approx(np.linalg.norm(t), rel=1e-9)
    frame = sequence[0]
    assert frame.left.shape == (RAW_HEIGHT, RAW_WIDTH)
    left, right = blob_centres(frame.left), blob_centres(frame.right)
    assert np.abs(left[:, 1] - right[:, 1]).max() < 0.1
    expected = camera.project_stereo(points_left @ sequence.rectifier.R_rect_raw.T)
    assert np.allclose(left, expected[:, :2], atol=0.1)
    assert np.allclose(right[:, 0], expected[:, 2], atol=0.1)


def test_generic_groundtruth_is_turned_into_the_rectified_left_camera(tmp_path):
    folder = make_generic(tmp_path, RAW_RIG, n=3, size=(RAW_WIDTH, RAW_HEIGHT))
    write_lines(folder / "groundtruth.txt", [f"{0.1 * i:.3f} {i + 3.0} 1 2 0 0 0 1" for i in range(3)])
    sequence = open_sequence(folder)
    R_rect_raw = sequence.rectifier.R_rect_raw
    assert np.allclose(sequence.groundtruth.positions, np.outer([0, 1, 2], R_rect_raw[:, 0]))
    assert np.allclose(sequence.groundtruth.poses[:, :3, :3], np.eye(3))


def test_generic_groundtruth_of_another_frame_is_moved_to_the_camera_with_T_gt_left(tmp_path):
    """Body poses stepping along the body's x axis: the camera, looking along it, steps along its z."""
    T_body_left = make_pose(B_FROM_CAM0, np.array([0.2, 0.0, 0.1]))
    folder = make_generic(tmp_path, rectified_calibration() | {"T_gt_left": T_body_left.tolist()}, n=3)
    write_lines(folder / "groundtruth.txt", [f"{0.1 * i:.3f} {0.5 * i} 0 0 0 0 0 1" for i in range(3)])
    groundtruth = open_sequence(folder).groundtruth
    np.testing.assert_allclose(groundtruth.positions, [[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0]], atol=1e-12)


def test_generic_opening_reads_no_image_and_a_corrupt_frame_raises_when_read(tmp_path):
    folder = make_generic(tmp_path, RAW_RIG, n=2, size=(RAW_WIDTH, RAW_HEIGHT))
    (folder / "left" / "0000.png").write_bytes(b"")
    sequence = open_sequence(folder)
    with pytest.raises(DatasetError, match="0000.png: cannot read image"):
        sequence[0]
    assert sequence[1].left.shape == (RAW_HEIGHT, RAW_WIDTH)


def test_generic_image_size_other_than_calibrated_raises_when_read(tmp_path):
    sequence = open_sequence(make_generic(tmp_path, RAW_RIG, n=2, size=(WIDTH, HEIGHT)))
    with pytest.raises(DatasetError, match="left/0000.png: image is 32x24 but the calibration is for 320x240"):
        sequence[0]


def without(mapping: dict, dotted_key: str) -> dict:
    """A deep copy of ``mapping`` without ``dotted_key``."""
    copy = yaml.safe_load(yaml.safe_dump(mapping))
    *parents, last = dotted_key.split(".")
    node = copy
    for parent in parents:
        node = node[parent]
    del node[last]
    return copy


@pytest.mark.parametrize(
    "calibration, expected",
    [
        (without(RAW_RIG, "right.K"), "calib.yaml: missing key 'right.K'"),
        (without(RAW_RIG, "image_size"), "calib.yaml: missing key 'image_size'"),
        (without(rectified_calibration(), "t"), "calib.yaml: missing key 't'"),
        (RAW_RIG | {"R": np.diag([1.0, 1.0, 2.0]).tolist()}, "'R' is not a rotation matrix"),
        (RAW_RIG | {"left": {"K": RAW_RIG["left"]["K"], "distortion": [0.1, 0.2, 0.3]}},
         "'left.distortion' has 3 numbers, expected 4 or 5"),
        (RAW_RIG | {"t": [0.12, 0.0, 0.0]}, "the right camera is not to the right"),
        (rectified_calibration() | {"t": [BASELINE, 0.0, 0.0]}, "the right camera is not to the right"),
        (rectified_calibration() | {"rectified": "yes"}, "'rectified' must be true or false"),
        (rectified_calibration() | {"fps": -5}, "'fps' must be positive"),
        (rectified_calibration() | {"T_gt_left": np.ones((4, 4)).tolist()},
         "'T_gt_left' must end with the row 0 0 0 1"),
        (rectified_calibration() | {"T_gt_left": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()},
         "'T_gt_left' is not a rotation matrix"),
        (rectified_calibration() | {"image_size": [32.5, 24]},
         "'image_size' must be two positive whole numbers"),
        (rectified_calibration() | {"left": {"K": "fx fy"}}, "'left.K' is not a list of numbers"),
        (["not", "a", "mapping"], "calib.yaml: expected a YAML mapping"),
        (rectified_calibration() | {"left": {"K": [[FX, 0.0, CX], [0.0, float("nan"), CY], [0.0, 0.0, 1.0]]}},
         "calib.yaml: fy of left.K is nan, not a finite number"),
        (rectified_calibration() | {"left": {"K": [[-FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]]}},
         f"calib.yaml: fx of left.K is {-FX:g}; a focal length must be positive"),
        (RAW_RIG | {"right": {"K": [[305.0, 0.0, 500.0], [0.0, 302.0, 126.0], [0.0, 0.0, 1.0]],
                              "distortion": [0.0, 0.0, 0.0, 0.0]}},
         "calib.yaml: cx of right.K is 500, outside the image (0 to its width, 320 px)"),
        (RAW_RIG | {"R": [[1.0, 0.0, 0.0], [0.0, 1.0, float("inf")], [0.0, 0.0, 1.0]]},
         "calib.yaml: R[1, 2] is inf, not a finite number"),
        (rectified_calibration() | {"t": [-BASELINE, float("-inf"), 0.0]},
         "calib.yaml: t[1] is -inf, not a finite number"),
        (rectified_calibration() | {"fps": float("inf")}, "calib.yaml: fps is inf, not a finite number"),
    ],
)
def test_generic_bad_calibration(tmp_path, calibration, expected):
    assert expected in open_error(make_generic(tmp_path, calibration))


@pytest.mark.parametrize(
    "break_it, expected",
    [
        (remove("calib.yaml"), "calib.yaml: YAML calibration file not found"),
        (remove("right/0002.png"), "left/0002.png: no image with the same name in "),
        (empty("right"), "right: no .png or .jpg or .jpeg images"),
        (rewrite("times.txt", "0.0"), "times.txt: 1 times for 3 image pairs"),
        (rewrite("groundtruth.txt", "0.0 1 2 3 0 0 0 1", "0.1 1 2"), "groundtruth.txt:2"),
    ],
)
def test_generic_bad_folder(tmp_path, break_it, expected):
    folder = make_generic(tmp_path, rectified_calibration(), n=3)
    break_it(folder)
    error = TrajectoryError if "groundtruth" in expected else DatasetError
    assert expected in open_error(folder, error)


# ---------------------------------------------------------------- left/right pairing


def rename(relative: str, new_name: str):
    """A folder change: give the file ``relative`` the name ``new_name`` in its folder."""
    return lambda folder: (folder / relative).rename((folder / relative).with_name(new_name))


def drop_both(left: str, right: str):
    """A folder change: delete another frame on each side, so that the counts stay equal."""
    return lambda folder: (remove(left)(folder), remove(right)(folder))


@pytest.mark.parametrize(
    "make, break_it, unpaired, other",
    [
        (make_kitti_odometry, drop_both("image_0/000001.png", "image_1/000002.png"), "image_1/000001.png", "image_0"),
        (make_kitti_raw, drop_both("image_00/data/0000000002.png", "image_01/data/0000000003.png"),
         "image_01/data/0000000002.png", "image_00/data"),
        (lambda root, n: make_generic(root, rectified_calibration(), n=n), rename("right/0001.png", "0004.png"),
         "left/0001.png", "right"),
    ],
)
def test_folder_layouts_pair_images_by_name(tmp_path, make, break_it, unpaired, other):
    folder = make(tmp_path, n=4)
    break_it(folder)
    message = open_error(folder)
    assert f"{unpaired}: no image with the same name in " in message
    assert message.endswith(f"/{other}")


def test_euroc_pairs_images_by_timestamp(tmp_path):
    folder = make_euroc(tmp_path, n=4)
    mav0 = folder / "mav0"
    for camera, dropped in (("cam0", 1), ("cam1", 2)):  # a frame missing on each side, counts equal
        csv = mav0 / camera / "data.csv"
        lines = csv.read_text().splitlines()
        csv.write_text("\n".join(lines[: dropped + 1] + lines[dropped + 2:]) + "\n")
    message = open_error(folder)
    assert "cam1/data/1403715273312142976.png: no image with the same timestamp in " in message
    assert message.endswith(f"cam0/data.csv; 1403715273312142976.png is listed in {mav0 / 'cam1' / 'data.csv'}")


def unpad_names(folder: Path) -> None:
    """Rename each file ``000012.png`` of ``folder`` to ``12.png`` (names without zero padding)."""
    for path in folder.iterdir():
        path.rename(path.with_name(f"{int(path.stem)}{path.suffix}"))


@pytest.mark.parametrize(
    "make, folders",
    [
        (lambda root, n: make_generic(root, rectified_calibration(), n=n), ["left", "right"]),
        (make_kitti_odometry, ["image_0", "image_1"]),
        (make_kitti_raw, ["image_00/data", "image_01/data", "oxts/data"]),
    ],
)
def test_frames_named_without_zero_padding_are_read_in_numeric_order(tmp_path, make, folders):
    folder = make(tmp_path, n=12)
    for relative in folders:
        unpad_names(folder / relative)
    frames = open_sequence(folder).frames
    for paths in (frames.left_paths, frames.right_paths):
        assert [path.name for path in paths] == [f"{i}.png" for i in range(12)]


def test_kitti_raw_oxts_packets_named_without_zero_padding_follow_the_frames(tmp_path):
    folder = make_kitti_raw(tmp_path, n=12)
    for relative in ("image_00/data", "image_01/data", "oxts/data"):
        unpad_names(folder / relative)
    forward = open_sequence(folder).groundtruth.positions[:, 2]
    np.testing.assert_allclose(forward, np.arange(12.0), atol=1e-6)


# ---------------------------------------------------------------- frame rate and scaling


def test_each_folder_layout_reports_its_nominal_frame_rate(tmp_path):
    rates = {
        "kitti_odometry": open_sequence(make_kitti_odometry(tmp_path / "a")).frame_rate,
        "kitti_raw": open_sequence(make_kitti_raw(tmp_path / "b")).frame_rate,
        "euroc": open_sequence(make_euroc(tmp_path / "c")).frame_rate,
    }
    assert {layout: (rate.hz, rate.source) for layout, rate in rates.items()} == {
        "kitti_odometry": (10.0, "KITTI nominal rate"),
        "kitti_raw": (10.0, "KITTI nominal rate"),
        "euroc": (20.0, "EuRoC nominal rate"),
    }


def test_a_synthetic_sequence_takes_its_rate_from_synth_json(tmp_path):
    folder = make_kitti_odometry(tmp_path)
    (folder / "synth.json").write_text('{"scenario": "static", "frame_rate": 7.5}')
    sequence = open_sequence(folder)
    assert (sequence.name, sequence.frame_rate.hz, sequence.frame_rate.source) == (
        "synth_static", 7.5, "frame_rate of synth.json")


def test_a_synth_json_rate_that_is_not_finite_gives_way_to_the_median_time_step(tmp_path):
    folder = make_kitti_odometry(tmp_path)
    (folder / "synth.json").write_text('{"scenario": "static", "frame_rate": Infinity}')
    rate = open_sequence(folder).frame_rate
    assert (rate.hz, rate.source) == (pytest.approx(10.0), "median step of times.txt")


@pytest.mark.parametrize(
    "fps, times, expected",
    [
        (12, None, (12.0, "fps of calib.yaml")),
        (12, ["0.0", "0.5", "1.0"], (12.0, "fps of calib.yaml")),
        (None, ["0.0", "0.5", "1.25"], (1 / 0.625, "median step of times.txt")),
        (None, None, (10.0, "default rate (no fps in calib.yaml, no times.txt)")),
    ],
)
def test_generic_rate_is_fps_else_the_median_time_step_else_10_hz(tmp_path, fps, times, expected):
    calibration = rectified_calibration() | ({} if fps is None else {"fps": fps})
    folder = make_generic(tmp_path, calibration, n=3)
    if times is not None:
        write_lines(folder / "times.txt", times)
    rate = open_sequence(folder).frame_rate
    assert (rate.hz, rate.source) == pytest.approx(expected)


def test_every_second_frame_runs_at_half_the_rate(tmp_path):
    part = open_sequence(make_kitti_odometry(tmp_path, n=5)).subsequence(1, 2)
    assert (part.frame_rate.hz, part.frame_rate.source) == (5.0, "KITTI nominal rate, every 2 frames")
    assert len(part) == 2 and part.frames.left_paths[1].name == "000003.png"


def test_scaled_frames_and_camera_agree_where_a_point_projects(tmp_path):
    """Blobs at known 3D points land where the scaled camera projects them, to a tenth of a pixel."""
    calibration = rectified_calibration() | {"image_size": [RAW_WIDTH, RAW_HEIGHT],
                                             "left": {"K": RAW_RIG["left"]["K"]}}
    folder = make_generic(tmp_path, calibration, n=1, size=(RAW_WIDTH, RAW_HEIGHT))
    sequence = open_sequence(folder)
    points = np.array([[-0.6, -0.3, 3.0], [0.0, 0.2, 4.0], [0.7, 0.1, 5.0]])
    full = sequence.camera.project_stereo(points)
    cv2.imwrite(str(folder / "left" / "0000.png"), gaussian_blobs(full[:, :2], sigma=3.0))
    cv2.imwrite(str(folder / "right" / "0000.png"), gaussian_blobs(full[:, [2, 1]], sigma=3.0))
    half = sequence.scaled(0.5)
    assert (half.scale, half.camera.size, half.camera.baseline) == (0.5, (160, 120), sequence.camera.baseline)
    frame = half[0]
    assert frame.left.shape == frame.right.shape == (120, 160)
    expected = half.camera.project_stereo(points)
    np.testing.assert_allclose(blob_centres(frame.left), expected[:, :2], atol=0.1)
    np.testing.assert_allclose(blob_centres(frame.right)[:, 0], expected[:, 2], atol=0.1)
    assert half.scaled(0.5).camera.size == (80, 60) and half.scaled(0.5).scale == 0.25
    assert sequence.scaled(1.0) is sequence
    with pytest.raises(DatasetError, match="scale must be in \\(0, 1\\], got 1.5"):
        sequence.scaled(1.5)


def test_scaled_dynamic_masks_follow_the_frames(tmp_path):
    folder = make_kitti_odometry(tmp_path, n=2)
    write_images(folder / "dynamic_masks", ["000000.png", "000001.png"])
    half = open_sequence(folder).scaled(0.5)
    assert half.dynamic_mask(1).shape == half[1].left.shape == (HEIGHT // 2, WIDTH // 2)
