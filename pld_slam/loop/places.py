"""Place recognition on its own: score every image of a folder against the earlier ones,
and evaluate the best match of each against a ground-truth loop matrix.

This is how place-recognition methods are compared on standard image sets (a folder of
images in the order they were taken, and an N x N matrix marking the pairs that show the
same place). `pld-slam places` is the command; here is the library, plain numpy between
the steps:

    paths = natural_sorted_images(folder)
    similarity = place_similarity(read_images(paths), "ggs", exclude_recent=k)     # (N, N)
    scores = evaluate_places(similarity, load_ground_truth(gt_path, len(paths)), k)

The similarity matrix. ``similarity[i, j]`` is how alike query image ``i`` and database
image ``j`` are, **higher = more similar**, whatever the detector. Only the pairs
``j < i - exclude_recent`` are scored (each image against the earlier ones, leaving out
the ``exclude_recent`` just before it); every other entry is NaN (`eligible_pairs`). For
GGS the similarity is the negated GGS distance ``-sim_v`` (`pld_slam.frontend.ggs`:
``sim_v`` is 0 for identical images and grows as they differ), so it lies in about
[-2, 0] with 0 for identical images; for bag of words it is DBoW2's L1 score of the
images' ORB words, in [0, 1]. A detector is a function from the images to this matrix;
`place_similarity` dispatches on the detector's name.

What the issue leaves open, and what we decide:

- Order: file names in natural order (``2.jpg`` before ``10.jpg``; digits compare as
  numbers, the rest case-insensitively, the name itself breaks the remaining ties such as
  ``01`` / ``1``). Files with the extensions of `IMAGE_EXTENSIONS` (any case) directly in
  the folder; sub-folders and hidden files (``.name``) are ignored.
- Images are read as grey (colour converted by OpenCV), any size; they are read one at a
  time and only their descriptors kept, so a long set does not fill the memory.
- Recent images: ``exclude_recent`` (default 0 in the CLI: every earlier image) removes
  the images just before a query from its database *and* from the ground truth: a query
  "has a true match" only if an image it may match is marked. Sets whose ground truth
  marks consecutive frames as the same place need a window here, or every query is
  trivially matched to its predecessor.
- The ground truth is symmetrised (``gt[i, j] or gt[j, i]``): sets ship it as the lower
  triangle, the upper, or both. Its diagonal is never used.
- One detection per query: its best match ``j* = argmax_j similarity[i, j]`` over the
  eligible ``j``; equal best scores go to the earliest image. A NaN score among the
  eligible counts as the least similar. Queries with no eligible image (the first
  ``exclude_recent + 1``) make no detection and are not counted anywhere.
- Top-1 accuracy: among the queries with a true match, the share whose best match is
  true. Queries without a true match do not enter it (but do enter precision-recall,
  where their detection is a false positive at any threshold that accepts it).
- Precision-recall: a threshold on the best-match similarity accepts the queries at or
  above it; a detection is a true positive if ``gt[i, j*]``; recall is over the queries
  with a true match (a query whose best match is wrong is a false positive *and* a miss).
  The curve has one point per distinct best-match score, highest first. Ties between
  queries are therefore taken together: one threshold cannot separate two equal scores,
  so their order (a stable sort by query index) changes nothing. Without ties this is
  the same as one point per rank.
- Recall at 100 % precision: the largest recall of a point whose precision is exactly 1
  (0 when the highest-scored detection is false).
- Average precision: ``sum_k (R_k - R_{k-1}) P_k`` over the points of the curve, which is
  without ties the usual "sum of the precision at each true positive's rank, divided by
  the number of queries with a true match" (scikit-learn's ``average_precision_score``).
- No query with a true match (or no ground truth marks at all): top-1 accuracy, recall
  and average precision are NaN (``null`` in JSON).
"""

import functools
import math
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pld_slam.config import Config, GgsConfig, PointsConfig
from pld_slam.datasets.base import read_grey
from pld_slam.datasets.files import natural_sorted
from pld_slam.errors import DatasetError, PldSlamError, read_user_text
from pld_slam.frontend.ggs import GgsDatabase, ggs_and_place_descriptors, ggs_distances
from pld_slam.frontend.points import detect_image_points
from pld_slam.loop.bow_detector import BowDatabase
from pld_slam.loop.vocabulary import Vocabulary

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".tif", ".tiff")
"""File extensions read as images (compared case-insensitively)."""

DETECTORS = ("ggs", "bow")
"""Place-recognition detectors `place_similarity` knows."""

VOCABULARY_HINT = "build one with `pld-slam vocabulary build IMAGE_DIR... --out vocab.npz`"


# --- the images --------------------------------------------------------------------------


