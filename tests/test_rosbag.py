"""The ROS bag loader, on bags written here with ``rosbags`` (ROS 1, ROS 2 sqlite3, ROS 2 mcap).

The EuRoC check writes the shared V1_01 extract as EuRoC's own bags hold it (raw mono8
images on ``/cam0/image_raw`` and ``/cam1/image_raw``, no CameraInfo) and compares what
the bag gives with what the ASL folder gives.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from conftest import require
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation
from test_datasets import (
    RAW_HEIGHT,
    RAW_RIG,
    RAW_WIDTH,
    gaussian_blobs,
    make_generic,
    open_error,
    rectified_calibration,
)

from pld_slam.datasets import BagOptions, open_sequence
from pld_slam.datasets.base import read_grey
from pld_slam.datasets.euroc import read_camera_sensor
from pld_slam.datasets.rectify import RECTIFY_ALPHA
from pld_slam.datasets.rosbag import PAIR_TOLERANCE_NS, camera_info_topic, raw_grey
from pld_slam.errors import DatasetError
from pld_slam.geometry.se3 import inverse, make_pose
from pld_slam.io.trajectory import read_kitti
from pld_slam.synth.writer import write_sequence
from pld_slam_cli.main import EXIT_USER_ERROR, cli

KINDS = ("ros1", "sqlite3", "mcap")
START_NS = 1_600_000_000_123_456_789
PERIOD_NS = 50_000_000  # 20 Hz
WIDTH, HEIGHT = 32, 24
FX, FY, CX, CY, BASELINE = 40.0, 41.0, 15.5, 11.5, 0.12


class Messages:
    """Messages of one bag kind: ROS 1 and ROS 2 differ in the header (``seq``) and CameraInfo (``K`` / ``k``)."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
        self.types = self.store.types

    def header(self, stamp_ns: int):
        stamp = self.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        extra = {"seq": 0} if self.kind == "ros1" else {}
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera", **extra)

    def image(self, stamp_ns: int, image: np.ndarray, encoding: str = "mono8"):
        height, width = image.shape[:2]
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(stamp_ns), height=height, width=width, encoding=encoding, is_bigendian=0,
            step=image.nbytes // height, data=image.reshape(-1).view(np.uint8),
        )

    def compressed(self, stamp_ns: int, data: np.ndarray):
        return self.types["sensor_msgs/msg/CompressedImage"](header=self.header(stamp_ns), format="png", data=data)

    def camera_info(self, size, K, D, R, P, model: str = "plumb_bob"):
        roi = self.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        matrices = {"d": np.ravel(D), "k": np.ravel(K), "r": np.ravel(R), "p": np.ravel(P)}
        if self.kind == "ros1":
            matrices = {name.upper(): value for name, value in matrices.items()}
        return self.types["sensor_msgs/msg/CameraInfo"](
            header=self.header(START_NS), width=size[0], height=size[1], distortion_model=model,
            binning_x=0, binning_y=0, roi=roi, **matrices,
        )

    def pose(self, msgtype: str, stamp_ns: int, T: np.ndarray, quaternion=None):
        """A pose message of ``msgtype`` (PoseStamped, TransformStamped or Odometry) holding ``T``."""
        types = self.types
        x, y, z = T[:3, 3]
        qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat() if quaternion is None else quaternion
        rotation = types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
        if msgtype == "geometry_msgs/msg/TransformStamped":
            transform = types["geometry_msgs/msg/Transform"](
                translation=types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z), rotation=rotation)
            return types[msgtype](header=self.header(stamp_ns), child_frame_id="body", transform=transform)
        pose = types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                                               orientation=rotation)
        if msgtype == "geometry_msgs/msg/PoseStamped":
            return types[msgtype](header=self.header(stamp_ns), pose=pose)
        zero = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        twist = types["geometry_msgs/msg/TwistWithCovariance"](
            twist=types["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36))
        return types[msgtype](
            header=self.header(stamp_ns), child_frame_id="body",
            pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)), twist=twist,
        )


