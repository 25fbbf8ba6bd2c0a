"""Place recognition on its own (`pld_slam.loop.places`, ``pld-slam places``).

The image set is procedural: five street-like places, then revisits of three of them
(the same view shifted by a few pixels, with new noise), some saved in colour, as JPEG,
or at another size. The metric tests use small similarity matrices whose figures are
computed by hand in the comments.
"""

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.image import imread

from pld_slam.config import Config, GgsConfig
from pld_slam.errors import DatasetError, PldSlamError
from pld_slam.frontend.ggs import ggs_and_place_descriptors, ggs_distance
from pld_slam.frontend.points import detect_image_points
from pld_slam.loop.places import (
    best_matches,
    eligible_pairs,
    evaluate_places,
    load_ground_truth,
    natural_sorted_images,
    place_similarity,
    read_images,
)
from pld_slam.loop.vocabulary import build_vocabulary
from pld_slam_cli.main import EXIT_USER_ERROR, cli

SHAPE = (120, 160)
PLACES = 5
REVISITS = {5: 0, 6: 1, 7: 2}
"""Revisit image -> the image of the same place."""


def street(seed: int, shape: tuple[int, int]) -> np.ndarray:
    """A street-like grey image: a gradient under random blocks and discs, blurred."""
    rng = np.random.default_rng(seed)
    height, width = shape
    image = np.repeat(np.linspace(rng.uniform(150, 230), rng.uniform(30, 110), height,
                                  dtype=np.float32)[:, None], width, axis=1)
    for _ in range(25):
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        size = (int(rng.integers(8, 60)), int(rng.integers(5, 45)))
        cv2.rectangle(image, (x, y), (x + size[0], y + size[1]), float(rng.uniform(20, 240)), -1)
    for _ in range(12):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        cv2.circle(image, centre, int(rng.integers(3, 20)), float(rng.uniform(0, 255)), -1)
    return np.clip(cv2.GaussianBlur(image, (0, 0), 1.0), 0, 255).astype(np.uint8)


def view(scene: np.ndarray, dx: int, dy: int, noise_seed: int) -> np.ndarray:
    """A SHAPE window of ``scene`` offset by (dx, dy) from its centre, with pixel noise."""
    top, left = (scene.shape[0] - SHAPE[0]) // 2 + dy, (scene.shape[1] - SHAPE[1]) // 2 + dx
    window = scene[top : top + SHAPE[0], left : left + SHAPE[1]].astype(np.float32)
    window += np.random.default_rng(noise_seed).normal(0.0, 4.0, SHAPE).astype(np.float32)
    return np.clip(window, 0, 255).astype(np.uint8)


def place_images() -> list[np.ndarray]:
    """Images 0-4: five places; 5, 6, 7: revisits of places 0, 1, 2 (shifted 3-5 px, new noise)."""
    scenes = [street(seed, (SHAPE[0] + 20, SHAPE[1] + 20)) for seed in range(PLACES)]
    images = [view(scene, 0, 0, 100 + index) for index, scene in enumerate(scenes)]
    shifts = [(4, 3), (-5, 2), (3, -4)]
    images += [view(scenes[place], dx, dy, 200 + place) for place, (dx, dy) in zip(REVISITS.values(), shifts)]
    return images


def ground_truth_matrix(n: int = PLACES + len(REVISITS)) -> np.ndarray:
    """(N, N) uint8, 255 where a revisit and its place meet (lower triangle only, as some sets ship it)."""
    truth = np.zeros((n, n), dtype=np.uint8)
    for revisit, place in REVISITS.items():
        truth[revisit, place] = 255
    return truth


