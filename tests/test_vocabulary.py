"""The bag-of-words vocabulary: a deterministic build, word lookup, TF-IDF scores, the file, the CLI."""

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pld_slam.errors import PldSlamError
from pld_slam.frontend.descriptors import hamming_distances
from pld_slam.loop.vocabulary import BowVector, Vocabulary, bow_score, build_vocabulary
from pld_slam_cli.main import cli


def noisy(descriptors: np.ndarray, flip_probability: float, seed: int) -> np.ndarray:
    """``descriptors`` (K, 32) with each bit flipped with ``flip_probability``."""
    bits = np.random.default_rng(seed).random((len(descriptors), 256)) < flip_probability
    return descriptors ^ np.packbits(bits, axis=1)


def image_sets(n_images: int, per_image: int, seed: int) -> list[np.ndarray]:
    """Descriptors of ``n_images`` "images", each its own random descriptors (n, 32)."""
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (per_image, 32), dtype=np.uint8) for _ in range(n_images)]


@pytest.fixture(scope="module")
def trained():
    images = image_sets(30, 200, seed=3)
    return images, build_vocabulary(images, branching=6, depth=3, seed=1)


def test_the_same_descriptors_and_seed_build_the_same_tree(trained):
    images, vocabulary = trained
    again = build_vocabulary(images, branching=6, depth=3, seed=1)
    other_seed = build_vocabulary(images, branching=6, depth=3, seed=2)
    for field in ("centres", "children", "level", "word", "idf"):
        np.testing.assert_array_equal(getattr(again, field), getattr(vocabulary, field))
    assert not np.array_equal(other_seed.centres[1:7], vocabulary.centres[1:7])


def test_the_tree_has_the_requested_shape(trained):
    _, vocabulary = trained
    assert vocabulary.branching == 6 and vocabulary.depth == 3
    assert 6**2 < vocabulary.n_words <= 6**3
    leaves = vocabulary.children[:, 0] < 0
    assert np.array_equal(vocabulary.word >= 0, leaves)
    assert np.array_equal(np.sort(vocabulary.word[leaves]), np.arange(vocabulary.n_words))


def test_each_lookup_step_takes_the_nearest_child(trained):
    images, vocabulary = trained
    descriptors = noisy(images[0][:50], 0.1, seed=4)
    for level in range(vocabulary.depth):
        parents = vocabulary.nodes_at_level(descriptors, level)
        chosen = vocabulary.nodes_at_level(descriptors, level + 1)
        for descriptor, parent, child in zip(descriptors, parents, chosen):
            children = vocabulary.children[parent]
            children = children[children >= 0]
            if len(children) == 0:
                assert child == parent  # a leaf stays
                continue
            distances = hamming_distances(np.repeat(descriptor[None], len(children), 0), vocabulary.centres[children])
            assert child in children and distances[list(children).index(child)] == distances.min()


def test_a_centre_is_the_bitwise_majority_of_its_training_descriptors(trained):
    images, vocabulary = trained
    descriptors = np.concatenate(images)
    nodes = vocabulary.nodes_at_level(descriptors, 1)
    for node in np.unique(nodes)[:3]:
        bits = np.unpackbits(descriptors[nodes == node], axis=1)
        majority = np.packbits(2 * bits.sum(axis=0) > len(bits))
        # Training assigned by the centres before their last update; a few bits may differ.
        assert np.unpackbits(majority ^ vocabulary.centres[node]).sum() <= 16


def test_tf_idf_scores_rank_an_images_own_descriptors_first(trained):
    images, vocabulary = trained
    database = [vocabulary.bow_vector(d) for d in images]
    for n in range(len(images)):
        query = vocabulary.bow_vector(noisy(images[n], 0.02, seed=n))
        scores = [bow_score(query, entry) for entry in database]
        assert int(np.argmax(scores)) == n


def test_the_l1_score_is_one_minus_half_the_l1_distance():
    a = BowVector(np.array([1, 4, 7]), np.array([0.5, 0.3, 0.2]))
    b = BowVector(np.array([4, 7, 9]), np.array([0.1, 0.6, 0.3]))
    dense = np.zeros((2, 10))
    dense[0, a.words], dense[1, b.words] = a.weights, b.weights
    assert bow_score(a, b) == pytest.approx(1 - 0.5 * np.abs(dense[0] - dense[1]).sum())
    assert bow_score(a, a) == pytest.approx(1.0)
    assert bow_score(a, BowVector(np.array([2]), np.array([1.0]))) == 0.0


def test_a_word_in_every_training_image_weighs_nothing():
    shared = np.random.default_rng(0).integers(0, 256, (1, 32), dtype=np.uint8)
    images = [np.concatenate([shared, d]) for d in image_sets(10, 40, seed=5)]
    vocabulary = build_vocabulary(images, branching=4, depth=2, seed=0)
    word = vocabulary.words(shared)[0]
    in_every_image = all(word in vocabulary.words(d) for d in images)
    assert (vocabulary.idf[word] == 0.0) == in_every_image
    assert word not in vocabulary.bow_vector(images[0]).words or not in_every_image


def test_save_and_load_give_the_same_vocabulary(trained, tmp_path):
    _, vocabulary = trained
    vocabulary.save(tmp_path / "v.npz")
    loaded = Vocabulary.load(tmp_path / "v.npz")
    for field in ("centres", "children", "level", "word", "idf"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(vocabulary, field))


def test_loading_something_else_names_the_file(tmp_path):
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(PldSlamError, match="other.npz"):
        Vocabulary.load(tmp_path / "other.npz")
    with pytest.raises(PldSlamError, match="missing.npz.*vocabulary build"):
        Vocabulary.load(tmp_path / "missing.npz")


def textured_images(folder, n_images: int) -> None:
    """``n_images`` random smooth textures as PNGs named 1.png ... n.png."""
    folder.mkdir()
    rng = np.random.default_rng(0)
    for n in range(1, n_images + 1):
        noise = rng.uniform(0, 255, (24, 32)).astype(np.float32)
        image = cv2.resize(noise, (320, 240), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{n}.png"), image)


def test_the_build_command_writes_the_same_file_for_the_same_images(tmp_path):
    textured_images(tmp_path / "images", 4)
    runner = CliRunner()
    outputs = []
    for name in ("a.npz", "b.npz"):
        result = runner.invoke(cli, ["vocabulary", "build", str(tmp_path / "images"), "--out", str(tmp_path / name),
                                     "--branching", "4", "--depth", "3"])
        assert result.exit_code == 0, result.output
        outputs.append((tmp_path / name).read_bytes())
    assert outputs[0] == outputs[1]
    vocabulary = Vocabulary.load(tmp_path / "a.npz")
    assert vocabulary.depth == 3 and vocabulary.n_words > 4
    assert "words" in result.output
    assert "clustering" not in result.stderr and "\r" not in result.stderr  # no progress bars into a log
