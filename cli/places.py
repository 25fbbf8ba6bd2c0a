"""``pld-slam places``: place recognition on its own, on a folder of images, against ground truth."""

import json
from pathlib import Path

import click
import numpy as np
from tqdm import tqdm

from pld_slam.config import Config
from pld_slam.errors import PldSlamError
from pld_slam.eval.place_plots import plot_precision_recall, plot_similarity_matrix
from pld_slam.io.output_folder import create_output_folder
from pld_slam.loop.places import (
    DETECTORS,
    PlaceScores,
    evaluate_places,
    load_ground_truth,
    natural_sorted_images,
    place_scorer,
    read_images,
)


def format_places_table(n_images: int, scores: PlaceScores | None) -> str:
    """Images and, with ground truth, the place-recognition figures as aligned text (NaN as n/a)."""

    def number(value: float) -> str:
        return "n/a" if np.isnan(value) else f"{value:.4f}"

    rows = [("images", str(n_images))]
    if scores is not None:
        rows += [
            ("queries with a true match", f"{scores.n_with_true_match} of {scores.n_queries}"),
            ("top-1 accuracy", number(scores.top1_accuracy)),
            ("recall at 100% precision", number(scores.recall_at_full_precision)),
            ("average precision", number(scores.average_precision)),
        ]
    return "\n".join(f"{label:<28}{value}" for label, value in rows)


def check_some_image_is_compared(image_dir: Path, n_images: int, exclude_recent: int) -> None:
    """`PldSlamError` when no image of ``image_dir`` has an earlier one outside the ``exclude_recent`` images
    before it: nothing would be scored."""
    if n_images <= exclude_recent + 1:
        left_out = f", the {exclude_recent} before each left out by --exclude-recent" if exclude_recent else ""
        raise PldSlamError(f"{image_dir}: no image has an earlier one to be compared with ({n_images} images"
                           f"{left_out})")


def _with_progress(paths: list[Path], description: str):
    """``paths`` with a progress bar on stderr (on a terminal), shown from the first image read."""
    with tqdm(paths, desc=description, unit="image", disable=None, leave=False) as bar:
        yield from bar


@click.command("places")
@click.argument("image_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--detector", type=click.Choice(DETECTORS), default="ggs", show_default=True,
              help="Place recognition: global gray similarity, or bag of words (needs --vocabulary).")
@click.option("--vocabulary", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Vocabulary file of the bow detector (pld-slam vocabulary build).")
@click.option("--exclude-recent", type=click.IntRange(min=0), default=0, show_default=True,
              help="Leave the N images just before each query out of its matches and of its ground truth.")
@click.option("--gt", "gt_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Ground-truth loop matrix: an N x N image (non-zero = same place) or a CSV of 0/1.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Output folder [default: places/<IMAGE_DIR name>].")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
def places_command(image_dir: Path, detector: str, vocabulary: Path | None, exclude_recent: int,
                   gt_path: Path | None, out_dir: Path | None, as_json: bool) -> None:
    """Score every image of IMAGE_DIR against the earlier ones, and evaluate against ground truth.

    Images (grey or colour, any size; png, jpg, jpeg, bmp, ppm, pgm, tif, tiff) are taken in natural name order
    (2.jpg before 10.jpg). Writes similarity.npy (N x N, higher = more similar, NaN where
    not scored) and similarity.png into --out; with --gt, the best match of each image is
    judged: top-1 accuracy over the images that have a true match, recall at 100 %
    precision, average precision, and precision_recall.png.
    """
    paths = natural_sorted_images(image_dir)
    check_some_image_is_compared(image_dir, len(paths), exclude_recent)
    ground_truth = None if gt_path is None else load_ground_truth(gt_path, len(paths))
    score = place_scorer(detector, vocabulary, exclude_recent, Config())
    out_dir = Path("places") / image_dir.resolve().name if out_dir is None else out_dir
    create_output_folder(out_dir)
    similarity = score(read_images(_with_progress(paths, f"{detector} {image_dir.name}")))
    scores = None if ground_truth is None else evaluate_places(similarity, ground_truth, exclude_recent)

    np.save(out_dir / "similarity.npy", similarity)
    plot_similarity_matrix(out_dir / "similarity.png", similarity, title=f"{detector.upper()} similarity")
    if scores is not None:
        plot_precision_recall(out_dir / "precision_recall.png", scores, title=detector.upper())

    if as_json:
        result = scores.as_dict() if scores is not None else {
            "images": len(paths), "queries": None, "queries_with_true_match": None, "top1_accuracy": None,
            "recall_at_full_precision": None, "average_precision": None,
        }
        click.echo(json.dumps(result))
    else:
        click.echo(format_places_table(len(paths), scores))
        click.echo(f"wrote {out_dir}")