@pytest.fixture(scope="module")
def image_dir(tmp_path_factory):
    """The place images as files whose names sort wrongly as plain strings: 1..8, some colour, one JPEG,
    one larger; plus files that are not images."""
    folder = tmp_path_factory.mktemp("places") / "street"
    folder.mkdir()
    for index, image in enumerate(place_images()):
        name = f"{index + 1}"
        if index == 3:
            cv2.imwrite(str(folder / f"{name}.jpg"), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR),
                        [cv2.IMWRITE_JPEG_QUALITY, 95])
        elif index == 6:
            cv2.imwrite(str(folder / f"{name}.png"), cv2.resize(image, None, fx=2, fy=2))
        elif index % 2:
            cv2.imwrite(str(folder / f"{name}.png"), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
        else:
            cv2.imwrite(str(folder / f"{name}.png"), image)
    (folder / "notes.txt").write_text("not an image")
    return folder


def run(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


# --- images ------------------------------------------------------------------------------


def test_natural_sort_puts_2_before_10_across_extensions_and_case(tmp_path):
    for name in ("10.png", "2.jpg", "1.PNG", "img_03.bmp", "img_3.tif", "img_20.pgm", "a.JPEG", "x.ppm"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "readme.txt").write_text("")
    (tmp_path / ".hidden.png").write_bytes(b"")
    (tmp_path / "sub.png").mkdir()
    names = [path.name for path in natural_sorted_images(tmp_path)]
    assert names == ["1.PNG", "2.jpg", "10.png", "a.JPEG", "img_03.bmp", "img_3.tif", "img_20.pgm", "x.ppm"]


def test_a_folder_without_images_is_an_error_naming_it(tmp_path):
    (tmp_path / "readme.txt").write_text("")
    with pytest.raises(DatasetError, match=str(tmp_path)):
        natural_sorted_images(tmp_path)


def test_an_unreadable_image_is_an_error_naming_the_file(tmp_path):
    (tmp_path / "1.png").write_bytes(b"not a png")
    with pytest.raises(DatasetError, match="1.png"):
        list(read_images(natural_sorted_images(tmp_path)))


# --- similarity --------------------------------------------------------------------------


def test_eligible_pairs_are_the_earlier_images_outside_the_recent_window():
    assert eligible_pairs(4).tolist() == np.tril(np.ones((4, 4), bool), -1).tolist()
    eligible = eligible_pairs(5, exclude_recent=2)
    assert np.argwhere(eligible).tolist() == [[3, 0], [4, 0], [4, 1]]


def test_ggs_similarity_is_the_negated_ggs_distance_of_the_earlier_images():
    images = place_images()[:4]
    similarity = place_similarity(iter(images), "ggs")
    descriptors = [ggs_and_place_descriptors(image, GgsConfig())[1] for image in images]
    assert similarity.shape == (4, 4)
    for i in range(4):
        for j in range(4):
            if j < i:
                assert similarity[i, j] == -ggs_distance(descriptors[i], descriptors[j])
            else:
                assert np.isnan(similarity[i, j])
    excluded = place_similarity(iter(images), "ggs", exclude_recent=1)
    assert np.array_equal(np.isnan(excluded), ~eligible_pairs(4, 1))
    assert excluded[3, 1] == similarity[3, 1]


def test_ggs_finds_every_revisit_of_the_generated_places(image_dir):
    paths = natural_sorted_images(image_dir)
    assert [path.stem for path in paths] == [str(i) for i in range(1, 9)]
    similarity = place_similarity(read_images(paths), "ggs")
    scores = evaluate_places(similarity, ground_truth_matrix() != 0)
    assert scores.best_match[5:].tolist() == [0, 1, 2]
    assert scores.n_with_true_match == 3 and scores.n_queries == 7
    assert scores.top1_accuracy == 1.0
    assert scores.recall_at_full_precision == 1.0
    assert scores.average_precision == 1.0


def test_bow_without_a_vocabulary_says_how_to_build_one():
    with pytest.raises(PldSlamError, match="pld-slam vocabulary build"):
        place_similarity(iter([]), "bow")


def test_bow_with_a_vocabulary_of_other_streets_finds_every_revisit(image_dir, tmp_path):
    points = Config().points
    training = [detect_image_points(street(seed, (240, 320)), points).descriptors for seed in range(50, 80)]
    build_vocabulary(training, branching=6, depth=4, seed=0).save(tmp_path / "vocab.npz")
    similarity = place_similarity(read_images(natural_sorted_images(image_dir)), "bow",
                                  vocabulary=tmp_path / "vocab.npz")
    assert np.nanmax(similarity) <= 1.0 and np.nanmin(similarity) >= 0.0
    scores = evaluate_places(similarity, ground_truth_matrix() != 0)
    assert scores.best_match[5:].tolist() == [0, 1, 2]
    assert scores.top1_accuracy == 1.0


def test_a_vocabulary_with_ggs_is_an_error(tmp_path):
    with pytest.raises(PldSlamError, match="only used by the bow detector"):
        place_similarity(iter([]), "ggs", vocabulary=tmp_path / "vocab.npz")


# --- metrics on constructed matrices -----------------------------------------------------

NAN = np.nan


def constructed(query_2_has_a_true_match: bool) -> tuple[np.ndarray, np.ndarray]:
    """Five images, queries 1-4 with best-match similarities 0.9, 0.8, 0.7, 0.6.

    Best matches: 1 -> 0 (true), 2 -> 1 (false), 3 -> 1 (true), 4 -> 2 (true). Query 2's
    true match, when it has one, is image 0, which it scores lower than image 1.
    """
    similarity = np.array([
        [NAN, NAN, NAN, NAN, NAN],
        [0.9, NAN, NAN, NAN, NAN],
        [0.1, 0.8, NAN, NAN, NAN],
        [0.1, 0.7, 0.2, NAN, NAN],
        [0.1, 0.2, 0.6, 0.3, NAN],
    ])
    truth = np.zeros((5, 5), dtype=bool)
    truth[1, 0] = truth[3, 1] = truth[4, 2] = True
    truth[2, 0] = query_2_has_a_true_match
    return similarity, truth


def test_a_false_positive_ranked_second_among_queries_without_a_true_match():
    # Ranked detections: TP, FP, TP, TP; 3 queries have a true match.
    # precision 1, 1/2, 2/3, 3/4 at recall 1/3, 1/3, 2/3, 1.
    # AP = (1 + 2/3 + 3/4) / 3 = 29/36; recall at 100 % precision = 1/3; top-1 = 3/3.
    scores = evaluate_places(*constructed(query_2_has_a_true_match=False))
    assert scores.best_match.tolist() == [-1, 0, 1, 1, 2]
    assert scores.best_is_true.tolist() == [False, True, False, True, True]
    assert scores.n_with_true_match == 3 and scores.n_queries == 4
    assert scores.top1_accuracy == 1.0
    assert scores.recall_at_full_precision == pytest.approx(1 / 3)
    assert scores.average_precision == pytest.approx(29 / 36)
    assert scores.precision == pytest.approx([1, 1 / 2, 2 / 3, 3 / 4])
    assert scores.recall == pytest.approx([1 / 3, 1 / 3, 2 / 3, 1])
    assert scores.thresholds == pytest.approx([0.9, 0.8, 0.7, 0.6])


def test_a_query_whose_best_match_is_wrong_is_a_false_positive_and_a_miss():
    # Same ranking, but query 2 has a true match (image 0) it ranks below image 1:
    # 4 positives, 3 found. top-1 = 3/4; recall at 100 % precision = 1/4;
    # AP = (1 + 2/3 + 3/4) / 4 = 29/48; the curve never reaches recall 1.
    scores = evaluate_places(*constructed(query_2_has_a_true_match=True))
    assert scores.n_with_true_match == 4
    assert scores.top1_accuracy == pytest.approx(3 / 4)
    assert scores.recall_at_full_precision == pytest.approx(1 / 4)
    assert scores.average_precision == pytest.approx(29 / 48)
    assert scores.recall[-1] == pytest.approx(3 / 4)


def test_a_false_detection_ranked_first_gives_no_recall_at_full_precision():
    similarity, truth = constructed(query_2_has_a_true_match=False)
    similarity[2, 1] = 0.95  # query 2's false detection now outranks query 1's true one
    # Ranked: FP, TP, TP, TP -> AP = (1/2 + 2/3 + 3/4) / 3 = 23/36.
    scores = evaluate_places(similarity, truth)
    assert scores.recall_at_full_precision == 0.0
    assert scores.average_precision == pytest.approx(23 / 36)
    assert scores.top1_accuracy == 1.0


def test_ground_truth_in_the_upper_triangle_counts_the_same():
    similarity, truth = constructed(query_2_has_a_true_match=False)
    lower = evaluate_places(similarity, truth)
    upper = evaluate_places(similarity, truth.T)
    assert upper.average_precision == lower.average_precision
    assert upper.best_is_true.tolist() == lower.best_is_true.tolist()


def test_tied_best_scores_share_one_threshold_whatever_the_query_order():
    # Queries 1 and 2 both score 0.9: one true, one false. No threshold accepts one without
    # the other: the first point has precision 1/2, so recall at 100 % precision is 0,
    # whichever of the two is the true one.
    similarity = np.array([
        [NAN, NAN, NAN],
        [0.9, NAN, NAN],
        [0.5, 0.9, NAN],
    ])
    for true_pair in ((1, 0), (2, 1)):
        truth = np.zeros((3, 3), dtype=bool)
        truth[true_pair] = True
        scores = evaluate_places(similarity, truth)
        assert scores.precision.tolist() == [0.5]
        assert scores.recall.tolist() == [1.0]
        assert scores.recall_at_full_precision == 0.0
        assert scores.average_precision == 0.5


def test_equal_best_scores_within_a_query_go_to_the_earliest_image():
    similarity = np.array([[NAN, NAN, NAN], [0.2, NAN, NAN], [0.7, 0.7, NAN]])
    best, best_similarity = best_matches(similarity)
    assert best.tolist() == [-1, 0, 0]
    assert best_similarity[2] == 0.7


def test_a_nan_score_among_the_eligible_never_beats_a_number():
    similarity = np.array([[NAN, NAN, NAN], [0.2, NAN, NAN], [NAN, -5.0, NAN]])
    assert best_matches(similarity)[0].tolist() == [-1, 0, 1]


def test_excluded_recent_images_are_neither_matches_nor_true_matches():
    # Ground truth marks every pair of neighbours (as sets with consecutive frames do) and
    # the loop 3 -> 0. Without exclusion every query is matched to its predecessor; with
    # one image excluded only query 3 has a true match, and finds it.
    similarity = np.array([
        [NAN, NAN, NAN, NAN],
        [0.9, NAN, NAN, NAN],
        [0.1, 0.9, NAN, NAN],
        [0.8, 0.2, 0.9, NAN],
    ])
    truth = np.eye(4, k=-1, dtype=bool)
    truth[3, 0] = True
    everything = evaluate_places(similarity, truth)
    assert everything.best_match.tolist() == [-1, 0, 1, 2] and everything.n_with_true_match == 3
    excluded = evaluate_places(similarity, truth, exclude_recent=1)
    assert excluded.best_match.tolist() == [-1, -1, 0, 0]
    assert excluded.has_true_match.tolist() == [False, False, False, True]
    # Ranked: query 3 (0.8, TP), query 2 (0.1, FP) -> AP 1, recall at 100 % precision 1.
    assert excluded.top1_accuracy == 1.0 and excluded.average_precision == 1.0
    assert excluded.recall_at_full_precision == 1.0
    assert excluded.precision.tolist() == [1.0, 0.5]


def test_without_any_true_match_the_figures_are_nan_and_json_null():
    similarity, _ = constructed(query_2_has_a_true_match=False)
    scores = evaluate_places(similarity, np.zeros((5, 5), dtype=bool))
    assert np.isnan(scores.top1_accuracy) and np.isnan(scores.average_precision)
    assert scores.as_dict()["recall_at_full_precision"] is None
    assert scores.precision.tolist() == [0.0] * 4


# --- ground truth files ------------------------------------------------------------------


def test_ground_truth_from_a_png_marks_non_zero_pixels_symmetrised(tmp_path):
    path = tmp_path / "gt.png"
    colour = np.zeros((4, 4, 3), dtype=np.uint8)
    colour[2, 0, 1] = 7  # only the green channel
    colour[3, 1] = 255
    cv2.imwrite(str(path), colour)
    truth = load_ground_truth(path, 4)
    assert truth.dtype == bool
    assert np.argwhere(truth).tolist() == [[0, 2], [1, 3], [2, 0], [3, 1]]


@pytest.mark.parametrize("text", ["0,0,0\n1,0,0\n0,1,0\n", "# loops\n0 0 0\n1 0 0\n\n0  1\t0\n"])
def test_ground_truth_from_csv_with_commas_or_white_space(tmp_path, text):
    path = tmp_path / "gt.csv"
    path.write_text(text)
    truth = load_ground_truth(path, 3)
    assert np.argwhere(truth).tolist() == [[0, 1], [1, 0], [1, 2], [2, 1]]


def test_ground_truth_of_the_wrong_size_names_the_file_and_both_sizes(tmp_path):
    path = tmp_path / "loops.png"
    cv2.imwrite(str(path), np.zeros((6, 5), dtype=np.uint8))
    with pytest.raises(DatasetError) as error:
        load_ground_truth(path, 8)
    message = str(error.value)
    assert "loops.png" in message and "6 x 5" in message and "8 images" in message and "8 x 8" in message


def test_ground_truth_csv_with_text_names_the_file_and_line(tmp_path):
    path = tmp_path / "gt.csv"
    path.write_text("0,0\n0,yes\n")
    with pytest.raises(DatasetError, match=r"gt.csv:2"):
        load_ground_truth(path, 2)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_ground_truth_csv_with_a_number_that_is_not_finite_names_the_file_and_line(tmp_path, value):
    path = tmp_path / "gt.csv"
    path.write_text(f"0,0\n{value},0\n")  # a NaN is not 0: it would have marked a pair
    with pytest.raises(DatasetError, match=r"gt.csv:2: not a finite number"):
        load_ground_truth(path, 2)


def test_ground_truth_csv_with_ragged_rows_is_an_error(tmp_path):
    path = tmp_path / "gt.csv"
    path.write_text("0,0,0\n0,0\n0,0,0\n")
    with pytest.raises(DatasetError, match=r"gt.csv:2: 2 values"):
        load_ground_truth(path, 3)


# --- the command -------------------------------------------------------------------------


def test_places_json_and_files(image_dir, tmp_path):
    gt = tmp_path / "gt.png"
    cv2.imwrite(str(gt), ground_truth_matrix())
    out = tmp_path / "out"
    result = run("places", image_dir, "--gt", gt, "--out", out, "--json")
    assert result.exit_code == 0, result.output
    values = json.loads(result.output)
    assert values == {"images": 8, "queries": 7, "queries_with_true_match": 3, "top1_accuracy": 1.0,
                      "recall_at_full_precision": 1.0, "average_precision": 1.0}
    similarity = np.load(out / "similarity.npy")
    assert similarity.shape == (8, 8)
    assert np.array_equal(np.isnan(similarity), ~eligible_pairs(8))
    assert np.all(similarity[eligible_pairs(8)] <= 0.0)
    assert np.argmax(np.nan_to_num(similarity[7], nan=-np.inf)) == 2
    for name in ("similarity.png", "precision_recall.png"):
        assert imread(out / name).shape == (480, 640, 4)


def test_places_table_with_a_csv_ground_truth_and_excluded_images(image_dir, tmp_path):
    gt = tmp_path / "gt.csv"
    np.savetxt(gt, ground_truth_matrix() != 0, fmt="%d", delimiter=",")
    out = tmp_path / "out"
    result = run("places", image_dir, "--gt", gt, "--out", out, "--exclude-recent", 2)
    assert result.exit_code == 0, result.output
    assert "top-1 accuracy              1.0000" in result.output
    assert "queries with a true match   3 of 5" in result.output
    assert np.isnan(np.load(out / "similarity.npy")[7, 5])


def test_places_without_ground_truth_writes_into_places_by_default(image_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, ["places", str(image_dir), "--json"])
    assert result.exit_code == 0, result.output
    values = json.loads(result.output)
    assert values["images"] == 8 and values["top1_accuracy"] is None
    assert np.load(tmp_path / "places" / image_dir.name / "similarity.npy").shape == (8, 8)
    assert not (image_dir.parent / "precision_recall.png").exists()


def test_places_bow_without_vocabulary_is_a_one_line_error(image_dir, tmp_path):
    result = run("places", image_dir, "--detector", "bow", "--out", tmp_path / "out")
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output.count("\n") == 1
    assert "pld-slam vocabulary build" in result.output
    assert not (tmp_path / "out").exists()


def test_places_ground_truth_of_the_wrong_size_is_a_one_line_error(image_dir, tmp_path):
    gt = tmp_path / "small.png"
    cv2.imwrite(str(gt), np.zeros((5, 5), dtype=np.uint8))
    result = run("places", image_dir, "--gt", gt, "--out", tmp_path / "out")
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output.startswith("error: ") and "small.png" in result.output and "5 x 5" in result.output


def test_places_unreadable_image_is_a_one_line_error(tmp_path):
    folder = tmp_path / "broken"
    folder.mkdir()
    cv2.imwrite(str(folder / "1.png"), np.zeros((20, 20), dtype=np.uint8))
    (folder / "2.jpg").write_bytes(b"\xff\xd8 truncated")
    result = run("places", folder, "--out", tmp_path / "out")
    assert result.exit_code == EXIT_USER_ERROR
    assert "2.jpg" in result.output


@pytest.mark.parametrize("with_gt", [True, False])
def test_places_where_no_image_has_an_earlier_one_to_match_is_a_one_line_error_before_any_work(
        image_dir, tmp_path, monkeypatch, with_gt):
    monkeypatch.setattr("pld_slam_cli.places.read_images", lambda paths: pytest.fail("images read"))
    gt = tmp_path / "gt.csv"
    np.savetxt(gt, ground_truth_matrix() != 0, fmt="%d", delimiter=",")
    out = tmp_path / "out"
    result = run("places", image_dir, *(("--gt", gt) if with_gt else ()), "--exclude-recent", 7, "--out", out)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == (f"error: {image_dir}: no image has an earlier one to be compared with (8 images, "
                             "the 7 before each left out by --exclude-recent)\n")
    assert not out.exists()
