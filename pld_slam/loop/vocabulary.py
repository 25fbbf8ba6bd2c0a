"""A vocabulary tree for binary descriptors, as DBoW2 builds it: the bag-of-words rival of GGS.

ORB-SLAM2 and PL-SLAM recognise places by bag of words: each ORB descriptor of an image is
quantised to a *word*, a leaf of a tree built offline by hierarchical clustering of
training descriptors, and an image becomes a sparse TF-IDF weighted histogram of words.

Building (`build_vocabulary`), per DBoW2 (Galvez-Lopez and Tardos 2012):

- The root holds every training descriptor. Each node with more than ``branching``
  descriptors is split into ``branching`` clusters by k-majority, the binary k-means:
  k-means++ seeding (each new centre drawn with probability proportional to the squared
  Hamming distance to the nearest centre so far), then assignment to the nearest centre
  and, per cluster, the bitwise majority of its descriptors as its new centre (ties give
  0), until no assignment changes or ``iterations`` rounds. Clusters left empty are
  dropped. The tree stops at ``depth`` levels below the root.
- DBoW2 turns a node of at most ``branching`` descriptors into one leaf per descriptor;
  we make such a node a leaf itself (a word), which changes nothing on large training
  sets (every node deep in the tree has many descriptors) and keeps small vocabularies
  from memorising single descriptors.
- Every level is clustered in one vectorised pass over all its nodes, so a 1,000-image
  training set (a million descriptors) takes minutes, not hours, in numpy.
- The weight of word ``w`` is its inverse document frequency, ``idf_w = log(N / N_w)``:
  N training images, N_w of them with at least one descriptor quantised to ``w``.
- Seeded: the same descriptors and seed give the same tree, bit for bit.

Using it: `Vocabulary.words` descends each descriptor from the root to a leaf, choosing at
every level the child whose centre is nearest in Hamming distance (the first on ties);
`Vocabulary.nodes_at_level` stops at a given level: DBoW2's *direct index*, which groups
an image's features by the node they pass through so that matching compares only
features under the same node. The loop's geometric check does not use it: it matches the
candidates of both detectors by descriptor alone (`pld_slam.loop.verify`), so that GGS
and bag of words are compared on place recognition and nothing else.
`Vocabulary.bow_vector` makes an image's TF-IDF vector (term frequency: a word's share
of the image's descriptors, times its idf), normalised to L1 norm 1. Two vectors are
scored by DBoW2's L1 score, ``1 - |a - b|_1 / 2``, in [0, 1] with 1 for the same words in
the same proportions (`bow_score`).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pld_slam.errors import PldSlamError
from pld_slam.frontend.descriptors import DESCRIPTOR_BYTES, MAX_DISTANCE

_NO_CHILD = -1
_FORMAT_VERSION = 1


@dataclass(frozen=True)
class BowVector:
    """An image's bag of words: ``words`` (U,) int64 sorted, ``weights`` (U,) float64 > 0 summing to 1."""

    words: np.ndarray
    weights: np.ndarray

    @classmethod
    def empty(cls) -> "BowVector":
        return cls(np.zeros(0, dtype=np.int64), np.zeros(0))


_NPZ_MAGIC = b"PK\x03\x04"
"""The first bytes of an .npz file (a zip archive, `numpy.savez_compressed`)."""


