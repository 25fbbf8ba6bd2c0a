"""ROS bags: a ROS 1 ``.bag`` file, or a ROS 2 bag folder (``metadata.yaml``, sqlite3 or mcap).

Read with the ``rosbags`` package (``AnyReader``), which needs no ROS installation.

- Image topics: the stereo pair is two topics of ``sensor_msgs/Image`` or
  ``sensor_msgs/CompressedImage``. With exactly two in the bag, the first in name order
  is the left camera (``/cam0`` before ``/cam1``, ``.../left/...`` before
  ``.../right/...``), unless both share one ``camera_info`` (two streams of one camera,
  an error); with more (a raw and a rectified stream per camera, say),
  `BagOptions` ``left_topic`` and ``right_topic`` (``--left-topic``, ``--right-topic``)
  name them, and a named topic that is missing or not an image raises.
- Pairing: each left image is paired with the right image whose header stamp is nearest,
  within `PAIR_TOLERANCE_NS` (5 ms: cameras triggered together are stamped within
  microseconds; 5 ms is a sixth of a 30 Hz period). Unlike the folder layouts, an image
  without a partner is left out rather than an error: a recorder under load drops the odd
  message of one topic, and the two topics rarely start and stop on the same frame; the
  stamps, not positions, pair the rest, so a drop cannot shift later pairs. When fewer
  than half of the left images pair (`MIN_PAIRED_SHARE`), the two topics are not a
  synchronised stereo pair (a wrong topic, or clocks apart), and that raises.
- Times: the left header stamps / 1e9 [s]. Frame rate: ``fps`` of the ``--calib`` file
  when it gives one, else the median step of the left stamps (a bag states no rate).
- Calibration: from ``BagOptions.calibration`` (``--calib``), a YAML file in the generic
  layout's ``calib.yaml`` schema (`pld_slam.datasets.generic`), when given; else from the
  first ``sensor_msgs/CameraInfo`` of each camera, on the ``camera_info`` topic beside the
  image topic (``/stereo/left/image_raw[/compressed]`` -> ``/stereo/left/camera_info``,
  the ROS camera convention). Images on an ``image_rect...`` topic are already
  rectified, and only the projections ``P`` are read; other images are rectified on load
  with ``K``, ``D``, ``R`` and ``P`` as ROS's ``image_proc`` does
  (`pld_slam.datasets.rectify.rectification_of`). EuRoC's bags carry no CameraInfo: give
  ``--calib``.
- Ground truth (``BagOptions.groundtruth_topic``, ``--gt-topic``): a topic of
  ``geometry_msgs/PoseStamped``, ``geometry_msgs/TransformStamped`` or
  ``nav_msgs/Odometry`` giving ``T_w_gt`` at its header stamps. ``gt`` is the raw left
  camera, unless the ``--calib`` file's ``T_gt_left`` says otherwise (EuRoC's body: its
  cam0 ``T_BS``). Each frame takes the pose nearest in time within 5 ms, moved to the
  rectified left camera, and the first to identity, as for the generic layout.
- Images: ``mono8``, ``8UC1``, ``mono16``, ``16UC1`` (the high byte kept), ``bgr8``,
  ``rgb8``, ``bgra8``, ``rgba8`` and the four 8-bit Bayer patterns (converted as
  ``cv_bridge`` does), or any format ``cv2.imdecode`` reads for compressed images.

Laziness. A bag can hold tens of GB. Opening reads every message of the two image topics
once, for its header stamp (a bag indexes messages by record time, not by stamp), and
keeps only the two times of each; a frame is then read alone, found again by its record
time through the bag's index. The bag stays open as long as the sequence is used.
"""

from dataclasses import dataclass, replace
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import Stores, get_typestore

