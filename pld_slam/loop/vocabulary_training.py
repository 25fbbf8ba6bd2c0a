"""Training descriptors for a vocabulary: ORB features of the images of one or more folders.

A folder is read as a stereo sequence when one of the dataset layouts matches it
(`pld_slam.datasets.open_sequence`: its left images, rectified where the layout needs it),
and as a plain folder of images otherwise (`pld_slam.loop.places.natural_sorted_images`).
Features come from the pipeline's own ORB detector (`pld_slam.frontend.points`, with the
run's ``points`` settings), so that the words a vocabulary learns are the words a run
computes.
"""

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from pld_slam.config import PointsConfig
from pld_slam.datasets import open_sequence
from pld_slam.errors import DatasetError
from pld_slam.frontend.points import detect_image_points
from pld_slam.loop.places import natural_sorted_images, read_images


def folder_images(folder: Path, every: int = 1) -> tuple[int, Iterator[np.ndarray]]:
    """How many images ``folder`` gives with every ``every``-th kept, and the grey images (H, W) uint8, lazily."""
    try:
        sequence = open_sequence(folder)
    except DatasetError:
        paths = natural_sorted_images(folder)[::every]
        return len(paths), read_images(paths)
    indices = range(0, len(sequence), every)
    return len(indices), (sequence[index].left for index in indices)


def training_descriptors(
    folders: Sequence[Path], config: PointsConfig, every: int = 1, progress: Callable[[int], None] | None = None
) -> list[np.ndarray]:
    """The ORB descriptors (K_i, 32) uint8 of each training image of ``folders`` (module docstring).

    ``progress`` is called with 1 after each image.
    """
    descriptors = []
    for folder in folders:
        _, images = folder_images(Path(folder), every)
        for image in images:
            descriptors.append(detect_image_points(image, config).descriptors)
            if progress is not None:
                progress(1)
    return descriptors


def count_training_images(folders: Sequence[Path], every: int = 1) -> int:
    """The number of images `training_descriptors` reads from ``folders``."""
    return sum(folder_images(Path(folder), every)[0] for folder in folders)
