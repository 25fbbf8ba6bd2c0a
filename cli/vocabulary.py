"""``pld-slam vocabulary build``: train the bag-of-words vocabulary of the ``bow`` loop detector."""

import time
from pathlib import Path

import click
from tqdm import tqdm

from pld_slam.config import load_config
from pld_slam.io.output_folder import create_output_folder
from pld_slam.loop.vocabulary import build_vocabulary
from pld_slam.loop.vocabulary_training import count_training_images, training_descriptors
from pld_slam_cli.config import config_files_option, set_option


@click.group("vocabulary")
def vocabulary_command() -> None:
    """Bag-of-words vocabularies for `--set loop.detector=bow`."""


@vocabulary_command.command("build")
@click.argument("image_dirs", nargs=-1, required=True,
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Vocabulary file to write (.npz).")
@click.option("--branching", type=click.IntRange(min=2), default=10, show_default=True,
              help="Children per node (DBoW2's k).")
@click.option("--depth", type=click.IntRange(min=1), default=5, show_default=True,
              help="Levels below the root (DBoW2's L).")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True,
              help="Use every N-th image of each folder.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the clustering.")
@config_files_option
@set_option
def build_command(
    image_dirs: tuple[Path, ...], out: Path, branching: int, depth: int, every: int, seed: int,
    config_paths: tuple[Path, ...], overrides: tuple[str, ...],
) -> None:
    """Train a vocabulary tree on the ORB features of the images in IMAGE_DIRS.

    Each folder is a sequence in any layout `pld-slam run` reads (its left images) or a
    plain folder of images. The same images, options and seed give the same file. Use it
    with `pld-slam run SEQUENCE --set loop.detector=bow --set loop.vocabulary=OUT`; train
    it on other sequences than those you evaluate on.
    """
    start = time.perf_counter()
    points = load_config(config_paths, overrides).points
    create_output_folder(out.parent)
    n_images = count_training_images(image_dirs, every)
    with tqdm(total=n_images, desc="features", unit="image", leave=False, disable=None) as bar:
        descriptors = training_descriptors(image_dirs, points, every, bar.update)
    with tqdm(total=depth, desc="clustering", unit="level", leave=False, disable=None) as bar:
        vocabulary = build_vocabulary(descriptors, branching, depth, seed, progress=bar.update)
    vocabulary.save(out)
    click.echo(
        f"wrote {out}: {vocabulary.n_words} words (k={branching}, L={depth}) from "
        f"{sum(len(d) for d in descriptors)} descriptors of {n_images} images in {time.perf_counter() - start:.1f} s"
    )