from pld_slam.datasets.base import FrameRate, StereoSequence, check_calibrated_size, decode_grey
from pld_slam.datasets.calibration import check_intrinsics, stereo_camera_from_projections
from pld_slam.datasets.files import nearest_within
from pld_slam.datasets.generic import RigCalibration, groundtruth_in_camera, read_rig_calibration
from pld_slam.datasets.rectify import RectifiedView, rectification_of
from pld_slam.errors import DatasetError
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.trajectory import rotations_from_quaternions
from pld_slam.trajectory import Trajectory

LAYOUT = "rosbag"
EXPECTED = "ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder with metadata.yaml)"

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

POSE_FIELDS = {
    "geometry_msgs/msg/PoseStamped": ("pose", "position", "orientation"),
    "geometry_msgs/msg/TransformStamped": ("transform", "translation", "rotation"),
    "nav_msgs/msg/Odometry": ("pose.pose", "position", "orientation"),
}
"""The ground-truth message types: where the pose is, its translation and its quaternion."""

PAIR_TOLERANCE_NS = 5_000_000
"""Largest difference [ns] between the header stamps of a left and a right image paired."""

MIN_PAIRED_SHARE = 0.5
"""Fewer left images than this share paired means the two topics are not a stereo pair."""

_READ_ERRORS = (AnyReaderError, Ros1ReaderError, Ros2ReaderError, OSError, KeyError, ValueError)
"""What ``rosbags`` raises on a bag it cannot read (KeyError and ValueError from malformed records)."""

_ENCODINGS = {  # channels, bytes per channel, conversion to grey (None: already grey)
    "mono8": (1, 1, None),
    "8UC1": (1, 1, None),
    "mono16": (1, 2, None),
    "16UC1": (1, 2, None),
    "bgr8": (3, 1, cv2.COLOR_BGR2GRAY),
    "rgb8": (3, 1, cv2.COLOR_RGB2GRAY),
    "bgra8": (4, 1, cv2.COLOR_BGRA2GRAY),
    "rgba8": (4, 1, cv2.COLOR_RGBA2GRAY),
    # cv_bridge's mapping: OpenCV names a Bayer pattern by its second row and column.
    "bayer_rggb8": (1, 1, cv2.COLOR_BayerBG2GRAY),
    "bayer_bggr8": (1, 1, cv2.COLOR_BayerRG2GRAY),
    "bayer_gbrg8": (1, 1, cv2.COLOR_BayerGR2GRAY),
    "bayer_grbg8": (1, 1, cv2.COLOR_BayerGB2GRAY),
}

_SUPPORTED_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")
"""CameraInfo distortion models OpenCV's radial-tangential model reads (5 and 8 coefficients)."""


@dataclass(frozen=True)
class BagOptions:
    """What the bag itself cannot say: which topics, and the calibration when it has none.

    Attributes
    ----------
    left_topic, right_topic : str or None
        The stereo image topics; both None to pick the bag's only two image topics.
    groundtruth_topic : str or None
        A pose topic giving ground truth; None for none.
    calibration : Path or None
        A ``calib.yaml`` (generic layout's schema) used instead of the bag's CameraInfo.
    """

    left_topic: str | None = None
    right_topic: str | None = None
    groundtruth_topic: str | None = None
    calibration: Path | None = None


@dataclass(frozen=True)
class MessageTimes:
    """The times of an image topic's messages, int64 [ns] in stamp order.

    ``record_ns`` (N,) is when the bag recorded each (its index finds the message again),
    ``stamp_ns`` (N,) its header stamp.
    """

    record_ns: np.ndarray
    stamp_ns: np.ndarray

    def take(self, indices: np.ndarray) -> "MessageTimes":
        """The times of messages ``indices`` (K,) (or a boolean mask) only."""
        return MessageTimes(self.record_ns[indices], self.stamp_ns[indices])