def write_bag(folder: Path, kind: str, messages: list[tuple[str, str, int, object]]) -> Path:
    """A bag of ``kind`` in ``folder`` holding ``(topic, type, record time [ns], message)``, written in time order."""
    store = Messages(kind).store
    path = folder / ("recording.bag" if kind == "ros1" else f"recording_{kind}")
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    writer = Ros1Writer(path) if kind == "ros1" else Ros2Writer(path, version=9, storage_plugin=plugin)
    with writer:
        connections = {}
        for topic, msgtype, record_ns, message in sorted(messages, key=lambda m: m[2]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            data = store.serialize_ros1(message, msgtype) if kind == "ros1" else store.serialize_cdr(message, msgtype)
            writer.write(connections[topic], record_ns, data)
    return path


IMAGE, COMPRESSED, INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"


def random_images(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8) for _ in range(n)]


def rectified_views() -> tuple[tuple, tuple]:
    """(K, D, R, P) of a rectified left and right camera (P of the right one at -fx * baseline)."""
    K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
    P_left = np.hstack([K, np.zeros((3, 1))])
    P_right = P_left + np.array([[0, 0, 0, -FX * BASELINE], [0, 0, 0, 0], [0, 0, 0, 0]])
    return (K, np.zeros(5), np.eye(3), P_left), (K, np.zeros(5), np.eye(3), P_right)


def stereo_messages(kind: str, n: int = 4, topics=("/stereo/left/image_rect", "/stereo/right/image_rect"),
                    right_offset_ns: int = 0, compressed: bool = False, camera_info: bool = True):
    """Messages of n random stereo pairs at 20 Hz on ``topics``, with their CameraInfo (rectified rig)."""
    make = Messages(kind)
    messages = []
    for topic, images, offset, view in zip(topics, (random_images(n, 0), random_images(n, 1)),
                                           (0, right_offset_ns), rectified_views(), strict=True):
        for i, image in enumerate(images):
            stamp = START_NS + i * PERIOD_NS + offset
            message = make.compressed(stamp, cv2.imencode(".png", image)[1].ravel()) if compressed \
                else make.image(stamp, image)
            messages.append((topic, COMPRESSED if compressed else IMAGE, stamp + 1000, message))
        if camera_info:
            messages.append((camera_info_topic(topic), INFO, START_NS, make.camera_info((WIDTH, HEIGHT), *view)))
    return messages


# ---------------------------------------------------------------- EuRoC: the bag gives what the ASL folder gives


def euroc_bag(asl: Path, folder: Path, kind: str) -> Path:
    """The ASL extract as a bag: raw images on /camK/image_raw at their stamps, body ground truth on /groundtruth."""
    make = Messages(kind)
    mav0 = asl / "mav0"
    messages = []
    for camera in ("cam0", "cam1"):
        for line in (mav0 / camera / "data.csv").read_text().splitlines()[1:]:
            stamp, name = line.split(",")
            image = make.image(int(stamp), read_grey(mav0 / camera / "data" / name))
            messages.append((f"/{camera}/image_raw", IMAGE, int(stamp), image))
    for line in (mav0 / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()[1:]:
        stamp, x, y, z, qw, qx, qy, qz = (float(v) for v in line.split(",")[:8])
        pose = make.pose("geometry_msgs/msg/PoseStamped", int(line.split(",")[0]), make_pose(np.eye(3), [x, y, z]),
                         quaternion=(qx, qy, qz, qw))
        messages.append(("/groundtruth", "geometry_msgs/msg/PoseStamped", int(line.split(",")[0]), pose))
    return write_bag(folder, kind, messages)


def euroc_calib_yaml(asl: Path, path: Path) -> Path:
    """The two ``sensor.yaml`` as one generic ``calib.yaml``, with cam0's ``T_BS`` as ``T_gt_left``."""
    left, right = (read_camera_sensor(asl / "mav0" / camera / "sensor.yaml") for camera in ("cam0", "cam1"))
    T_right_left = inverse(right.T_B_S) @ left.T_B_S
    calibration = {
        "image_size": list(left.size),
        "left": {"K": left.K.tolist(), "distortion": left.distortion.tolist()},
        "right": {"K": right.K.tolist(), "distortion": right.distortion.tolist()},
        "R": T_right_left[:3, :3].tolist(), "t": T_right_left[:3, 3].tolist(), "T_gt_left": left.T_B_S.tolist(),
    }
    path.write_text(yaml.safe_dump(calibration))
    return path


@pytest.mark.parametrize("kind", KINDS)
def test_euroc_bag_gives_the_asl_folders_frames_times_and_trajectory(data_dir, tmp_path, kind):
    asl = require(data_dir / "euroc" / "V1_01_easy_flight")
    bag = euroc_bag(asl, tmp_path, kind)
    calib = euroc_calib_yaml(asl, tmp_path / "calib.yaml")
    from_bag = open_sequence(bag, BagOptions(groundtruth_topic="/groundtruth", calibration=calib))
    from_folder = open_sequence(asl)
    assert (from_bag.layout, len(from_bag)) == ("rosbag", len(from_folder)) == ("rosbag", 10)
    assert from_bag.camera == from_folder.camera
    np.testing.assert_array_equal(from_bag.timestamps, from_folder.timestamps)
    for bag_frame, folder_frame in zip(from_bag, from_folder, strict=True):
        np.testing.assert_array_equal(bag_frame.left, folder_frame.left)
        np.testing.assert_array_equal(bag_frame.right, folder_frame.right)
    np.testing.assert_array_equal(from_bag.groundtruth.timestamps, from_folder.groundtruth.timestamps)
    np.testing.assert_allclose(from_bag.groundtruth.poses, from_folder.groundtruth.poses, atol=1e-12)
    assert from_bag.frame_rate.hz == pytest.approx(20.0, rel=1e-3)
    assert from_bag.frame_rate.source == "median step of the left image stamps"


# ---------------------------------------------------------------- CameraInfo


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("compressed", [False, True])
def test_rectified_topics_take_the_camera_from_camera_info_projections(tmp_path, kind, compressed):
    bag = write_bag(tmp_path, kind, stereo_messages(kind, n=4, compressed=compressed))
    sequence = open_sequence(bag)
    camera = sequence.camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.size) == (FX, FY, CX, CY, (WIDTH, HEIGHT))
    assert camera.baseline == pytest.approx(BASELINE)
    assert sequence.rectifier is None and sequence.groundtruth is None
    np.testing.assert_array_equal(sequence.timestamps, (START_NS + PERIOD_NS * np.arange(4)) / 1e9)
    assert sequence.frame_rate.hz == pytest.approx(20.0)
    assert sequence.name == bag.stem if kind == "ros1" else bag.name
    for frame, left, right in zip(sequence, random_images(4, 0), random_images(4, 1), strict=True):
        np.testing.assert_array_equal(frame.left, left)
        np.testing.assert_array_equal(frame.right, right)