@dataclass(frozen=True)
class Vocabulary:
    """A vocabulary tree (module docstring). Node 0 is the root.

    Attributes
    ----------
    centres : (M, 32) uint8
        Each node's cluster centre (the root's is unused).
    children : (M, branching) int64
        Each node's children, -1 where it has fewer (all -1 for a leaf).
    level : (M,) int64
        Each node's depth below the root (root 0).
    word : (M,) int64
        The word index of each leaf, -1 for inner nodes.
    idf : (W,) float64
        Each word's inverse document frequency.
    """

    centres: np.ndarray
    children: np.ndarray
    level: np.ndarray
    word: np.ndarray
    idf: np.ndarray

    @property
    def branching(self) -> int:
        return self.children.shape[1]

    @property
    def depth(self) -> int:
        return int(self.level.max())

    @property
    def n_words(self) -> int:
        return len(self.idf)

    def nodes_at_level(self, descriptors: np.ndarray, level: int) -> np.ndarray:
        """The node (K,) int64 each descriptor (K, 32) uint8 passes through at ``level`` (its leaf if shallower)."""
        node = np.zeros(len(descriptors), dtype=np.int64)
        for _ in range(level):
            children = self.children[node]
            inner = children[:, 0] != _NO_CHILD
            if not inner.any():
                break
            nearest = nearest_centre(descriptors[inner], self.centres, children[inner])
            node[inner] = children[inner][np.arange(len(nearest)), nearest]
        return node

    def words(self, descriptors: np.ndarray) -> np.ndarray:
        """The word (K,) int64 of each descriptor (K, 32) uint8: its leaf's word index."""
        return self.word[self.nodes_at_level(descriptors, self.depth)]

    def bow_vector(self, descriptors: np.ndarray) -> BowVector:
        """The image's L1-normalised TF-IDF vector from its descriptors (K, 32) uint8 (module docstring)."""
        if len(descriptors) == 0:
            return BowVector.empty()
        words, counts = np.unique(self.words(descriptors), return_counts=True)
        weights = counts / len(descriptors) * self.idf[words]
        keep = weights > 0
        words, weights = words[keep], weights[keep]
        total = weights.sum()
        if total <= 0:
            return BowVector.empty()
        return BowVector(words.astype(np.int64), weights / total)

    def save(self, path: str | Path) -> None:
        """Write the vocabulary to ``path`` (a ``.npz`` file)."""
        np.savez_compressed(
            path, version=_FORMAT_VERSION, centres=self.centres, children=self.children, level=self.level,
            word=self.word, idf=self.idf,
        )

    @classmethod
    def load(cls, path: str | Path) -> "Vocabulary":
        """Read a vocabulary written by `save` (``pld-slam vocabulary build``).

        Raises PldSlamError naming the file when it is missing or not a vocabulary.
        """
        path = Path(path)
        if not path.is_file():
            raise PldSlamError(f"{path}: no such vocabulary file (build one with `pld-slam vocabulary build`)")
        keys = ("version", "centres", "children", "level", "word", "idf")
        with path.open("rb") as file:
            if file.read(4) != _NPZ_MAGIC:
                raise PldSlamError(f"{path}: not a pld-slam vocabulary (not the .npz archive that "
                                   "`pld-slam vocabulary build` writes)")
        try:
            with np.load(path) as data:
                version, *arrays = (data[key] for key in keys)
            version = int(version)
        except Exception as error:  # a damaged file: numpy's, zipfile's, zlib's errors, EOFError, ... (issue 43)
            raise PldSlamError(f"{path}: not a pld-slam vocabulary ({type(error).__name__}: {error})") from None
        if version != _FORMAT_VERSION:
            raise PldSlamError(f"{path}: vocabulary format {version}, expected {_FORMAT_VERSION}")
        vocabulary = cls(*arrays)
        vocabulary.check(path)
        return vocabulary

    def check(self, path: Path) -> None:
        """PldSlamError naming ``path`` when the arrays do not make a tree."""
        n_nodes = len(self.centres)
        consistent = (
            self.centres.shape == (n_nodes, DESCRIPTOR_BYTES) and self.centres.dtype == np.uint8
            and self.children.ndim == 2 and len(self.children) == n_nodes
            and len(self.level) == n_nodes and len(self.word) == n_nodes
            and self.children.max(initial=0) < n_nodes and self.word.max(initial=-1) < len(self.idf)
            and np.array_equal(np.flatnonzero(self.word >= 0), np.flatnonzero(self.children[:, 0] == _NO_CHILD))
        )
        if not consistent:
            raise PldSlamError(f"{path}: vocabulary arrays are inconsistent (a damaged file?)")


def bow_score(a: BowVector, b: BowVector) -> float:
    """DBoW2's L1 score ``1 - |a - b|_1 / 2`` of two L1-normalised vectors, in [0, 1].

    For non-negative vectors of norm 1, ``|a| + |b| - |a - b| = 2 min(a, b)`` per word, so the
    score is the sum over shared words of the smaller weight.
    """
    _, in_a, in_b = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
    return float(np.minimum(a.weights[in_a], b.weights[in_b]).sum())


