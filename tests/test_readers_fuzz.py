"""Every reader of a user's file, fed arbitrary bytes and mutated valid files (issue 43).

The class of bug, not its cases: whatever a file holds, its reader gives a parsed result or
one `PldSlamError` whose message names the file, never another exception (a traceback
instead of the CLI's one ``error:`` line). Each reader is fed (a) arbitrary bytes and
(b) a valid file mutated: bytes flipped, lines dropped or repeated, the file cut short,
numbers replaced by ``nan``, ``inf``, a huge number, nothing or text. Files inside a
sequence folder are read the way a run reads them, by `open_sequence`. The examples are
derandomized (``tests/conftest.py``'s hypothesis profile), so every run tries the same.
"""

import json
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_argoverse import PERIOD_NS, START_NS, make_log, random_vehicle_poses
from test_datasets import (
    B_FROM_CAM0,
    kitti_pose_rows,
    make_euroc,
    make_generic,
    make_kitti_raw,
    rectified_calibration,
    sensor_yaml,
    write_lines,
)

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.datasets.files import jpeg_size, png_size
from pld_slam.errors import PldSlamError
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.trajectory import read_euroc, read_kitti, read_trajectory, read_tum
from pld_slam.loop.places import load_ground_truth
from pld_slam.loop.vocabulary import Vocabulary, build_vocabulary
from pld_slam.report.regress import read_baseline
from pld_slam.report.suite import load_suite
from pld_slam.synth.writer import write_sequence