def test_raw_topics_are_rectified_with_camera_info_as_the_generic_rig_is(tmp_path):
    """CameraInfo holding stereoRectify's R and P for a distorted rig gives the frames the generic folder gives."""
    K = [np.array(RAW_RIG[side]["K"]) for side in ("left", "right")]
    D = [np.array(RAW_RIG[side]["distortion"]) for side in ("left", "right")]
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K[0], D[0], K[1], D[1], (RAW_WIDTH, RAW_HEIGHT), np.array(RAW_RIG["R"]),
                                           np.array(RAW_RIG["t"]).reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY,
                                           alpha=RECTIFY_ALPHA)
    folder = make_generic(tmp_path / "generic", RAW_RIG, n=2, size=(RAW_WIDTH, RAW_HEIGHT))
    blobs = np.array([[60.0, 50.0], [160.0, 120.0], [250.0, 190.0]])
    make = Messages("ros1")
    messages = []
    for side, topic, R, P in (("left", "/cam0/image_raw", R1, P1), ("right", "/cam1/image_raw", R2, P2)):
        image = gaussian_blobs(blobs + (0.0 if side == "left" else -8.0))
        for i in range(2):
            cv2.imwrite(str(folder / side / f"{i:04d}.png"), image)
            messages.append((topic, IMAGE, START_NS + i * PERIOD_NS, make.image(START_NS + i * PERIOD_NS, image)))
        info = make.camera_info((RAW_WIDTH, RAW_HEIGHT), K[side == "right"], D[side == "right"], R, P)
        messages.append((camera_info_topic(topic), INFO, START_NS, info))
    from_bag = open_sequence(write_bag(tmp_path, "ros1", messages))
    from_folder = open_sequence(folder)
    assert from_bag.camera == from_folder.camera
    np.testing.assert_allclose(from_bag.rectifier.R_rect_raw, from_folder.rectifier.R_rect_raw)
    np.testing.assert_array_equal(from_bag[1].left, from_folder[1].left)
    np.testing.assert_array_equal(from_bag[1].right, from_folder[1].right)
    assert not np.array_equal(from_bag[1].left, read_grey(folder / "left" / "0001.png"))  # it was rectified