def natural_sorted_images(folder: Path) -> list[Path]:
    """The image files directly in ``folder``, in natural order of their names (module docstring).

    Raises `DatasetError` when ``folder`` is not a folder or holds no image file.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder")
    paths = [
        path for path in folder.iterdir()
        if path.is_file() and not path.name.startswith(".") and path.suffix.lower() in IMAGE_EXTENSIONS
    ]
    if not paths:
        raise DatasetError(f"{folder}: no images ({', '.join(ext[1:] for ext in IMAGE_EXTENSIONS)})")
    return natural_sorted(paths)


def read_images(paths: Iterable[Path]) -> Iterator[np.ndarray]:
    """Each file as a grey image (H, W) uint8, read lazily; `DatasetError` naming an unreadable file."""
    for path in paths:
        yield read_grey(Path(path))


# --- the similarity matrix ---------------------------------------------------------------


def eligible_pairs(n_images: int, exclude_recent: int = 0) -> np.ndarray:
    """(N, N) bool: True where database image ``j`` may match query ``i``, i.e. ``j < i - exclude_recent``."""
    if exclude_recent < 0:
        raise ValueError(f"exclude_recent must be >= 0, got {exclude_recent}")
    index = np.arange(n_images)
    return index[None, :] < index[:, None] - exclude_recent


def lower_rows_matrix(rows: list[np.ndarray]) -> np.ndarray:
    """The (N, N) matrix whose row ``i`` starts with ``rows[i]`` (at most N values), NaN after it."""
    similarity = np.full((len(rows), len(rows)), np.nan)
    for index, row in enumerate(rows):
        similarity[index, : len(row)] = row
    return similarity


def ggs_place_scores(images: Iterable[np.ndarray], config: GgsConfig = GgsConfig(),
                     exclude_recent: int = 0) -> np.ndarray:
    """GGS similarity matrix (N, N) float64 of grey images (H, W) uint8: ``-sim_v``, NaN where not eligible.

    The GGS is place recognition's (`pld_slam.frontend.ggs.ggs_and_place_descriptors`).

    Streams: each image's descriptor is computed, queried against the descriptors of the
    images it may match (``j < i - exclude_recent``, all seen already) and kept; the
    images themselves are not. Images may differ in size (GGS histograms are normalised
    per cell).
    """
    database = GgsDatabase()
    rows: list[np.ndarray] = []
    for index, image in enumerate(images):
        _, descriptor = ggs_and_place_descriptors(image, config)
        n_database = max(index - exclude_recent, 0)
        rows.append(-ggs_distances(descriptor, database.descriptors[:n_database]) if n_database else np.zeros(0))
        database.add(index, descriptor)
    return lower_rows_matrix(rows)


def bow_place_scores(images: Iterable[np.ndarray], vocabulary: Vocabulary, config: PointsConfig = PointsConfig(),
                     exclude_recent: int = 0) -> np.ndarray:
    """Bag-of-words similarity matrix (N, N) float64 of grey images (H, W) uint8: DBoW2's L1
    score (`pld_slam.loop.vocabulary.bow_score`, 0 without a shared word), NaN where not eligible.

    Each image's ORB descriptors (the pipeline's detector, ``config``) become its vector,
    scored through the inverse index (`pld_slam.loop.bow_detector.BowDatabase`) against
    the images it may match, then indexed; like `ggs_place_scores`, it streams.
    """
    database = BowDatabase()
    rows: list[np.ndarray] = []
    for index, image in enumerate(images):
        vector = vocabulary.bow_vector(detect_image_points(image, config).descriptors)
        n_database = max(index - exclude_recent, 0)
        row = np.zeros(n_database)
        ids, _, scores = database.query(vector)
        eligible = ids < n_database
        row[ids[eligible]] = scores[eligible]
        rows.append(row)
        database.add(index, vector)
    return lower_rows_matrix(rows)


def place_similarity(images: Iterable[np.ndarray], detector: str = "ggs", vocabulary: Path | None = None,
                     exclude_recent: int = 0, config: Config = Config()) -> np.ndarray:
    """The similarity matrix (N, N) float64 of grey images (H, W) uint8 by ``detector`` (module docstring).

    Parameters
    ----------
    images : iterable of (H, W) uint8
        The images in order (e.g. ``read_images(natural_sorted_images(folder))``).
    detector : {"ggs", "bow"}
        GGS (``config.ggs``), or bag of words (needs ``vocabulary``; ORB features by ``config.points``).
    vocabulary : Path or None
        A vocabulary file for ``bow``; an error with any other detector.
    exclude_recent : int
        Images just before a query that it is not compared with.

    Returns
    -------
    (N, N) float64: ``[i, j]`` higher = more similar for ``j < i - exclude_recent``, NaN elsewhere.
    """
    return place_scorer(detector, vocabulary, exclude_recent, config)(images)


def place_scorer(detector: str = "ggs", vocabulary: Path | None = None, exclude_recent: int = 0,
                 config: Config = Config()) -> Callable[[Iterable[np.ndarray]], np.ndarray]:
    """`place_similarity` of the images, its detector and options checked (and a ``bow`` vocabulary loaded)
    now, before any image is read; `PldSlamError` for a detector without its vocabulary or with one it does
    not use."""
    if exclude_recent < 0:
        raise ValueError(f"exclude_recent must be >= 0, got {exclude_recent}")
    if detector == "ggs":
        if vocabulary is not None:
            raise PldSlamError("a vocabulary is only used by the bow detector, not by ggs")
        return functools.partial(ggs_place_scores, config=config.ggs, exclude_recent=exclude_recent)
    if detector == "bow":
        if vocabulary is None:
            raise PldSlamError(f"the bow detector needs a vocabulary (--vocabulary FILE); {VOCABULARY_HINT}")
        return functools.partial(bow_place_scores, vocabulary=Vocabulary.load(vocabulary), config=config.points,
                                 exclude_recent=exclude_recent)
    raise PldSlamError(f"unknown place detector {detector!r} (one of {', '.join(DETECTORS)})")


# --- ground truth ------------------------------------------------------------------------


def load_ground_truth(path: Path, n_images: int) -> np.ndarray:
    """A ground-truth loop matrix (N, N) bool from an image or a text file, symmetrised.

    An image (any extension of `IMAGE_EXTENSIONS`, grey or colour, any bit depth): every
    non-zero pixel marks a pair. Anything else is read as text: one row per line, numbers
    separated by commas and/or white space, non-zero marks a pair; empty lines and lines
    starting with ``#`` are skipped. The matrix must be ``n_images`` x ``n_images``;
    `DatasetError` naming the file otherwise. Returns ``gt | gt.T``.
    """
    path = Path(path)
    if path.suffix.lower() in IMAGE_EXTENSIONS:
        pixels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if pixels is None:
            raise DatasetError(f"{path}: cannot read ground-truth image (missing, empty or not an image)")
        marks = pixels != 0 if pixels.ndim == 2 else np.any(pixels != 0, axis=2)
    else:
        marks = _read_text_matrix(path) != 0
    if marks.shape != (n_images, n_images):
        raise DatasetError(
            f"{path}: ground truth is {marks.shape[0]} x {marks.shape[1]} but there are {n_images} images "
            f"(needs {n_images} x {n_images})"
        )
    return marks | marks.T


def _read_text_matrix(path: Path) -> np.ndarray:
    """A matrix (R, C) float64 written as text rows of numbers separated by commas or white space."""
    text = read_user_text(path, DatasetError, "ground truth")
    rows = []
    for line_number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            row = [float(value) for value in re.split(r"[,\s]+", line.strip(", \t"))]
        except ValueError:
            raise DatasetError(f"{path}:{line_number}: not a row of numbers: {line[:60]!r}") from None
        if not all(math.isfinite(value) for value in row):
            raise DatasetError(f"{path}:{line_number}: not a finite number in {line[:60]!r} (a pair is 0 or 1)")
        if rows and len(row) != len(rows[0]):
            raise DatasetError(f"{path}:{line_number}: {len(row)} values, the first row has {len(rows[0])}")
        rows.append(row)
    if not rows:
        raise DatasetError(f"{path}: no ground-truth rows")
    return np.array(rows)


# --- evaluation --------------------------------------------------------------------------


@dataclass(frozen=True)
class PlaceScores:
    """The best match of each query against ground truth, and the place-recognition figures.

    Attributes
    ----------
    best_match : (N,) int64
        Best-matching database image of each query, -1 where it has no eligible image.
    best_similarity : (N,) float64
        Its similarity (NaN where none).
    best_is_true : (N,) bool
        Whether the ground truth marks the best match.
    has_true_match : (N,) bool
        Whether the ground truth marks any eligible image of the query.
    precision, recall, thresholds : (K,) float64
        The precision-recall curve, one point per distinct best-match similarity, highest
        first: the detections with similarity >= ``thresholds[k]`` have ``precision[k]``
        and ``recall[k]`` (NaN recall without any true match).
    top1_accuracy, recall_at_full_precision, average_precision : float
        Module docstring; NaN without any query with a true match.
    """

    best_match: np.ndarray
    best_similarity: np.ndarray
    best_is_true: np.ndarray
    has_true_match: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    thresholds: np.ndarray
    top1_accuracy: float
    recall_at_full_precision: float
    average_precision: float

    @property
    def n_images(self) -> int:
        return len(self.best_match)

    @property
    def n_queries(self) -> int:
        """Queries with at least one eligible database image (they make a detection)."""
        return int(np.count_nonzero(self.best_match >= 0))

    @property
    def n_with_true_match(self) -> int:
        """Queries whose eligible images include a true match: the recall denominator."""
        return int(np.count_nonzero(self.has_true_match))

    def as_dict(self) -> dict:
        """The figures as JSON-ready values (NaN as None)."""

        def number(value: float) -> float | None:
            return None if np.isnan(value) else float(value)

        return {
            "images": self.n_images,
            "queries": self.n_queries,
            "queries_with_true_match": self.n_with_true_match,
            "top1_accuracy": number(self.top1_accuracy),
            "recall_at_full_precision": number(self.recall_at_full_precision),
            "average_precision": number(self.average_precision),
        }


def best_matches(similarity: np.ndarray, exclude_recent: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Best database image (N,) int64 of each query and its similarity (N,) float64 (-1 / NaN without any).

    Over the eligible pairs (`eligible_pairs`); a NaN similarity counts as the least
    similar; equal best scores go to the earliest image.
    """
    similarity = np.asarray(similarity, dtype=np.float64)
    eligible = eligible_pairs(len(similarity), exclude_recent)
    # The eligible images of a query are the first columns of its row, so argmax (the first
    # maximum) never picks an ineligible -inf over an eligible one, even a NaN (-inf) one.
    scored = np.where(eligible & ~np.isnan(similarity), similarity, -np.inf)
    best = np.where(eligible.any(axis=1), np.argmax(scored, axis=1), -1)
    rows = np.flatnonzero(best >= 0)
    best_similarity = np.full(len(similarity), np.nan)
    best_similarity[rows] = similarity[rows, best[rows]]
    return best.astype(np.int64), best_similarity