FUZZ = settings(max_examples=int(os.environ.get("PLD_SLAM_FUZZ_EXAMPLES", "60")), deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
"""Each reader's examples: 60 keep the whole file under a minute; ``PLD_SLAM_FUZZ_EXAMPLES=3000`` searches deeper."""

NUMBER = re.compile(rb"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
NOT_NUMBERS = [b"nan", b"inf", b"-inf", b"1e308", b"1e999", b"-1e999", b"99999999999999999999999", b"", b"text",
               b"0", b"-1"]


def flip_bytes(draw, data: bytes) -> bytes:
    """``data`` with a few bytes replaced by arbitrary ones."""
    if not data:
        return data
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        out[draw(st.integers(0, len(out) - 1))] = draw(st.integers(0, 255))
    return bytes(out)


def drop_line(draw, data: bytes) -> bytes:
    """``data`` without one of its lines."""
    lines = data.splitlines(keepends=True)
    if not lines:
        return data
    del lines[draw(st.integers(0, len(lines) - 1))]
    return b"".join(lines)


def duplicate_line(draw, data: bytes) -> bytes:
    """``data`` with one of its lines written twice."""
    lines = data.splitlines(keepends=True)
    if not lines:
        return data
    at = draw(st.integers(0, len(lines) - 1))
    return b"".join(lines[: at + 1] + lines[at:])


def replace_number(draw, data: bytes) -> bytes:
    """``data`` with one of its numbers replaced by nan, inf, a huge number, nothing or text."""
    found = list(NUMBER.finditer(data))
    if not found:
        return data
    match = found[draw(st.integers(0, len(found) - 1))]
    return data[: match.start()] + draw(st.sampled_from(NOT_NUMBERS)) + data[match.end():]


def truncate(draw, data: bytes) -> bytes:
    """``data`` cut short."""
    return data[: draw(st.integers(0, len(data)))]


MUTATIONS = (flip_bytes, drop_line, duplicate_line, replace_number, truncate)


@st.composite
def mutated(draw, valid: bytes) -> bytes:
    """``valid`` after one to three `MUTATIONS`."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        data = draw(st.sampled_from(MUTATIONS))(draw, data)
    return data


def contents(valid: bytes) -> st.SearchStrategy[bytes]:
    """Arbitrary bytes, or ``valid`` mutated (weighted towards the mutations, which reach further)."""
    return st.one_of(st.binary(max_size=400), mutated(valid), mutated(valid))


def read_or_name_the_file(read: Callable[[], object], path: Path) -> None:
    """``read()`` parses, or raises a one-line `PldSlamError` naming ``path``; anything else fails the test."""
    try:
        read()
    except PldSlamError as error:
        message = str(error)
        assert str(path) in message, f"the error does not name {path}: {message}"
        assert "\n" not in message, message


@dataclass(frozen=True)
class FolderFile:
    """A file of a sequence folder: the folder's maker and the file's path in the folder it returns."""

    make: Callable[[Path], Path]
    relative: str


def make_synthetic(root: Path) -> Path:
    """A 3-frame synthetic sequence (KITTI odometry layout with poses.txt and synth.json)."""
    folder = root / "synthetic"
    write_sequence(folder, "static", 3, size=(96, 72), seed=0)
    return folder


def make_kitti_with_official_poses(root: Path) -> Path:
    """A 3-frame synthetic sequence under ``sequences/00`` with KITTI's ``poses/00.txt`` beside it."""
    folder = make_synthetic(root / "kitti" / "sequences")
    folder = folder.rename(folder.parent / "00")
    poses = np.stack([make_pose(np.eye(3), np.array([0.0, 0.0, 0.5 * i])) for i in range(3)])
    write_lines(root / "kitti" / "poses" / "00.txt", kitti_pose_rows(poses))
    (folder / "poses.txt").unlink()
    return folder


def make_raw(root: Path) -> Path:
    """A 3-frame KITTI raw drive with OXTS packets and their times."""
    return make_kitti_raw(root, packet_times=[f"2011-01-01 00:00:{i:02d}.100000001" for i in range(3)])


def make_generic_with_times_and_groundtruth(root: Path) -> Path:
    """A 3-frame generic rig with ``times.txt`` and a TUM ``groundtruth.txt``."""
    folder = make_generic(root, rectified_calibration())
    write_lines(folder / "times.txt", ["0.0", "0.1", "0.2"])
    write_lines(folder / "groundtruth.txt", [f"{0.1 * i:.1f} {0.2 * i} 0 0 0 0 0 1" for i in range(3)])
    return folder


def make_argoverse(root: Path) -> Path:
    """A 3-frame Argoverse log with vehicle poses."""
    return make_log(root, vehicle_poses=random_vehicle_poses(3))


FOLDER_FILES = {
    "kitti times": FolderFile(make_synthetic, "times.txt"),
    "kitti calib": FolderFile(make_synthetic, "calib.txt"),
    "synthetic poses": FolderFile(make_synthetic, "poses.txt"),
    "synth.json": FolderFile(make_synthetic, "synth.json"),
    "kitti official poses": FolderFile(make_kitti_with_official_poses, "../../poses/00.txt"),
    "kitti raw cam_to_cam": FolderFile(make_raw, "../calib_cam_to_cam.txt"),
    "kitti raw velo_to_cam": FolderFile(make_raw, "../calib_velo_to_cam.txt"),
    "kitti raw imu_to_velo": FolderFile(make_raw, "../calib_imu_to_velo.txt"),
    "kitti raw image times": FolderFile(make_raw, "image_00/timestamps.txt"),
    "kitti raw oxts packet": FolderFile(make_raw, "oxts/data/0000000001.txt"),
    "kitti raw oxts times": FolderFile(make_raw, "oxts/timestamps.txt"),
    "euroc image list": FolderFile(make_euroc, "mav0/cam0/data.csv"),
    "euroc sensor.yaml": FolderFile(make_euroc, "mav0/cam1/sensor.yaml"),
    "euroc ground truth": FolderFile(make_euroc, "mav0/state_groundtruth_estimate0/data.csv"),
    "generic calib.yaml": FolderFile(make_generic_with_times_and_groundtruth, "calib.yaml"),
    "generic times": FolderFile(make_generic_with_times_and_groundtruth, "times.txt"),
    "generic ground truth": FolderFile(make_generic_with_times_and_groundtruth, "groundtruth.txt"),
    "argoverse calibration": FolderFile(make_argoverse, "vehicle_calibration_stereo_info.json"),
    "argoverse pose": FolderFile(make_argoverse, f"poses/city_SE3_egovehicle_{START_NS + PERIOD_NS}.json"),
}


@pytest.mark.parametrize("name", FOLDER_FILES)
def test_a_sequence_file_opens_or_its_error_names_it(name, tmp_path):
    spec = FOLDER_FILES[name]
    folder = spec.make(tmp_path)
    path = (folder / spec.relative).resolve()
    valid = path.read_bytes()
    open_sequence(folder)  # the valid folder opens

    @FUZZ
    @given(contents(valid))
    def check(data: bytes) -> None:
        path.write_bytes(data)
        read_or_name_the_file(lambda: open_sequence(folder), path)

    check()


FOUND = [  # what the fuzzing above found, each a traceback before issue 43's fixes
    ("kitti times", b"\x80"),  # not UTF-8: UnicodeDecodeError (every text reader)
    ("kitti calib", b"P0: 57.6 0 48 0 0 57.6 36 0 0 0 0 0\nP1: 57.6 0 48 -28.8 0 57.6 36 0 0 0 1 0\n"),  # singular
    ("kitti raw velo_to_cam", b"R: 0 0 0 0 0 -1 1 0 0\nT: 0.1 -0.2 0.3\n"),  # not a rotation: LinAlgError
    ("kitti raw image times", b"\t011-01-01 00:00:00.100000001\n2011-01-01 00:00:01.100000001\n"
                              b"2011-01-01 00:00:02.100000001\n"),  # the error named only oxts/timestamps.txt
    ("euroc image list", b"#timestamp [ns],filename\n99999999999999999999999,a.png\n"),  # OverflowError
    ("euroc image list", "#timestamp [ns],filename\n\u00b2,a.png\n".encode()),  # a digit int() refuses
    ("euroc image list", b"#timestamp [ns],filename\n1403715273262142975,a.png\n1403715273312142976,b.png\n"
                         b"1403715273362142976,c.png\n"),  # a time cam1 lacks: the error named only cam1's list
    ("euroc sensor.yaml", sensor_yaml(make_pose(B_FROM_CAM0, np.array([0.01, -0.02, 0.03]))).encode()),  # cv2.error
]


@pytest.mark.parametrize(("name", "data"), FOUND)
def test_what_the_fuzzing_found_is_an_error_naming_the_file(name, data, tmp_path):
    spec = FOLDER_FILES[name]
    folder = spec.make(tmp_path)
    path = (folder / spec.relative).resolve()
    path.write_bytes(data)
    with pytest.raises(PldSlamError) as caught:
        open_sequence(folder)
    assert str(path) in str(caught.value)


def test_a_damaged_vocabulary_is_an_error_naming_it(tmp_path):
    path = tmp_path / "vocabulary.npz"
    path.write_bytes(vocabulary_bytes(path)[:100])  # EOFError, zlib.error, BadZipFile before issue 43
    with pytest.raises(PldSlamError, match=f"{path}: not a pld-slam vocabulary"):
        Vocabulary.load(path)


def test_a_text_file_given_as_vocabulary_is_an_error_naming_it_without_numpy_advice(tmp_path):
    path = tmp_path / "vocabulary.txt"
    path.write_text("not a vocabulary\n")
    with pytest.raises(PldSlamError, match=f"^{path}: not a pld-slam vocabulary") as caught:
        Vocabulary.load(path)
    assert "allow_pickle" not in str(caught.value)


def tum_text() -> str:
    return "".join(f"{0.1 * i:.1f} {0.2 * i} 0.1 0 0 0 0.0998 0.995\n" for i in range(4))


def kitti_text() -> str:
    return "".join(" ".join(f"{v:.6g}" for v in make_pose(np.eye(3), np.array([0.2 * i, 0, 0]))[:3].ravel()) + "\n"
                   for i in range(4))


def euroc_text() -> str:
    return "#timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z\n" + "".join(
        f"{1_403_715_273_262_142_976 + i * 50_000_000},{0.2 * i},0,0,1,0,0,0\n" for i in range(4))


def config_text() -> str:
    return "points:\n  n_features: 1500\n  stereo_ratio: 0.7\nloop:\n  detector: bow\nmapping:\n  enabled: false\n"


def suite_text() -> str:
    return "description: fewer features\nvariants:\n  paper: {}\n  half: {points.n_features: 1000}\n"


def baseline_text() -> str:
    return json.dumps({"description": "ci", "tolerance": {"relative": 0.1, "absolute_m": 0.001}, "cells": [
        {"name": "static", "sequence": {"synthetic": "static", "seed": 0, "frames": 20}, "ate_rmse_m": 0.05},
        {"name": "kitti", "sequence": {"data": "kitti_odometry/sequences/06"}, "overrides": ["points.n_features=1500"],
         "ate_rmse_m": 0.03},
    ]}, indent=1)


def loop_matrix_text() -> str:
    return "0,0,1\n0 0 0\n1, 0, 0\n"


def png_bytes(image: np.ndarray) -> bytes:
    """``image`` encoded as PNG."""
    return cv2.imencode(".png", image)[1].tobytes()


def jpeg_bytes(image: np.ndarray) -> bytes:
    """``image`` encoded as JPEG."""
    return cv2.imencode(".jpg", image)[1].tobytes()


def vocabulary_bytes(path: Path) -> bytes:
    """A small vocabulary (random descriptors, branching 3, depth 2) as `Vocabulary.save` writes it at ``path``."""
    rng = np.random.default_rng(0)
    build_vocabulary([rng.integers(0, 256, (40, 32), dtype=np.uint8)], branching=3, depth=2).save(path)
    return path.read_bytes()


@dataclass(frozen=True)
class FileReader:
    """A reader of one file: its name in the test folder, a valid content (written there first), and the call."""

    name: str
    valid: Callable[[Path], bytes]
    read: Callable[[Path], object]


FILE_READERS = {
    "tum": FileReader("estimate.tum.txt", lambda _: tum_text().encode(), read_tum),
    "kitti": FileReader("estimate.kitti.txt", lambda _: kitti_text().encode(), read_kitti),
    "euroc": FileReader("estimate.euroc.csv", lambda _: euroc_text().encode(), read_euroc),
    "trajectory auto": FileReader("estimate.txt", lambda _: tum_text().encode(), read_trajectory),
    "config yaml": FileReader("config.yaml", lambda _: config_text().encode(), lambda path: load_config([path])),
    "suite yaml": FileReader("suite.yaml", lambda _: suite_text().encode(), lambda path: load_suite(str(path))),
    "baseline json": FileReader("baseline.json", lambda _: baseline_text().encode(), read_baseline),
    "loop matrix csv": FileReader("loops.csv", lambda _: loop_matrix_text().encode(),
                                  lambda path: load_ground_truth(path, 3)),
    "loop matrix png": FileReader("loops.png", lambda _: png_bytes(np.eye(3, dtype=np.uint8) * 255),
                                  lambda path: load_ground_truth(path, 3)),
    "vocabulary": FileReader("vocabulary.npz", vocabulary_bytes, Vocabulary.load),
    "png header": FileReader("image.png", lambda _: png_bytes(np.zeros((4, 6), np.uint8)), png_size),
    "jpeg header": FileReader("image.jpg", lambda _: jpeg_bytes(np.zeros((4, 6), np.uint8)), jpeg_size),
}


@pytest.mark.parametrize("name", FILE_READERS)
def test_a_user_file_parses_or_its_error_names_it(name, tmp_path):
    reader = FILE_READERS[name]
    path = tmp_path / reader.name
    valid = reader.valid(path)
    path.write_bytes(valid)
    reader.read(path)  # the valid file parses

    @FUZZ
    @given(contents(valid))
    def check(data: bytes) -> None:
        path.write_bytes(data)
        read_or_name_the_file(lambda: reader.read(path), path)

    check()