def test_a_calib_file_wins_over_camera_info_and_its_fps_is_the_rate(tmp_path):
    calib = tmp_path / "calib.yaml"
    calib.write_text(yaml.safe_dump(rectified_calibration() | {"fps": 25}))
    sequence = open_sequence(write_bag(tmp_path, "ros1", stereo_messages("ros1")), BagOptions(calibration=calib))
    assert sequence.camera.fx == 50.0 != FX  # calib.yaml's, not the CameraInfo's
    assert (sequence.frame_rate.hz, sequence.frame_rate.source) == (25.0, "fps of the calibration file")


def test_camera_info_topic_is_beside_the_image_topic():
    assert camera_info_topic("/stereo/left/image_raw") == "/stereo/left/camera_info"
    assert camera_info_topic("/stereo/left/image_rect/compressed") == "/stereo/left/camera_info"
    assert camera_info_topic("/cam0/image_raw") == "/cam0/camera_info"


# ---------------------------------------------------------------- image encodings


def image_message(image: np.ndarray, encoding: str, step: int | None = None, bigendian: bool = False):
    """A ROS 2 Image of ``image``'s bytes, rows padded to ``step`` bytes."""
    rows = image.reshape(image.shape[0], -1).view(np.uint8)
    step = rows.shape[1] if step is None else step
    padded = np.zeros((image.shape[0], step), dtype=np.uint8)
    padded[:, : rows.shape[1]] = rows
    message = Messages("sqlite3").image(START_NS, image, encoding)
    return type(message)(header=message.header, height=image.shape[0], width=image.shape[1], encoding=encoding,
                         is_bigendian=int(bigendian), step=step, data=padded.reshape(-1))


@pytest.mark.parametrize("encoding, conversion", [("rgb8", cv2.COLOR_RGB2GRAY), ("bgr8", cv2.COLOR_BGR2GRAY)])
def test_colour_images_are_read_as_grey_in_their_channel_order(encoding, conversion):
    colour = np.random.default_rng(0).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    grey = raw_grey(image_message(colour, encoding, step=3 * WIDTH + 4), "m")
    np.testing.assert_array_equal(grey, cv2.cvtColor(colour, conversion))
    assert not np.array_equal(grey, cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY if encoding == "bgr8" else
                                                 cv2.COLOR_BGR2GRAY))


@pytest.mark.parametrize("bigendian", [False, True])
def test_sixteen_bit_images_keep_their_high_byte(bigendian):
    values = np.full((HEIGHT, WIDTH), 0x12F0, dtype=">u2" if bigendian else "<u2")
    grey = raw_grey(image_message(values, "mono16", step=2 * WIDTH + 2, bigendian=bigendian), "m")
    assert grey.dtype == np.uint8 and (grey == 0x12).all()


@pytest.mark.parametrize(
    "message, expected",
    [
        (image_message(np.zeros((4, 4), np.uint8), "yuv422"),
         "m: image encoding 'yuv422' is not supported (supported: mono8"),
        (image_message(np.zeros((4, 4), np.uint8), "rgb8"), "m: 16 bytes (step 4) for a 4x4 rgb8 image"),
    ],
)
def test_an_image_message_that_cannot_be_read_is_one_line_naming_it(message, expected):
    with pytest.raises(DatasetError, match=expected.replace("(", r"\(").replace(")", r"\)")):
        raw_grey(message, "m")


# ---------------------------------------------------------------- topics, pairing, calibration: bad input


def both_streams(kind: str) -> list:
    """Raw and rectified topics of each camera (four image topics), with CameraInfo."""
    raw = stereo_messages(kind, topics=("/stereo/left/image_raw", "/stereo/right/image_raw"), camera_info=False)
    return raw + stereo_messages(kind)


def with_imu(kind: str) -> list:
    make = Messages(kind)
    imu = make.types["sensor_msgs/msg/Imu"]
    vector = make.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.81)
    quaternion = make.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    message = imu(header=make.header(START_NS), orientation=quaternion, orientation_covariance=np.zeros(9),
                  angular_velocity=vector, angular_velocity_covariance=np.zeros(9), linear_acceleration=vector,
                  linear_acceleration_covariance=np.zeros(9))
    return stereo_messages(kind) + [("/imu0", "sensor_msgs/msg/Imu", START_NS, message)]


