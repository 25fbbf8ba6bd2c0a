"""KITTI's two stereo pairs, and which one a sequence is read from (``dataset.cameras``).

KITTI's rig has a grey pair (cam0, cam1: odometry ``image_0/``, ``image_1/``; raw
``image_00/``, ``image_01/``) and a colour pair (cam2, cam3: ``image_2/``, ``image_3/``;
raw ``image_02/``, ``image_03/``). All four are rectified to cam0's orientation, and each
has its projection matrix ``K [I | t]`` of points in cam0's rectified frame (odometry
``P0``-``P3`` of ``calib.txt``, raw ``P_rect_00``-``P_rect_03`` of ``calib_cam_to_cam.txt``).
Both layouts (`pld_slam.datasets.kitti_odometry`, `pld_slam.datasets.kitti_raw`) read
either pair the same way:

- Which pair: ``auto`` (the default) reads the grey pair, or the colour one where the
  folder has the colour left images and not the grey ones (a colour-only download);
  ``grey`` or ``colour`` asks for one, and a folder without it raises, naming the image
  folder missing. The sequence's ``cameras`` says which pair it was read from.
- Images: the colour ones are read as grey (`pld_slam.datasets.base.decode_grey`).
- Camera: `pld_slam.datasets.calibration.stereo_camera_from_projections` of the pair's
  two matrices: the colour pair has its own principal point and baseline (0.5354 m on
  odometry 04 against the grey pair's 0.5372).
- Ground truth: KITTI's (the odometry poses, the raw OXTS poses as the devkit moves
  them) is of cam0. The colour pair's is of cam2, whose pose in cam0 is
  ``T_c0_c2 = inv(camera_from_reference(P2))``, a translation (6 cm to the left): each
  reader moves its cam0 poses to ``T_w_c2 = T_w_c0 T_c0_c2``, then puts the first at
  identity, which gives ``T_c2_c0 inv(T_w_c0(0)) T_w_c0(i) T_c0_c2``. The translation is
  all of ``t = K^-1 P2[:, 3]``, not ``P2[0, 3] / fx`` alone: that would put cam2 5 mm off
  in x and miss its 1.4 mm in y and 6.2 mm in z (odometry 04).
"""

from dataclasses import dataclass
from pathlib import Path

from pld_slam.errors import ConfigError, DatasetError

CAMERAS = ("auto", "grey", "colour")
"""The values of ``dataset.cameras`` (`pld_slam.config.DatasetConfig`)."""


@dataclass(frozen=True)
class CameraPair:
    """One of KITTI's stereo pairs as a layout stores it.

    Attributes
    ----------
    name : str
        ``grey`` or ``colour``, as ``dataset.cameras`` names it.
    left, right : Path
        The folders of its left and right images.
    keys : tuple of str
        The calibration keys of its left and right projection matrices (``P2``, ``P3``).
    """

    name: str
    left: Path
    right: Path
    keys: tuple[str, str]

    @property
    def colour(self) -> bool:
        """Whether the pair's images are colour (read as grey)."""
        return self.name == "colour"


def chosen_pair(grey: CameraPair, colour: CameraPair, cameras: str) -> CameraPair:
    """The pair ``cameras`` (``auto``, ``grey`` or ``colour``) names, its folders checked.

    ``auto`` is the colour pair where its left folder exists and the grey one's does
    not, else the grey pair (whose missing folders the layout's reader names).

    Raises
    ------
    DatasetError
        ``grey`` or ``colour`` asked for where its image folders are missing (naming the
        first missing).
    ConfigError
        An unknown value of ``cameras``.
    """
    if cameras not in CAMERAS:
        raise ConfigError(f"dataset.cameras: {cameras!r} is not one of {', '.join(CAMERAS)}")
    if cameras == "auto":
        return colour if colour.left.is_dir() and not grey.left.is_dir() else grey
    pair = grey if cameras == "grey" else colour
    for folder in (pair.left, pair.right):
        if not folder.is_dir():
            raise DatasetError(f"{folder}: image folder not found (dataset.cameras={cameras} reads the {cameras} pair)")
    return pair