@dataclass(frozen=True)
class BagImages:
    """Stereo pairs read one at a time from the image messages of an open bag (a `FrameSource`).

    Attributes
    ----------
    bag : Path
        The bag, named in errors.
    reader : AnyReader
        The open bag.
    topics : tuple of str
        The left and right image topics.
    left, right : MessageTimes
        (N,) times of the paired messages of each topic.
    size : tuple of int
        ``(width, height)`` [px] of the calibration, which every image must have.
    """

    forks_safely: ClassVar[bool] = False
    """The open reader would be shared with a forked child: one file offset, one SQLite connection."""

    bag: Path
    reader: AnyReader
    topics: tuple[str, str]
    left: MessageTimes
    right: MessageTimes
    size: tuple[int, int]

    def __len__(self) -> int:
        return len(self.left.stamp_ns)

    def read(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The grey pair of frame ``index``, each checked to be of the calibrated size."""
        return self._image(self.topics[0], self.left, index), self._image(self.topics[1], self.right, index)

    def _image(self, topic: str, times: MessageTimes, index: int) -> np.ndarray:
        """The grey image of message ``index`` of ``topic``."""
        stamp_ns = int(times.stamp_ns[index])
        source = _message_name(self.bag, topic, stamp_ns)
        message, msgtype = _message_at(self.reader, self.bag, topic, int(times.record_ns[index]), stamp_ns)
        if message is None:
            raise DatasetError(f"{source}: not found again at its record time")
        image = grey_image(message, msgtype, source)
        check_calibrated_size(source, image, self.size)
        return image

    def describe(self, index: int) -> str:
        return _message_name(self.bag, self.topics[0], int(self.left.stamp_ns[index]))

    def select(self, indices: np.ndarray) -> "BagImages":
        return replace(self, left=self.left.take(indices), right=self.right.take(indices))


def matches(path: Path) -> bool:
    """Whether ``path`` is a ROS 1 bag (a ``.bag`` file) or a ROS 2 bag (a folder with ``metadata.yaml``)."""
    return (path.is_file() and path.suffix == ".bag") or (path / "metadata.yaml").is_file()


def load(path: Path, options: BagOptions = BagOptions()) -> StereoSequence:
    """Open the bag at ``path`` (see the module docstring)."""
    bag = path.resolve()
    reader = _open(bag)
    topics = _image_topics(reader, bag, options)
    left, right = _paired(bag, topics, *(_message_times(reader, bag, topic) for topic in topics))
    rig = read_rig_calibration(options.calibration) if options.calibration else _camera_info_rig(reader, bag, topics)
    timestamps = left.stamp_ns / 1e9
    return StereoSequence(
        name=bag.stem if bag.is_file() else bag.name,
        layout=LAYOUT,
        root=bag,
        camera=rig.camera,
        timestamps=timestamps,
        frame_rate=_frame_rate(rig, timestamps),
        frames=BagImages(bag, reader, topics, left, right, rig.camera.size),
        groundtruth=_groundtruth(reader, bag, options.groundtruth_topic, timestamps, rig.T_gt_rect),
        rectifier=rig.rectifier,
    )


def _frame_rate(rig: RigCalibration, timestamps: np.ndarray) -> FrameRate:
    """``fps`` of the ``--calib`` file, else the median step of the frame times (N,) [s]."""
    if rig.fps is not None:
        return FrameRate(rig.fps, "fps of the calibration file")
    return FrameRate.from_times(timestamps, "median step of the left image stamps")


def _open(bag: Path) -> AnyReader:
    """The open reader of ``bag``; a bag ``rosbags`` cannot read raises `DatasetError` naming it."""
    reader = AnyReader([bag], default_typestore=get_typestore(Stores.LATEST))
    try:
        reader.open()
    except _READ_ERRORS as error:
        raise DatasetError(f"{bag}: cannot read the bag ({_one_line(error)})") from None
    return reader


def _one_line(error: Exception) -> str:
    """The message of ``error`` on one line."""
    return " ".join(str(error).split()) or type(error).__name__


def _message_name(bag: Path, topic: str, stamp_ns: int) -> str:
    """How errors name one message: ``BAG: TOPIC message stamped NS ns``."""
    return f"{bag}: {topic} message stamped {stamp_ns} ns"


def _topic_type(reader: AnyReader, topic: str) -> str | None:
    """The message type of ``topic``, None when the bag has no such topic."""
    info = reader.topics.get(topic)
    return None if info is None else info.msgtype


def _image_topics(reader: AnyReader, bag: Path, options: BagOptions) -> tuple[str, str]:
    """The (left, right) image topics: the ones named, or the bag's only two (module docstring)."""
    images = sorted(topic for topic in reader.topics if _topic_type(reader, topic) in (IMAGE, COMPRESSED_IMAGE))
    listed = ", ".join(images) or "none"
    named = (options.left_topic, options.right_topic)
    if named == (None, None):
        if len(images) != 2:
            raise DatasetError(
                f"{bag}: {len(images)} image topics ({listed}); "
                "name the stereo pair with --left-topic and --right-topic"
            )
        if camera_info_topic(images[0]) == camera_info_topic(images[1]):  # a raw and a compressed stream, say
            raise DatasetError(
                f"{bag}: the image topics {listed} are one camera's ({camera_info_topic(images[0])}), "
                "not a stereo pair"
            )
        return images[0], images[1]
    if None in named:
        raise DatasetError(f"{bag}: give both --left-topic and --right-topic (image topics: {listed})")
    for topic in named:
        msgtype = _topic_type(reader, topic)
        if msgtype is None:
            raise DatasetError(f"{bag}: no topic {topic} (image topics: {listed})")
        if msgtype not in (IMAGE, COMPRESSED_IMAGE):
            raise DatasetError(f"{bag}: topic {topic} is {msgtype}, not an image ({IMAGE} or {COMPRESSED_IMAGE})")
    return options.left_topic, options.right_topic


def _messages(reader: AnyReader, bag: Path, topic: str, start: int | None = None, stop: int | None = None):
    """``(record time [ns], message, type)`` of the messages of ``topic`` (recorded in [start, stop))."""
    connections = [connection for connection in reader.connections if connection.topic == topic]
    try:
        for connection, record_ns, raw in reader.messages(connections, start=start, stop=stop):
            yield record_ns, reader.deserialize(raw, connection.msgtype), connection.msgtype
    except _READ_ERRORS as error:
        raise DatasetError(f"{bag}: cannot read {topic} ({_one_line(error)})") from None


def _stamp_ns(message) -> int:
    """The header stamp [ns] of a stamped message."""
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


def _message_times(reader: AnyReader, bag: Path, topic: str) -> MessageTimes:
    """The record times and header stamps of every message of ``topic``, in stamp order.

    Two messages of one stamp raise, as they could not be told apart when paired.
    """
    times = np.array([(record_ns, _stamp_ns(message)) for record_ns, message, _ in _messages(reader, bag, topic)],
                     dtype=np.int64).reshape(-1, 2)
    if not len(times):
        raise DatasetError(f"{bag}: {topic} has no message")
    times = times[np.argsort(times[:, 1], kind="stable")]
    repeated = np.flatnonzero(np.diff(times[:, 1]) == 0)
    if repeated.size:
        raise DatasetError(f"{_message_name(bag, topic, int(times[repeated[0], 1]))}: stamped twice")
    return MessageTimes(times[:, 0], times[:, 1])


def _paired(
    bag: Path, topics: tuple[str, str], left: MessageTimes, right: MessageTimes
) -> tuple[MessageTimes, MessageTimes]:
    """The left and right messages paired by nearest header stamp (module docstring: Pairing)."""
    partner = nearest_within(right.stamp_ns, left.stamp_ns, PAIR_TOLERANCE_NS)
    paired = partner >= 0
    if paired.sum() < MIN_PAIRED_SHARE * len(left.stamp_ns):
        first = "" if paired.all() else f" (first unpaired: {left.stamp_ns[np.argmin(paired)]} ns)"
        raise DatasetError(
            f"{bag}: {paired.sum()} of {len(left.stamp_ns)} {topics[0]} images have a {topics[1]} image "
            f"stamped within {PAIR_TOLERANCE_NS / 1e6:g} ms{first}; are they a synchronised stereo pair?"
        )
    return left.take(paired), right.take(partner[paired])


def _message_at(reader: AnyReader, bag: Path, topic: str, record_ns: int, stamp_ns: int):
    """``(message, type)`` of ``topic`` recorded at ``record_ns`` and stamped ``stamp_ns``; (None, None) if none."""
    for _, message, msgtype in _messages(reader, bag, topic, record_ns, record_ns + 1):
        if _stamp_ns(message) == stamp_ns:
            return message, msgtype
    return None, None


def grey_image(message, msgtype: str, source: str) -> np.ndarray:
    """The (H, W) uint8 grey image of an ``Image`` or ``CompressedImage`` message; ``source`` names it in errors."""
    if msgtype == COMPRESSED_IMAGE:
        return decode_grey(np.asarray(message.data, dtype=np.uint8), source)
    return raw_grey(message, source)


def raw_grey(message, source: str) -> np.ndarray:
    """The (H, W) uint8 grey image of a ``sensor_msgs/Image`` (encodings in the module docstring).

    Rows are ``step`` bytes apart (padding dropped); 16-bit pixels keep their high byte.
    ``source`` names the message in errors.
    """
    if message.encoding not in _ENCODINGS:
        raise DatasetError(f"{source}: image encoding {message.encoding!r} is not supported "
                           f"(supported: {', '.join(_ENCODINGS)})")
    channels, depth, conversion = _ENCODINGS[message.encoding]
    height, width, step = int(message.height), int(message.width), int(message.step)
    data = np.asarray(message.data, dtype=np.uint8)
    row_bytes = width * channels * depth
    if step < row_bytes or data.size < step * height:
        raise DatasetError(f"{source}: {data.size} bytes (step {step}) for a {width}x{height} {message.encoding} image")
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    if depth == 2:
        pixels = np.ascontiguousarray(rows).view(">u2" if message.is_bigendian else "<u2")
        return (pixels >> 8).astype(np.uint8)
    image = rows.reshape(height, width, channels) if channels > 1 else rows
    return np.ascontiguousarray(image) if conversion is None else cv2.cvtColor(image, conversion)


def camera_info_topic(image_topic: str) -> str:
    """The ``camera_info`` topic of an image topic: ``/ns/image_raw[/compressed]`` -> ``/ns/camera_info``."""
    parts = image_topic.rstrip("/").split("/")
    if parts[-1] == "compressed":
        parts.pop()
    return "/".join([*parts[:-1], "camera_info"])


def _is_rectified_topic(image_topic: str) -> bool:
    """Whether the images of ``image_topic`` are rectified already (an ``image_rect...`` topic)."""
    parts = image_topic.rstrip("/").split("/")
    return parts[-2 if parts[-1] == "compressed" else -1].startswith("image_rect")


def _camera_info_rig(reader: AnyReader, bag: Path, topics: tuple[str, str]) -> RigCalibration:
    """The calibration of the first CameraInfo of each camera (module docstring: Calibration)."""
    (left, left_source), (right, right_source) = (_first_camera_info(reader, bag, topic) for topic in topics)
    size = (int(left.width), int(left.height))
    if (int(right.width), int(right.height)) != size:
        raise DatasetError(f"{right_source}: {right.width}x{right.height} but the left camera is {size[0]}x{size[1]}")
    views = _rectified_view(left, left_source), _rectified_view(right, right_source)
    if not np.allclose(views[0].P[:, :3], views[1].P[:, :3]):
        raise DatasetError(f"{right_source}: P differs from the left camera's in its first three columns; "
                           "the two CameraInfo are not one stereo calibration")
    T_left_rect = make_pose(views[0].R.T, np.zeros(3))
    if _is_rectified_topic(topics[0]):
        camera = stereo_camera_from_projections(views[0].P, views[1].P, *size, source=left_source)
        return RigCalibration(camera, None, T_left_rect, None)
    for view, source in zip(views, (left_source, right_source), strict=True):
        check_intrinsics(view.K, size, source, "K")
    rectifier = rectification_of(*views, size, left_source)
    return RigCalibration(rectifier.camera, rectifier, T_left_rect, None)


def _first_camera_info(reader: AnyReader, bag: Path, image_topic: str):
    """The first CameraInfo message beside ``image_topic``, and how errors name it."""
    topic = camera_info_topic(image_topic)
    source = f"{bag}: {topic}"
    if _topic_type(reader, topic) != CAMERA_INFO:
        raise DatasetError(f"{source}: no {CAMERA_INFO} topic for {image_topic}; give the calibration with --calib")
    for _, message, _ in _messages(reader, bag, topic):
        return message, source
    raise DatasetError(f"{source}: no message; give the calibration with --calib")


def _rectified_view(info, source: str) -> RectifiedView:
    """The `RectifiedView` of a CameraInfo (``k d r p`` in ROS 2, ``K D R P`` in ROS 1)."""
    def field(name: str) -> np.ndarray:
        return np.asarray(getattr(info, name) if hasattr(info, name) else getattr(info, name.upper()), float)

    distortion = field("d")
    if info.distortion_model not in _SUPPORTED_DISTORTION_MODELS and distortion.any():
        raise DatasetError(f"{source}: distortion model {info.distortion_model!r} is not supported "
                           f"({' or '.join(_SUPPORTED_DISTORTION_MODELS)})")
    view = RectifiedView(field("k").reshape(3, 3), distortion if distortion.size else np.zeros(5),
                         field("r").reshape(3, 3), field("p").reshape(3, 4))
    for name, values in (("K", view.K), ("D", view.distortion), ("R", view.R), ("P", view.P)):
        if not np.isfinite(values).all():
            raise DatasetError(f"{source}: {name} holds {values[~np.isfinite(values)][0]:g}, not a finite number")
    if not view.P[0, 0] > 0.0:
        raise DatasetError(f"{source}: the camera is not calibrated (P is zero); give the calibration with --calib")
    return view


def _groundtruth(
    reader: AnyReader, bag: Path, topic: str | None, timestamps: np.ndarray, T_gt_rect: np.ndarray
) -> Trajectory | None:
    """``T_w_c`` of the rectified left camera at the frame times from pose topic ``topic``, first = identity.

    None without a topic; ``T_gt_rect`` (4, 4) maps the rectified left camera frame into
    the frame whose poses the topic gives.
    """
    if topic is None:
        return None
    msgtype = _topic_type(reader, topic)
    if msgtype not in POSE_FIELDS:
        found = "no such topic" if msgtype is None else f"it is {msgtype}"
        raise DatasetError(f"{bag}: ground-truth topic {topic}: {found}, not one of {', '.join(POSE_FIELDS)}")
    messages = [message for _, message, _ in _messages(reader, bag, topic)]
    if not messages:
        raise DatasetError(f"{bag}: ground-truth topic {topic} has no message")
    stamps_ns, first = np.unique([_stamp_ns(message) for message in messages], return_index=True)
    values = np.array([_pose_values(messages[i], POSE_FIELDS[msgtype]) for i in first])
    R = rotations_from_quaternions(
        values[:, 3:], lambda i, problem: DatasetError(f"{_message_name(bag, topic, int(stamps_ns[i]))}: {problem}")
    )
    T_w_gt = Trajectory(stamps_ns / 1e9, np.array([make_pose(r, t) for r, t in zip(R, values[:, :3], strict=True)]))
    return groundtruth_in_camera(T_w_gt, timestamps, T_gt_rect, f"{bag}: {topic}")


def _pose_values(message, fields: tuple[str, str, str]) -> list[float]:
    """``[x, y, z, qx, qy, qz, qw]`` of a pose message; ``fields`` from `POSE_FIELDS`."""
    pose = message
    for name in fields[0].split("."):
        pose = getattr(pose, name)
    t, q = getattr(pose, fields[1]), getattr(pose, fields[2])
    return [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