def test_four_image_topics_need_the_pair_named(tmp_path):
    bag = write_bag(tmp_path, "sqlite3", both_streams("sqlite3"))
    with pytest.raises(DatasetError) as raised:
        open_sequence(bag)
    assert str(raised.value) == (
        f"{bag}: 4 image topics (/stereo/left/image_raw, /stereo/left/image_rect, /stereo/right/image_raw, "
        "/stereo/right/image_rect); name the stereo pair with --left-topic and --right-topic"
    )
    chosen = open_sequence(bag, BagOptions("/stereo/left/image_rect", "/stereo/right/image_rect"))
    assert chosen.frames.topics == ("/stereo/left/image_rect", "/stereo/right/image_rect")
    assert chosen.rectifier is None  # image_rect: rectified already


@pytest.mark.parametrize(
    "messages, options, expected",
    [
        (with_imu, BagOptions("/imu0", "/stereo/right/image_rect"),
         ": topic /imu0 is sensor_msgs/msg/Imu, not an image "
         "(sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage)"),
        (with_imu, BagOptions("/nowhere", "/stereo/right/image_rect"),
         ": no topic /nowhere (image topics: /stereo/left/image_rect, /stereo/right/image_rect)"),
        (with_imu, BagOptions(left_topic="/stereo/left/image_rect"), ": give both --left-topic and --right-topic"),
        (lambda kind: stereo_messages(kind, right_offset_ns=30_000_000), BagOptions(),
         f": 0 of 4 /stereo/left/image_rect images have a /stereo/right/image_rect image stamped within 5 ms "
         f"(first unpaired: {START_NS} ns); are they a synchronised stereo pair?"),
        (lambda kind: stereo_messages(kind, topics=("/cam0/image_raw", "/cam1/image_raw"), camera_info=False),
         BagOptions(), ": /cam0/camera_info: no sensor_msgs/msg/CameraInfo topic for /cam0/image_raw; "
                       "give the calibration with --calib"),
        (with_imu, BagOptions(groundtruth_topic="/imu0"),
         ": ground-truth topic /imu0: it is sensor_msgs/msg/Imu, not one of geometry_msgs/msg/PoseStamped, "
         "geometry_msgs/msg/TransformStamped, nav_msgs/msg/Odometry"),
        (lambda kind: stereo_messages(kind, topics=("/cam/image_raw", "/cam/image_raw/compressed")), BagOptions(),
         ": the image topics /cam/image_raw, /cam/image_raw/compressed are one camera's (/cam/camera_info), "
         "not a stereo pair"),
        (with_imu, BagOptions(calibration=Path("/nowhere/calib.yaml")),
         "/nowhere/calib.yaml: YAML calibration file not found"),
    ],
)
def test_bag_bad_input_is_one_line_naming_the_bag_and_topic(tmp_path, messages, options, expected):
    bag = write_bag(tmp_path, "ros1", messages("ros1"))
    with pytest.raises(DatasetError) as raised:
        open_sequence(bag, options)
    assert "\n" not in str(raised.value)
    assert str(raised.value).startswith(str(bag) if "calib.yaml" not in expected else "/nowhere")
    assert expected in str(raised.value)


@pytest.mark.parametrize(
    "right_info, expected",
    [
        (dict(D=[0.1, 0.0, 0.0, 0.0], model="equidistant"),
         "/cam1/camera_info: distortion model 'equidistant' is not supported (plumb_bob or rational_polynomial)"),
        (dict(P=np.zeros((3, 4))), "/cam1/camera_info: the camera is not calibrated (P is zero)"),
        (dict(P=rectified_views()[1][3] * 1.1), "/cam1/camera_info: P differs from the left camera's"),
        (dict(size=(WIDTH, 2 * HEIGHT)), "/cam1/camera_info: 32x48 but the left camera is 32x24"),
        (dict(R=np.diag([1.0, 1.0, np.nan])), "/cam1/camera_info: R holds nan, not a finite number"),
        (dict(K=np.array([[FX, 0.0, 3.0 * WIDTH], [0.0, FY, CY], [0.0, 0.0, 1.0]])),
         f"/cam1/camera_info: cx of K is {3 * WIDTH}, outside the image (0 to its width, {WIDTH} px)"),
    ],
)
def test_camera_info_that_cannot_describe_the_pair_is_refused(tmp_path, right_info, expected):
    make = Messages("ros1")
    left, right = rectified_views()
    right_fields = dict(zip(("K", "D", "R", "P"), right, strict=True)) | {"size": (WIDTH, HEIGHT)} | right_info
    model = right_fields.pop("model", "plumb_bob")
    infos = [("/cam0/camera_info", INFO, START_NS, make.camera_info((WIDTH, HEIGHT), *left)),
             ("/cam1/camera_info", INFO, START_NS, make.camera_info(right_fields.pop("size"), **right_fields,
                                                                    model=model))]
    messages = stereo_messages("ros1", topics=("/cam0/image_raw", "/cam1/image_raw"), camera_info=False)
    assert expected in open_error(write_bag(tmp_path, "ros1", messages + infos))