def hamming_to_centres(descriptors: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Hamming distances (K, C) int64 of descriptors (K, 32) to per-descriptor centres (K, C, 32) uint8."""
    xor = descriptors.view(np.uint64)[:, None, :] ^ centres.reshape(*centres.shape[:2], -1).view(np.uint64)
    return np.bitwise_count(xor).sum(axis=2, dtype=np.int64)


def nearest_centre(descriptors: np.ndarray, centres: np.ndarray, children: np.ndarray) -> np.ndarray:
    """For each descriptor (K, 32), the column (K,) of ``children`` (K, C) (node ids, -1 none) with the
    nearest centre among ``centres`` (M, 32); the first on ties."""
    distances = hamming_to_centres(descriptors, centres[children])
    distances[children == _NO_CHILD] = MAX_DISTANCE + 1
    return distances.argmin(axis=1)


def build_vocabulary(
    descriptor_sets: Sequence[np.ndarray],
    branching: int = 10,
    depth: int = 5,
    seed: int = 0,
    iterations: int = 10,
    progress: Callable[[int], None] | None = None,
) -> Vocabulary:
    """Build a vocabulary tree from training images' descriptors (module docstring).

    Parameters
    ----------
    descriptor_sets : one (K_i, 32) uint8 array per training image.
    branching, depth : DBoW2's k and L.
    seed : seed of the k-means++ draws.
    iterations : most k-majority rounds per level.
    progress : called with 1 after each level is built.
    """
    if branching < 2 or depth < 1:
        raise PldSlamError(f"vocabulary: branching must be >= 2 and depth >= 1 (got {branching}, {depth})")
    descriptors = np.concatenate([np.asarray(d, dtype=np.uint8).reshape(-1, DESCRIPTOR_BYTES) for d in descriptor_sets])
    if len(descriptors) == 0:
        raise PldSlamError("vocabulary: the training images have no descriptors")
    image = np.repeat(np.arange(len(descriptor_sets)), [len(d) for d in descriptor_sets])
    rng = np.random.default_rng(seed)
    tree = _Tree(branching)
    node = np.zeros(len(descriptors), dtype=np.int64)
    for level in range(depth):
        splitting = _nodes_to_split(tree, node, level, branching)
        if len(splitting):
            node = _split_level(tree, descriptors, node, splitting, level + 1, rng, iterations)
        if progress is not None:
            progress(1)
    return tree.finish(node, image, len(descriptor_sets))


class _Tree:
    """The growing tree of `build_vocabulary`: centres, children and levels of the nodes so far."""

    def __init__(self, branching: int) -> None:
        self.branching = branching
        self.centres = [np.zeros((1, DESCRIPTOR_BYTES), dtype=np.uint8)]
        self.children = [np.full((1, branching), _NO_CHILD, dtype=np.int64)]
        self.level = [np.zeros(1, dtype=np.int64)]
        self.size = 1

    def add_children(self, parents: np.ndarray, centres: np.ndarray, slot: np.ndarray, level: int) -> np.ndarray:
        """New nodes with ``centres`` (K, 32) as children ``slot`` (K,) of ``parents`` (K,); their ids (K,)."""
        ids = self.size + np.arange(len(parents))
        children = np.concatenate(self.children)
        children[parents, slot] = ids
        self.children = [children, np.full((len(ids), self.branching), _NO_CHILD, dtype=np.int64)]
        self.centres.append(centres)
        self.level.append(np.full(len(ids), level, dtype=np.int64))
        self.size += len(ids)
        return ids

    def finish(self, node: np.ndarray, image: np.ndarray, n_images: int) -> Vocabulary:
        """The vocabulary, with the idf of each word from the leaf ``node`` (N,) of each training
        descriptor and the ``image`` (N,) it came from."""
        children = np.concatenate(self.children)
        leaves = np.flatnonzero(children[:, 0] == _NO_CHILD)
        word = np.full(self.size, -1, dtype=np.int64)
        word[leaves] = np.arange(len(leaves))
        word_image = np.unique(np.stack([word[node], image]), axis=1)
        images_with_word = np.bincount(word_image[0], minlength=len(leaves))
        idf = np.log(n_images / np.maximum(images_with_word, 1))
        return Vocabulary(np.concatenate(self.centres), children, np.concatenate(self.level), word, idf)


def _nodes_to_split(tree: _Tree, node: np.ndarray, level: int, branching: int) -> np.ndarray:
    """The nodes at ``level`` holding more than ``branching`` training descriptors."""
    counts = np.bincount(node, minlength=tree.size)
    levels = np.concatenate(tree.level)
    return np.flatnonzero((levels == level) & (counts > branching))


def _split_level(
    tree: _Tree, descriptors: np.ndarray, node: np.ndarray, splitting: np.ndarray, child_level: int,
    rng: np.random.Generator, iterations: int,
) -> np.ndarray:
    """Split every node in ``splitting`` into children at ``child_level`` by k-majority; the new
    node (N,) of each descriptor."""
    k = tree.branching
    active = np.flatnonzero(np.isin(node, splitting))
    active = active[np.argsort(node[active], kind="stable")]
    segment = np.searchsorted(splitting, node[active])
    starts = np.searchsorted(segment, np.arange(len(splitting)))
    sizes = np.diff(np.append(starts, len(active)))
    members = descriptors[active]
    centres = _kmeans_plus_plus(members, segment, starts, sizes, k, rng)
    cluster = np.zeros(len(active), dtype=np.int64)
    for round_ in range(iterations):
        assigned = hamming_to_centres(members, centres[segment]).argmin(axis=1)
        if round_ > 0 and np.array_equal(assigned, cluster):
            break
        cluster = assigned
        centres = _majority_centres(members, segment * k + cluster, centres)
    used = np.unique(segment * k + cluster)
    ids = tree.add_children(splitting[used // k], centres.reshape(-1, DESCRIPTOR_BYTES)[used], used % k,
                            child_level)
    new_node = node.copy()
    new_node[active] = ids[np.searchsorted(used, segment * k + cluster)]
    return new_node


def _kmeans_plus_plus(
    members: np.ndarray, segment: np.ndarray, starts: np.ndarray, sizes: np.ndarray, k: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """k-means++ seeds (S, k, 32) of S segments of ``members`` (N, 32), sorted by ``segment`` (N,).

    The first seed of each segment is uniform; each next one is drawn with probability
    proportional to the squared Hamming distance to the nearest seed so far (uniform again
    when every member sits on a seed: the duplicate seed's cluster stays empty).
    """
    n_segments = len(starts)
    picks = np.zeros((n_segments, k), dtype=np.int64)
    picks[:, 0] = starts + np.floor(rng.random(n_segments) * sizes).astype(np.int64)
    nearest = np.full(len(members), np.inf)
    for c in range(1, k):
        newest = members[picks[:, c - 1]][segment]
        distance = hamming_to_centres(members, newest[:, None, :])[:, 0].astype(np.float64)
        nearest = np.minimum(nearest, distance**2)
        cumulative = np.cumsum(nearest)
        before = np.where(starts > 0, cumulative[np.maximum(starts - 1, 0)], 0.0)
        total = cumulative[starts + sizes - 1] - before
        draw = rng.random(n_segments)
        weighted = np.searchsorted(cumulative, before + draw * total, side="right")
        uniform = starts + np.floor(draw * sizes).astype(np.int64)
        picks[:, c] = np.clip(np.where(total > 0, weighted, uniform), starts, starts + sizes - 1)
    return members[picks]


def _majority_centres(members: np.ndarray, group: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Per group (segment * k + cluster), the bitwise majority of its members (ties 0); groups
    without members keep their centre. ``centres`` (S, k, 32) -> (S, k, 32)."""
    order = np.argsort(group, kind="stable")
    groups, first, counts = np.unique(group[order], return_index=True, return_counts=True)
    sorted_members = members[order]
    majority = np.zeros((len(groups), DESCRIPTOR_BYTES), dtype=np.uint8)
    for bit in range(8):
        ones = np.add.reduceat(((sorted_members >> bit) & 1).astype(np.int64), first, axis=0)
        majority |= ((2 * ones > counts[:, None]).astype(np.uint8) << bit)
    updated = centres.reshape(-1, DESCRIPTOR_BYTES).copy()
    updated[groups] = majority
    return updated.reshape(centres.shape)