def precision_recall(best_similarity: np.ndarray, best_is_true: np.ndarray,
                     n_positives: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Precision, recall and thresholds (K,) of detections ranked by similarity (module docstring).

    ``best_similarity`` (M,) and ``best_is_true`` (M,) bool: one detection per query
    (NaN similarity ranks last); ``n_positives``: queries with a true match. One point
    per distinct similarity, highest first; recall NaN when ``n_positives`` is 0.
    """
    ranking_scores = np.where(np.isnan(best_similarity), -np.inf, best_similarity)
    order = np.argsort(-ranking_scores, kind="stable")
    ranked, is_true = ranking_scores[order], np.asarray(best_is_true, dtype=bool)[order]
    true_positives = np.cumsum(is_true)
    detections = np.arange(1, len(ranked) + 1)
    last_of_tie = np.flatnonzero(np.r_[ranked[1:] != ranked[:-1], True]) if len(ranked) else np.zeros(0, int)
    precision = true_positives[last_of_tie] / detections[last_of_tie]
    recall = true_positives[last_of_tie] / n_positives if n_positives else np.full(len(last_of_tie), np.nan)
    return precision.astype(np.float64), recall.astype(np.float64), ranked[last_of_tie].astype(np.float64)


def evaluate_places(similarity: np.ndarray, ground_truth: np.ndarray, exclude_recent: int = 0) -> PlaceScores:
    """Best match of each query, top-1 accuracy, precision-recall, recall at 100 % precision, AP.

    Parameters
    ----------
    similarity : (N, N) float
        Higher = more similar; only ``j < i - exclude_recent`` is read.
    ground_truth : (N, N) bool
        Pairs showing the same place; symmetrised here.
    exclude_recent : int
        As for the similarity: the images just before a query are neither matches nor
        true matches.
    """
    similarity = np.asarray(similarity, dtype=np.float64)
    ground_truth = np.asarray(ground_truth, dtype=bool)
    n = len(similarity)
    if similarity.shape != (n, n) or ground_truth.shape != (n, n):
        raise ValueError(f"similarity {similarity.shape} and ground truth {ground_truth.shape} must both be (N, N)")
    truth = (ground_truth | ground_truth.T) & eligible_pairs(n, exclude_recent)
    best, best_similarity = best_matches(similarity, exclude_recent)
    queries = np.flatnonzero(best >= 0)
    best_is_true = np.zeros(n, dtype=bool)
    best_is_true[queries] = truth[queries, best[queries]]
    has_true_match = truth.any(axis=1)
    n_positives = int(np.count_nonzero(has_true_match))
    precision, recall, thresholds = precision_recall(best_similarity[queries], best_is_true[queries], n_positives)
    if n_positives:
        top1 = float(np.count_nonzero(best_is_true)) / n_positives
        full = precision == 1.0
        recall_full = float(recall[full].max()) if full.any() else 0.0
        average_precision = float(np.sum(np.diff(recall, prepend=0.0) * precision))
    else:
        top1 = recall_full = average_precision = float("nan")
    return PlaceScores(best, best_similarity, best_is_true, has_true_match, precision, recall, thresholds,
                       top1, recall_full, average_precision)