def test_a_dropped_message_costs_its_frame_only(tmp_path):
    messages = stereo_messages("mcap", n=6)
    dropped = START_NS + 2 * PERIOD_NS
    kept = [m for m in messages if not (m[0] == "/stereo/right/image_rect" and m[2] == dropped + 1000)]
    sequence = open_sequence(write_bag(tmp_path, "mcap", kept))
    np.testing.assert_array_equal(sequence.timestamps, (START_NS + PERIOD_NS * np.array([0, 1, 3, 4, 5])) / 1e9)
    np.testing.assert_array_equal(sequence[2].right, random_images(6, 1)[3])


def test_stamps_just_within_the_pair_tolerance_pair(tmp_path):
    sequence = open_sequence(write_bag(tmp_path, "ros1", stereo_messages("ros1", right_offset_ns=PAIR_TOLERANCE_NS)))
    assert len(sequence) == 4


def test_images_are_decoded_when_read_and_a_bad_one_names_its_message(tmp_path):
    messages = stereo_messages("sqlite3", n=3, compressed=True)
    bad_stamp = START_NS + PERIOD_NS
    broken = [(t, kind, record, Messages("sqlite3").compressed(bad_stamp, np.frombuffer(b"not a png", np.uint8)))
              if t == "/stereo/right/image_rect" and record == bad_stamp + 1000 else (t, kind, record, message)
              for t, kind, record, message in messages]
    bag = write_bag(tmp_path, "sqlite3", broken)
    sequence = open_sequence(bag)  # opening decodes no image
    with pytest.raises(DatasetError) as raised:
        sequence[1]
    assert str(raised.value) == (f"{bag}: /stereo/right/image_rect message stamped {bad_stamp} ns: "
                                 "cannot read image (not an image, or corrupt)")
    assert sequence.frames.describe(1) == f"{bag}: /stereo/left/image_rect message stamped {bad_stamp} ns"
    assert sequence[2].left.shape == (HEIGHT, WIDTH)


def test_a_file_that_is_not_a_bag_and_bag_options_on_a_folder_are_refused(tmp_path):
    (tmp_path / "broken.bag").write_bytes(b"#ROSBAG V2.0\nnot really")
    assert open_error(tmp_path / "broken.bag").startswith(f"{tmp_path / 'broken.bag'}: cannot read the bag (")
    folder = make_generic(tmp_path, RAW_RIG, n=1, size=(RAW_WIDTH, RAW_HEIGHT))
    with pytest.raises(DatasetError, match="not a ROS bag; topics and --calib apply to bags only"):
        open_sequence(folder, BagOptions(left_topic="/cam0/image_raw"))


# ---------------------------------------------------------------- ground truth


MOTION = [make_pose(Rotation.from_euler("y", 5.0 * i, degrees=True).as_matrix(), [0.1 * i, 0.0, 0.5 * i])
          for i in range(4)]
"""Poses of the left camera (rectified rig: raw = rectified) in a world frame."""


@pytest.mark.parametrize("msgtype", ["geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped",
                                     "nav_msgs/msg/Odometry"])
@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_ground_truth_from_each_pose_message_type(tmp_path, kind, msgtype):
    make = Messages(kind)
    world = make_pose(Rotation.from_euler("z", 40, degrees=True).as_matrix(), [3.0, -2.0, 1.0])
    stamps = [START_NS + i * PERIOD_NS for i in range(len(MOTION))]
    poses = [("/gt", msgtype, stamp + 2_000_000, make.pose(msgtype, stamp, world @ T))  # recorded 2 ms late
             for stamp, T in zip(stamps, MOTION, strict=True)]
    bag = write_bag(tmp_path, kind, stereo_messages(kind) + poses)
    sequence = open_sequence(bag, BagOptions(groundtruth_topic="/gt"))
    np.testing.assert_array_equal(sequence.groundtruth.timestamps, sequence.timestamps)
    np.testing.assert_allclose(sequence.groundtruth.poses, np.array(MOTION), atol=1e-9)


def test_a_ground_truth_quaternion_of_zero_names_its_message(tmp_path):
    make = Messages("ros1")
    msgtype = "geometry_msgs/msg/PoseStamped"
    poses = [("/gt", msgtype, START_NS, make.pose(msgtype, START_NS, np.eye(4), quaternion=(0.0, 0.0, 0.0, 0.0)))]
    bag = write_bag(tmp_path, "ros1", stereo_messages("ros1") + poses)
    with pytest.raises(DatasetError) as raised:
        open_sequence(bag, BagOptions(groundtruth_topic="/gt"))
    assert str(raised.value) == (f"{bag}: /gt message stamped {START_NS} ns: "
                                 "quaternion norm is 0, not 1 (zero or not unit)")


# ---------------------------------------------------------------- pld-slam run on a bag


def synthetic_bag(folder: Path) -> Path:
    """A rendered synthetic street (rectified, 10 Hz) as a ROS 1 bag, with ground truth and a third image topic."""
    sequence_folder = folder / "synth"
    write_sequence(sequence_folder, "static", n_frames=4, size=(320, 240), seed=1)
    sequence = open_sequence(sequence_folder)
    make = Messages("ros1")
    camera = sequence.camera
    K = camera.K
    views = [(K, np.zeros(5), np.eye(3), np.hstack([K, [[-camera.bf * side], [0.0], [0.0]]])) for side in (0, 1)]
    messages = []
    truth = read_kitti(sequence_folder / "poses.txt").poses
    for i, frame in enumerate(sequence):
        stamp = START_NS + i * 100_000_000
        for topic, image in (("/left/image_rect", frame.left), ("/right/image_rect", frame.right),
                             ("/left/image_raw", frame.left)):
            messages.append((topic, IMAGE, stamp, make.image(stamp, image)))
        messages.append(("/gt", "geometry_msgs/msg/PoseStamped", stamp,
                         make.pose("geometry_msgs/msg/PoseStamped", stamp, truth[i])))
    for topic, view in zip(("/left/camera_info", "/right/camera_info"), views, strict=True):
        messages.append((topic, INFO, START_NS, make.camera_info(camera.size, *view)))
    return write_bag(folder, "ros1", messages)


def test_pld_slam_run_on_a_bag_tracks_as_on_the_folder_it_was_written_from(tmp_path):
    """Topics, ground truth and --scale reach the run; the trajectory is the folder's, byte for byte."""
    bag = synthetic_bag(tmp_path)
    runner = CliRunner()
    result = runner.invoke(cli, ["run", str(bag), "--left-topic", "/left/image_rect", "--right-topic",
                                 "/right/image_rect", "--gt-topic", "/gt", "--scale", "0.5", "--out", tmp_path / "bag"])
    assert result.exit_code == 0, result.output
    summary = yaml.safe_load((tmp_path / "bag" / "summary.json").read_text())
    assert (summary["layout"], summary["frames"], summary["n_matched"]) == ("rosbag", 4, 4)
    assert summary["frame_rate"] == {"hz": pytest.approx(10.0), "source": "median step of the left image stamps"}
    assert summary["config"]["dataset"]["scale"] == 0.5
    assert summary["config_sources"] == ["defaults", "--set dataset.scale=0.5"]
    assert "sequence time at 10 Hz, median step of the left image stamps / wall time" in result.output

    # The folder's family file (synthetic.yaml) sets points.n_features only; a bag runs on the defaults.
    folder_run = runner.invoke(cli, ["run", str(tmp_path / "synth"), "--set", "points.n_features=1500",
                                     "--scale", "0.5", "--out", tmp_path / "folder"])
    assert folder_run.exit_code == 0, folder_run.output
    trajectories = [(tmp_path / run / "trajectory.kitti.txt").read_bytes() for run in ("bag", "folder")]
    assert trajectories[0] == trajectories[1]
    folder_summary = yaml.safe_load((tmp_path / "folder" / "summary.json").read_text())
    assert summary["ate_rmse_m"] == pytest.approx(folder_summary["ate_rmse_m"], abs=1e-9)

    ambiguous = runner.invoke(cli, ["run", str(bag), "--out", tmp_path / "bag"])
    assert ambiguous.exit_code == EXIT_USER_ERROR
    assert ambiguous.output.strip().endswith("name the stereo pair with --left-topic and --right-topic")
